/* Run parameters; the NumPy twin is clsim.simulator.PARAMS_DTYPE (4-byte
 * fields only, so there is no padding to keep in step). */
#ifndef CLSIM_PARAMS_CL
#define CLSIM_PARAMS_CL

typedef struct {
    float sensor[3];    /* receiver/emitter position, local metres */
    float axis[3];      /* unit beam axis, sensor -> target */
    float e1[3];        /* unit vectors perpendicular to axis */
    float e2[3];
    float beam_sigma;   /* per-axis angular standard deviation, rad */
    float tan2_fov;     /* squared tangent of the receiver FOV half angle */
    float virt_r2;      /* squared radius of the analog virtual aperture, m2 */
    float norm_nee;     /* R_ref^2: NEE tallies are in units of A / R_ref^2 */
    float norm_analog;  /* R_ref^2 / A_virtual */
    float h;            /* voxel size, m */
    int shape[3];
    int bshape[3];
    float ground_z;     /* local metres */
    int has_ground;
    float leaf_R, leaf_T, wood_R, wood_T, ground_R;
    float crown_c[2];   /* local metres */
    int outward;        /* leaf azimuth outward from crown_c */
    float ds;           /* paper-mode step, m */
    float t0_ns;        /* start of the first fine time bin */
    float dt_ns;        /* fine bin width */
    int nbins;
    int max_order;
    int n_batches;
    int n_trace;
    int hotspot;        /* 1: single-scattering returns retrace their free incoming path (T = 1) */
    int leaf_avg;       /* 1: spherical leaf angles, uniform azimuths: the next-event weight averaged,
                         * the leaf normal drawn directly, G = 1/2 */
    uint qmc;           /* random shift of the lattice of first free paths, from the seed */
    int skip_first;     /* 1: no order-1 next-event tallies (the deterministic first order adds them) */
} params_t;

/* stats[] slots: fixed-point weights (x 2^32) unless noted */
#define ST_ESC_UP 0
#define ST_ESC_DOWN 1
#define ST_ABSORBED 2
#define ST_TRUNCATED 3
#define ST_RR_KILLED 4
#define ST_RR_ADDED 5
#define ST_GROUND_DIRECT 6
#define ST_OUTSIDE 7      /* detected energy outside the time window (tally units) */
#define ST_DETECTIONS 8   /* count */
#define ST_VOXEL_STEPS 9  /* count of voxels crossed (a uniform brick's segment: its voxels) */
#define ST_EVENTS 10      /* count */
#define ST_SHADOW 11      /* count of shadow rays */
#define ST_WALK_STEPS 12  /* count of walk steps (a voxel, an empty brick, a uniform brick's segment) */
#define NSTAT 13

#endif

"""The memory plan (tlsvox.voxel.plan) against what voxelize allocates, measured with tracemalloc."""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

from tests.tlsvox.voxel.test_voxlad import BOX_HI, BOX_LO, _box_scan
from tlsvox.voxel.grid import VoxelGrid
from tlsvox.voxel.plan import ALLOCATOR_SHARE, Layout, beams_bytes, build_bytes, memory_plan, with_allocator
from tlsvox.voxel.pulses import beams_from_scan
from tlsvox.voxel.stages import voxelize
from tlsvox.voxel.trace import Beams

#: the plan is an upper bound of the arrays' bytes, and not a loose one
FACTOR = 1.5


@pytest.fixture(scope="module")
def big_box_scans():
    """The turbid box of test_voxlad from two scanners, 120,000 pulses each (beams of about 10 MiB):
    large enough that the arrays, not the interpreter's small objects, make the peak."""
    rng = np.random.default_rng(77)
    return [_box_scan(rng, np.array([-6.0, -1.0, 1.6]), 20.0, n_az=400, n_zen=300, scan_id=0),
            _box_scan(rng, np.array([4.0, 5.0, 1.6]), -70.0, n_az=400, n_zen=300, scan_id=1)]


@pytest.fixture(scope="module")
def cpu_tracer():
    """One CPU tracer with two private copies whatever the machine's cores (a 16-core CPU would make
    the dense sums eight times larger and move the phases): its sums are host memory, as the plan
    counts them (the memory does not depend on which CPU runtime runs the kernel, so one is enough)."""
    from tlsvox.errors import DeviceError
    from tlsvox.voxel.trace import Tracer

    try:
        return Tracer("cpu", copies=2)
    except DeviceError as err:
        pytest.skip(f"no CPU OpenCL device for the tracer: {err}")


@pytest.mark.parametrize("voxel_size, air, phase", [(0.2, 0.0, "build"), (0.1, 3.0, "run")])
def test_plan_bounds_the_measured_peak(big_box_scans, cpu_tracer, voxel_size, air, phase):
    """A plain run (default options but the ground and the dense layout, which auto picks on a 2-core
    machine; a many-core one can pick sparse): the plan's need is at least the peak of the
    arrays voxelize makes (tracemalloc, from its start) and at most FACTOR times it (measured 1.27
    and 1.21).  Tight bounds at 20 cm: making and joining the beams is the peak; 3 m of air at
    10 cm: the dense sums are."""
    bounds = np.array([BOX_LO - air, BOX_HI + air])
    kw = dict(voxel_size=voxel_size, ground=None, bounds=bounds, tracer=cpu_tracer, progress=False, layout="dense")
    plan = voxelize(big_box_scans, plan_only=True, **kw)
    assert plan.layout is Layout.DENSE and plan.need == with_allocator(max(plan.build, plan.run))
    assert (plan.build > plan.run) == (phase == "build"), plan.describe()
    voxelize(big_box_scans, **kw)  # the imports and the kernel build, outside the measured run
    tracemalloc.start()
    try:
        base = tracemalloc.get_traced_memory()[0]
        voxelize(big_box_scans, **kw)
        peak = tracemalloc.get_traced_memory()[1] - base
    finally:
        tracemalloc.stop()
    assert peak <= plan.need <= FACTOR * peak, (peak / 2**20, plan.describe())
    # the arrays alone make the peak within 1 % (measured 0.006 % under in the dense run): the
    # allocator's share is on top of a full count, not in place of a missing term
    arrays = max(plan.build, plan.run)
    assert 0.99 * peak <= arrays, (peak / 2**20, plan.describe())
    assert plan.need == pytest.approx((1 + ALLOCATOR_SHARE) * arrays, abs=1)


def test_build_counts_each_scan_and_the_join(big_box_scans, cpu_tracer):
    """One scan: no join; two: the join holds both copies of the beams; the runs of scan_index
    are the scans."""
    parts = [beams_from_scan(s)[0] for s in big_box_scans]
    joined = Beams.concat(parts)
    assert beams_bytes(joined) == sum(beams_bytes(p) for p in parts) - 8  # one echo_start end fewer
    assert build_bytes(joined) >= 2 * beams_bytes(joined) > build_bytes(parts[0])
    assert build_bytes(parts[0]) > beams_bytes(parts[0])
    grid = VoxelGrid.from_bounds(BOX_LO, BOX_HI, voxel_size=0.5)
    plan = memory_plan(grid, joined, cpu_tracer)
    assert plan.build == build_bytes(joined) and plan.need == with_allocator(plan.build)
    assert "making the beams" in plan.describe()


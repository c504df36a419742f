"""The bad-input corpus: every entry point given what a user might wrongly give it.

Each case runs the real command in-process on small files generated at test
time (and copies of the real data in ../shared/data where a case needs them)
and checks what the user sees and what is left on disk:

- the exit code: 2 for a usage or input error, 1 for a runtime failure;
- one line on stderr, naming the problem (a fragment of it is checked);
- no traceback (a raw exception fails the test);
- no input changed (sha256 of every file in the workspace before and after);
- no partial output (no file appears in the workspace).

The counts of the closing note come from ``test_corpus_counts``.
"""

from __future__ import annotations

import hashlib
import json
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from clsim.cli.app import main as clsim_main
from tlsvox.cli.app import main as tlsvox_main

pytest.importorskip("open3d")
REAL = Path(__file__).resolve().parents[2] / "shared" / "data"


@dataclass(frozen=True)
class Case:
    tool: str  # "tlsvox" or "clsim"
    argv: tuple  # with "{d}" for the workspace folder
    code: int  # expected exit code
    says: str  # a fragment of the one error line (case-insensitive)
    needs_real: bool = False


def T(argv, says, code=2, real=False):
    return Case("tlsvox", tuple(argv.split()), code, says, real)


def C(argv, says, code=2, real=False):
    return Case("clsim", tuple(argv.split()), code, says, real)


SIM = "simulate {d}/scene.npz --photons 100 -q"
VOX = "voxelize {d}/s1.laz {d}/s2.laz -q"
DEC = "decompose {d}/return.csv"
GEO = "georegister {d}/tls.npy {d}/als.npy"

CASES = {
    # ---- clsim simulate: the scene
    "simulate: scene missing": C("simulate {d}/nope.npz -o {d}/out/w.npz", "does not exist"),
    "simulate: scene is text": C("simulate {d}/notnpz.npz -o {d}/out/w.npz", "not a readable npz"),
    "simulate: scene lacks keys": C("simulate {d}/keys.npz -o {d}/out/w.npz", "missing keys"),
    "simulate: scene is a folder": C("simulate {d}/out -o {d}/out/w.npz", "scene"),
    "simulate: scene is a LAS file": C("simulate {d}/s1.laz -o {d}/out/w.npz", "scene"),
    "simulate: .vox with a bad header": C("simulate {d}/bad.vox -o {d}/out/w.npz", "vox"),
    "simulate: .vox with negative PAD": C("simulate {d}/neg.vox -o {d}/out/w.npz", "negative"),
    "simulate: .vox empty": C("simulate {d}/empty.vox -o {d}/out/w.npz", "vox"),
    # ---- clsim survey
    "survey: scene missing": C("survey {d}/nope.npz -o {d}/out/sv -q", "does not exist"),
    "survey: scene is text": C("survey {d}/notnpz.npz -o {d}/out/sv -q", "not a readable npz"),
    "survey: photons 0": C("survey {d}/scene.npz -o {d}/out/sv --photons 0 -q", "--photons"),
    "survey: workers negative": C("survey {d}/scene.npz -o {d}/out/sv --workers -1 -q", "--workers"),
    "survey: start not X,Y": C("survey {d}/scene.npz -o {d}/out/sv --start 3 -q", "--start"),
    "survey: start equals end": C("survey {d}/scene.npz -o {d}/out/sv --start 1,1 --end 1,1 -q", "same point"),
    "survey: more pulses than the line": C("survey {d}/scene.npz -o {d}/out/sv --pulses 100000000 -q",
                                           "do not fit the trajectory"),
    "survey: sensor unknown": C("survey {d}/scene.npz -o {d}/out/sv --sensor nope -q", "nope"),
    "survey: pulses and duration": C("survey {d}/scene.npz -o {d}/out/sv --pulses 5 --duration 1 -q",
                                     "not allowed with"),
    # ---- clsim simulate: the numbers
    "simulate: photons 0": C(SIM + " --photons 0 -o {d}/out/w.npz", "photons"),
    "simulate: photons negative": C(SIM + " --photons -5 -o {d}/out/w.npz", "photons"),
    "simulate: photons not a number": C(SIM + " --photons many -o {d}/out/w.npz", "--photons"),
    "simulate: photons 1e12": C(SIM + " --photons 1000000000000 -o {d}/out/w.npz", "photons"),
    "simulate: seed negative": C(SIM + " --seed -1 -o {d}/out/w.npz", "seed"),
    "simulate: seed not an integer": C(SIM + " --seed 1.5 -o {d}/out/w.npz", "--seed"),
    "simulate: max order 0": C(SIM + " --max-order 0 -o {d}/out/w.npz", "max_order"),
    "simulate: max order 1000": C(SIM + " --max-order 1000 -o {d}/out/w.npz", "max_order"),
    "simulate: mode unknown": C(SIM + " --mode exakt -o {d}/out/w.npz", "--mode"),
    "simulate: detect unknown": C(SIM + " --detect magic -o {d}/out/w.npz", "--detect"),
    "simulate: sensor unknown": C(SIM + " --sensor leica-xyz -o {d}/out/w.npz", "sensor preset"),
    "simulate: sensor file missing": C(SIM + " --sensor {d}/nope.toml -o {d}/out/w.npz", "sensor"),
    "simulate: sensor file is not TOML": C(SIM + " --sensor {d}/bad.toml -o {d}/out/w.npz", "toml"),
    "simulate: off-nadir 95": C(SIM + " --off-nadir 95 -o {d}/out/w.npz", "off_nadir"),
    "simulate: off-nadir nan": C(SIM + " --off-nadir nan -o {d}/out/w.npz", "off_nadir"),
    "simulate: fov negative": C(SIM + " --fov -1 -o {d}/out/w.npz", "fov"),
    "simulate: batches 0": C(SIM + " --batches 0 -o {d}/out/w.npz", "batches"),
    "simulate: trace negative": C(SIM + " --trace -3 -o {d}/out/w.npz", "trace"),
    "simulate: target one number": C(SIM + " --target 1 -o {d}/out/w.npz", "--target"),
    "simulate: target words": C(SIM + " --target a,b -o {d}/out/w.npz", "--target"),
    "simulate: target nan": C(SIM + " --target nan,0 -o {d}/out/w.npz", "--target"),
    "simulate: targets file missing": C(SIM + " -o {d}/out/w.npz --targets {d}/nope.csv", "does not exist"),
    "simulate: targets file of words": C(SIM + " -o {d}/out/w.npz --targets {d}/text.csv", "--targets"),
    "simulate: targets file empty": C(SIM + " -o {d}/out/w.npz --targets {d}/empty.csv", "no target"),
    "simulate: targets with --target": C(SIM + " -o {d}/out/w.npz --targets {d}/impulse.csv --target 0,0", "--target"),
    "simulate: -o equals the targets file": C(SIM + " -o {d}/impulse.csv --targets {d}/impulse.csv", ".npz"),
    "simulate: trace-plot without trace": C(SIM + " -o {d}/out/w.npz --trace-plot {d}/out/t.png", "--trace"),
    "simulate: plot suffix unknown": C(SIM + " -o {d}/out/w.npz --plot {d}/out/w.bmpx", "picture"),
    "simulate: output suffix not npz": C(SIM + " -o {d}/out/w.txt", ".npz"),
    # ---- clsim simulate: outputs onto inputs
    "simulate: -o equals the scene": C(SIM + " -o {d}/scene.npz", "nothing was written"),
    "simulate: --plot equals the scene": C(SIM + " -o {d}/out/w.npz --plot {d}/scene.npz", "nothing was written"),
    "simulate: --plot equals -o": C(SIM + " -o {d}/out/w.npz --plot {d}/out/w.npz", "nothing was written"),
    "simulate: -o through ..": C(SIM + " -o {d}/out/../scene.npz", "nothing was written"),
    "simulate: -o is a folder": C(SIM + " -o {d}/out", ".npz"),
    "simulate: --trace-plot equals -o": C(SIM + " --trace 4 -o {d}/out/w.npz --trace-plot {d}/out/w.npz",
                                          "nothing was written"),
    # ---- clsim decompose
    "decompose: file missing": C("decompose {d}/nope.las -o {d}/out/e.csv", "does not exist"),
    "decompose: unknown suffix": C("decompose {d}/x.txt -o {d}/out/e.csv", "unknown waveform file type"),
    "decompose: zero-byte LAS": C("decompose {d}/zero.las -o {d}/out/e.csv", "las"),
    "decompose: text named .las": C("decompose {d}/notlas.las -o {d}/out/e.csv", "las"),
    "decompose: zero-byte LAZ": C("decompose {d}/zero.laz -o {d}/out/e.csv", "la"),
    "decompose: CSV of words": C("decompose {d}/text.csv -o {d}/out/e.csv", "csv"),
    "decompose: empty CSV": C("decompose {d}/empty.csv -o {d}/out/e.csv", "csv"),
    "decompose: CSV with NaN": C("decompose {d}/nan.csv -o {d}/out/e.csv", "nan"),
    "decompose: -o equals input": C(DEC + " -o {d}/return.csv", "nothing was written"),
    "decompose: --plot equals input": C(DEC + " -o {d}/out/e.csv --plot {d}/return.csv", "nothing was written"),
    "decompose: --plot equals -o": C(DEC + " -o {d}/out/e.csv --plot {d}/out/e.csv", "nothing was written"),
    "decompose: -o through ..": C(DEC + " -o {d}/out/../return.csv", "nothing was written"),
    "decompose: --plot suffix unknown": C(DEC + " -o {d}/out/e.csv --plot {d}/out/p.gif", "picture"),
    "decompose: limit negative": C(DEC + " -o {d}/out/e.csv --limit -3", "limit"),
    "decompose: limit zero": C(DEC + " -o {d}/out/e.csv --limit 0", "limit"),
    "decompose: limit words": C(DEC + " -o {d}/out/e.csv --limit all", "--limit"),
    "decompose: dt 0": C(DEC + " -o {d}/out/e.csv --dt-ns 0", "dt"),
    "decompose: dt negative": C(DEC + " -o {d}/out/e.csv --dt-ns -1", "dt"),
    "decompose: dt nan": C(DEC + " -o {d}/out/e.csv --dt-ns nan", "dt"),
    "decompose: false alarm 2": C(DEC + " -o {d}/out/e.csv --false-alarm 2", "false"),
    "decompose: false alarm 0": C(DEC + " -o {d}/out/e.csv --false-alarm 0", "false"),
    "decompose: detection unknown": C(DEC + " -o {d}/out/e.csv --detection psychic", "--detection"),
    "decompose: pulse sigma negative": C(DEC + " -o {d}/out/e.csv --pulse-sigma-ns -2", "sigma"),
    "decompose: min amplitude nan": C(DEC + " -o {d}/out/e.csv --min-amplitude nan", "amplitude"),
    "decompose: plot count negative": C(DEC + " -o {d}/out/e.csv --plot {d}/out/p.png --plot-count -1", "count"),
    "decompose: impulse missing": C(DEC + " -o {d}/out/e.csv --impulse {d}/nope.csv", "does not exist"),
    "decompose: impulse is a folder": C(DEC + " -o {d}/out/e.csv --impulse {d}/out", "folder"),
    "decompose: impulse of words": C(DEC + " -o {d}/out/e.csv --impulse {d}/text.csv", "impulse"),
    "decompose: impulse all zero": C(DEC + " -o {d}/out/e.csv --impulse {d}/zeros.csv", "impulse"),
    "decompose: batch with impulse": C(DEC + " -o {d}/out/e.csv --batch --impulse {d}/impulse.csv", "batch"),
    "decompose: batch with min amplitude": C(DEC + " -o {d}/out/e.csv --batch --min-amplitude 10", "batch"),
    "decompose: geolocation missing": C(DEC + " -o {d}/out/e.csv --geolocation {d}/nope.csv", "does not exist"),
    "decompose: geolocation of words": C(DEC + " -o {d}/out/e.csv --geolocation {d}/text.csv", "geolocation"),
    "decompose: output suffix not csv": C(DEC + " -o {d}/out/e.npz", ".csv"),
    "decompose: LAS with a 0-byte .wdp": C("decompose {d}/zerowdp/fwf.las -o {d}/out/e.csv", "wdp", real=True),
    "decompose: LAS without its .wdp": C("decompose {d}/nowdp/fwf.las -o {d}/out/e.csv", "wdp", real=True),
    "decompose: LASzip waveform file": C("decompose {d}/real/fwf.laz -o {d}/out/e.csv", "laz", real=True),
    "decompose: real LAS -o onto .wdp": C("decompose {d}/real/fwf.las -o {d}/real/fwf.wdp", ".csv", real=True),
    "decompose: real LAS -o onto .wdp as CSV": C("decompose {d}/real/fwf.las -o {d}/real/fwf.wdp.csv --plot "
                                                 "{d}/real/fwf.wdp", "nothing was written", real=True),
    # ---- clsim waveforms info
    "info: file missing": C("waveforms info {d}/nope.las", "does not exist"),
    "info: zero-byte LAS": C("waveforms info {d}/zero.las", "las"),
    "info: text named .las": C("waveforms info {d}/notlas.las", "las"),
    "info: unknown suffix": C("waveforms info {d}/x.txt", "unknown waveform file type"),
    "info: a point cloud LAS without waveforms": C("waveforms info {d}/s1.laz", "waveform"),
    "info: no file": C("waveforms info", "required"),
    # ---- clsim georegister (same as tlsvox georegister)
    "clsim georegister: source missing": C("georegister {d}/nope.npy {d}/als.npy -o {d}/out/t.json",
                                           "does not exist"),
    "clsim georegister: -o equals source": C(GEO + " -o {d}/tls.npy", "nothing was written"),
    # ---- clsim other commands
    "clsim: no command": C("", "required"),
    "clsim: unknown command": C("simulat {d}/scene.npz", "invalid choice"),
    "clsim: unknown option": C(SIM + " -o {d}/out/w.npz --photon 5", "unrecognized"),
    "bench: photons 0": C("bench --photons 0", "photons"),
    "bench: repeats 0": C("bench --repeats 0", "repeats"),
    "bench: photons words": C("bench --photons lots", "--photons"),
    # ---- tlsvox tree
    "tree: height 0": T("tree -o {d}/out/t.ply --height 0", "height"),
    "tree: height negative": T("tree -o {d}/out/t.ply --height -3", "height"),
    "tree: height nan": T("tree -o {d}/out/t.ply --height nan", "height"),
    "tree: height inf": T("tree -o {d}/out/t.ply --height inf", "height"),
    "tree: crown radius 0": T("tree -o {d}/out/t.ply --crown-radius 0", "crown_radius"),
    "tree: leaf area negative": T("tree -o {d}/out/t.ply --leaf-area -10", "leaf_area"),
    "tree: leaf angle unknown": T("tree -o {d}/out/t.ply --leaf-angle sideways", "leaf_angle"),
    "tree: leaf azimuth unknown": T("tree -o {d}/out/t.ply --leaf-azimuth inward", "--leaf-azimuth"),
    "tree: seed negative": T("tree -o {d}/out/t.ply --seed -1", "seed"),
    "tree: seed words": T("tree -o {d}/out/t.ply --seed one", "--seed"),
    "tree: output suffix": T("tree -o {d}/out/t.obj", ".ply"),
    "tree: -o equals a scan": T("tree -o {d}/s1.laz", "ply"),
    "tree: -o onto the tree JSON of another tree": T("tree -o {d}/oak.json", "ply"),
    "tree: no -o": T("tree", "required"),
    # ---- tlsvox scan
    "scan: tree JSON missing": T("scan {d}/nope.json -o {d}/out/s.laz", "does not exist"),
    "scan: tree JSON broken": T("scan {d}/broken.json -o {d}/out/s.laz", "json"),
    "scan: tree JSON of something else": T("scan {d}/other.json -o {d}/out/s.laz", "tree"),
    "scan: position of two numbers": T("scan {d}/oak.json -o {d}/out/s.laz --position 1 2", "--position"),
    "scan: position nan": T("scan {d}/oak.json -o {d}/out/s.laz --position nan 0 1.7", "position"),
    "scan: yaw nan": T("scan {d}/oak.json -o {d}/out/s.laz --yaw nan", "yaw"),
    "scan: step 0": T("scan {d}/oak.json -o {d}/out/s.laz --step 0", "step"),
    "scan: step negative": T("scan {d}/oak.json -o {d}/out/s.laz --step -0.1", "step"),
    "scan: step too fine for memory": T("scan {d}/oak.json -o {d}/out/s.laz --step 0.00001", "step"),
    "scan: preset unknown": T("scan {d}/oak.json -o {d}/out/s.laz --preset riegl-vz9000", "preset"),
    "scan: output suffix": T("scan {d}/oak.json -o {d}/out/s.ply", ".las"),
    "scan: -o equals the tree JSON": T("scan {d}/oak.json -o {d}/oak.json", ".las"),
    "scan: -o equals the tree PLY": T("scan {d}/oak.json -o {d}/oak.ply", ".las"),
    "scan: -o in capitals .JSON": T("scan {d}/oak.json -o {d}/OAK.JSON", ".las"),
    "scan: scan id negative": T("scan {d}/oak.json -o {d}/out/s.laz --scan-id -2", "--scan-id"),
    "scan: scan id too large for LAS": T("scan {d}/oak.json -o {d}/out/s.laz --scan-id 70000", "--scan-id"),
    "scan: position inside the trunk": T("scan {d}/oak.json -o {d}/out/s.laz --position 0 0 1", "inside"),
    # ---- tlsvox view
    "view: file missing": T("view {d}/nope.laz --screenshot {d}/out/v.png", "does not exist"),
    "view: zero-byte LAZ": T("view {d}/zero.laz --screenshot {d}/out/v.png", "la"),
    "view: text named .las": T("view {d}/notlas.las --screenshot {d}/out/v.png", "las"),
    "view: unknown suffix": T("view {d}/x.txt --screenshot {d}/out/v.png", "unknown file type"),
    "view: screenshot suffix": T("view {d}/s1.laz --screenshot {d}/out/v.bmp", "picture"),
    "view: screenshot equals scan": T("view {d}/s1.laz --screenshot {d}/s1.laz", "nothing was written"),
    "view: screenshot equals sidecar": T("view {d}/s1.laz --screenshot {d}/s1.pose.json", "nothing was written"),
    "view: material colours without truth": T("view {d}/plain.las --color material --screenshot {d}/out/v.png",
                                              "truth_material"),
    "view: colour unknown": T("view {d}/s1.laz --color rainbow --screenshot {d}/out/v.png", "--color"),
    "view: point size 0": T("view {d}/s1.laz --point-size 0 --screenshot {d}/out/v.png", "point"),
    "view: empty PLY": T("view {d}/empty.ply --screenshot {d}/out/v.png", "no points"),
    # ---- tlsvox register
    "register: one scan": T("register {d}/s1.laz -o {d}/out/m.laz", "at least 2"),
    "register: a scan missing": T("register {d}/s1.laz {d}/nope.laz -o {d}/out/m.laz", "does not exist"),
    "register: zero-byte scan": T("register {d}/s1.laz {d}/zero.laz -o {d}/out/m.laz", "la"),
    "register: text named .las": T("register {d}/s1.laz {d}/notlas.las -o {d}/out/m.laz", "las"),
    "register: the same scan twice": T("register {d}/s1.laz {d}/s1.laz -o {d}/out/m.laz", "twice"),
    "register: -o equals a scan": T("register {d}/s1.laz {d}/s2.laz -o {d}/s1.laz", "nothing was written"),
    "register: transforms equal a sidecar": T("register {d}/s1.laz {d}/s2.laz -o {d}/out/m.laz --transforms "
                                              "{d}/s2.pose.json", "nothing was written"),
    "register: -o equals the transforms": T("register {d}/s1.laz {d}/s2.laz -o {d}/out/m.laz --transforms "
                                            "{d}/out/m.laz", "nothing was written"),
    "register: output suffix": T("register {d}/s1.laz {d}/s2.laz -o {d}/out/m.ply", ".las"),
    "register: min fitness 2": T("register {d}/s1.laz {d}/s2.laz -o {d}/out/m.laz --min-fitness 2", "fitness"),
    "register: min fitness negative": T("register {d}/s1.laz {d}/s2.laz -o {d}/out/m.laz --min-fitness -1",
                                        "fitness"),
    "register: method unknown": T("register {d}/s1.laz {d}/s2.laz -o {d}/out/m.laz --method magic", "--method"),
    "register: targets where there are none": T("register {d}/s1.laz {d}/s2.laz -o {d}/out/m.laz --method targets",
                                                "target", code=1),
    # ---- tlsvox classify
    "classify: scan missing": T("classify {d}/nope.laz -o {d}/out/c", "does not exist"),
    "classify: scan without reflectance": T("classify {d}/plain.las -o {d}/out/c", "reflectance"),
    "classify: zero-byte scan": T("classify {d}/zero.laz -o {d}/out/c", "la"),
    "classify: -o is a scan file": T("classify {d}/s1.laz -o {d}/s2.laz", "nothing was written"),
    "classify: -o is the input scan": T("classify {d}/s1.laz -o {d}/s1.laz", "nothing was written"),
    "classify: --plot equals the scan": T("classify {d}/s1.laz -o {d}/out/c --plot {d}/s1.laz", "nothing was written"),
    "classify: --plot suffix": T("classify {d}/s1.laz -o {d}/out/c --plot {d}/out/h.tiff", "picture"),
    "classify: method unknown": T("classify {d}/s1.laz -o {d}/out/c --method guess", "--method"),
    "classify: rule unknown": T("classify {d}/s1.laz -o {d}/out/c --rule coin", "--rule"),
    # ---- tlsvox voxelize: numbers
    "voxelize: voxel size 0": T(VOX + " -o {d}/out/v.npz --voxel-size 0", "voxel"),
    "voxelize: voxel size negative": T(VOX + " -o {d}/out/v.npz --voxel-size -0.2", "voxel"),
    "voxelize: voxel size nan": T(VOX + " -o {d}/out/v.npz --voxel-size nan", "voxel"),
    "voxelize: voxel size inf": T(VOX + " -o {d}/out/v.npz --voxel-size inf", "voxel"),
    "voxelize: voxel size 1e6": T(VOX + " -o {d}/out/v.npz --voxel-size 1e6", "voxel"),
    "voxelize: voxel size words": T(VOX + " -o {d}/out/v.npz --voxel-size fine", "--voxel-size"),
    "voxelize: voxel size needs 1 TB": T(VOX + " -o {d}/out/v.npz --voxel-size 0.0001", "needs"),
    "voxelize: max range negative": T(VOX + " -o {d}/out/v.npz --max-range -5", "max"),
    "voxelize: max range 0": T(VOX + " -o {d}/out/v.npz --max-range 0", "max"),
    "voxelize: n-min negative": T(VOX + " -o {d}/out/v.npz --n-min -1", "n_min"),
    "voxelize: min explored 2": T(VOX + " -o {d}/out/v.npz --min-explored 2", "min_explored"),
    "voxelize: leaf size 0": T(VOX + " -o {d}/out/v.npz --leaf-size 0", "leaf_size"),
    "voxelize: small voxel factor negative": T(VOX + " -o {d}/out/v.npz --small-voxel-factor -1", "small"),
    "voxelize: ground nan": T(VOX + " -o {d}/out/v.npz --ground nan", "ground"),
    "voxelize: ground words": T(VOX + " -o {d}/out/v.npz --ground low", "ground"),
    "voxelize: bounds of 5 numbers": T(VOX + " -o {d}/out/v.npz --bounds 0,0,0,1,1", "bounds"),
    "voxelize: bounds inverted": T(VOX + " -o {d}/out/v.npz --bounds 1,1,1,0,0,0", "bounds"),
    "voxelize: bounds words": T(VOX + " -o {d}/out/v.npz --bounds a,b,c,d,e,f", "bounds"),
    "voxelize: bounds miss the scans": T(VOX + " -o {d}/out/v.npz --bounds 100,100,100,101,101,101", "bounds"),
    "voxelize: estimator unknown": T(VOX + " -o {d}/out/v.npz --estimator guess", "--estimator"),
    "voxelize: leaf angle unknown": T(VOX + " -o {d}/out/v.npz --leaf-angle sideways", "--leaf-angle"),
    "voxelize: wood unknown": T(VOX + " -o {d}/out/v.npz --wood logs", "--wood"),
    "voxelize: fill unknown": T(VOX + " -o {d}/out/v.npz --fill all", "--fill"),
    "voxelize: angular grid words": T(VOX + " -o {d}/out/v.npz --angular-grid fine", "angular"),
    "voxelize: angular grid negative": T(VOX + " -o {d}/out/v.npz --angular-grid -0.06,0.06", "angular"),
    "voxelize: scanner rpy of two": T(VOX + " -o {d}/out/v.npz --scanner-rpy 1,2", "rpy"),
    "voxelize: device unknown": T(VOX + " -o {d}/out/v.npz --device quantum", "device", code=1),
    # ---- tlsvox voxelize: files
    "voxelize: a scan missing": T("voxelize {d}/s1.laz {d}/nope.laz -o {d}/out/v.npz", "does not exist"),
    "voxelize: zero-byte scan": T("voxelize {d}/zero.laz -o {d}/out/v.npz", "la"),
    "voxelize: text named .las": T("voxelize {d}/notlas.las -o {d}/out/v.npz", "las"),
    "voxelize: scan without pose": T("voxelize {d}/nopose.laz -o {d}/out/v.npz", "pose"),
    "voxelize: -o equals a scan": T(VOX + " -o {d}/s1.laz", "nothing was written"),
    "voxelize: -o equals the pulse table": T(VOX + " -o {d}/s1.pulses.npz", "nothing was written"),
    "voxelize: -o equals a pose": T(VOX + " -o {d}/s2.pose.json", "nothing was written"),
    "voxelize: --vox equals a scan": T(VOX + " -o {d}/out/v.npz --vox {d}/s1.laz", "nothing was written"),
    "voxelize: --vox equals -o": T(VOX + " -o {d}/out/v.npz --vox {d}/out/v.npz", "nothing was written"),
    "voxelize: -o through ..": T(VOX + " -o {d}/out/../s1.laz", "nothing was written"),
    "voxelize: output suffix": T(VOX + " -o {d}/out/v.vox", ".npz"),
    "voxelize: --vox suffix": T(VOX + " -o {d}/out/v.npz --vox {d}/out/v.txt", ".vox"),
    "voxelize: transforms missing": T(VOX + " -o {d}/out/v.npz --transforms {d}/nope.json", "does not exist"),
    "voxelize: transforms broken JSON": T(VOX + " -o {d}/out/v.npz --transforms {d}/broken.json", "json"),
    "voxelize: transforms of other scans": T(VOX + " -o {d}/out/v.npz --transforms {d}/othertransforms.json",
                                             "no pose for scan"),
    "voxelize: transforms equal -o": T(VOX + " -o {d}/out/v.npz --transforms {d}/out/v.npz", "nothing was written"),
    "voxelize: the same scan twice": T("voxelize {d}/s1.laz {d}/s1.laz -o {d}/out/v.npz", "twice"),
    "voxelize: no scans": T("voxelize -o {d}/out/v.npz", "required"),
    "voxelize: echo weights unknown": T(VOX + " -o {d}/out/v.npz --echo-weights half", "--echo-weights"),
    "voxelize: undetected unknown": T(VOX + " -o {d}/out/v.npz --undetected maybe", "--undetected"),
    "voxelize: leaf shape of one number": T(VOX + " -o {d}/out/v.npz --undetected model --leaf-shape 5",
                                            "--leaf-shape"),
    "voxelize: leaf reflectance 0": T(VOX + " -o {d}/out/v.npz --echo-weights threshold --leaf-reflectance 0",
                                      "leaf reflectance"),
    "voxelize: scan origin with a LAS": T(VOX + " -o {d}/out/v.npz --scan-origin 0,0,0", "--scan-origin"),
    "voxelize: scan origin of two": T("voxelize {d}/pulses.txt -o {d}/out/v.npz --scan-origin 1,2", "--scan-origin"),
    "voxelize: bare xyz cloud": T("voxelize {d}/cloud.xyz --scanner-frame -o {d}/out/v.npz", "bare xyz"),
    "voxelize: pulse text, miss rows without direction": T("voxelize {d}/nanmiss.txt --scanner-frame -o {d}/out/v.npz",
                                                           "direction is unknown"),
    "voxelize: pulse text, counts disagree": T("voxelize {d}/badcount.txt --scanner-frame -o {d}/out/v.npz",
                                               "disagree on the return count"),
    "voxelize: pulse text, ragged rows": T("voxelize {d}/ragged.txt --scanner-frame -o {d}/out/v.npz", "columns"),
    # ---- tlsvox georegister
    "georegister: source missing": T("georegister {d}/nope.npy {d}/als.npy -o {d}/out/t.json", "does not exist"),
    "georegister: target missing": T("georegister {d}/tls.npy {d}/nope.npy -o {d}/out/t.json", "does not exist"),
    "georegister: source of 3 points": T("georegister {d}/few.npy {d}/als.npy -o {d}/out/t.json", "points"),
    "georegister: source with NaN": T("georegister {d}/nanpts.npy {d}/als.npy -o {d}/out/t.json", "nan"),
    "georegister: source of wrong shape": T("georegister {d}/flat.npy {d}/als.npy -o {d}/out/t.json", "shape"),
    "georegister: source suffix unknown": T("georegister {d}/x.txt {d}/als.npy -o {d}/out/t.json",
                                            "unknown point cloud type"),
    "georegister: -o equals source": T(GEO + " -o {d}/tls.npy", "nothing was written"),
    "georegister: --output-cloud equals target": T(GEO + " -o {d}/out/t.json --output-cloud {d}/als.npy",
                                                   "nothing was written"),
    "georegister: --output-cloud suffix": T(GEO + " -o {d}/out/t.json --output-cloud {d}/out/c.las", "output-cloud"),
    "georegister: init of 3 numbers": T(GEO + " -o {d}/out/t.json --init 1,2,3", "init"),
    "georegister: init words": T(GEO + " -o {d}/out/t.json --init a,b,c,d", "init"),
    "georegister: init file missing": T(GEO + " -o {d}/out/t.json --init {d}/nope.json", "init"),
    "georegister: init file broken": T(GEO + " -o {d}/out/t.json --init {d}/broken.json", "init"),
    "georegister: yaw range negative": T(GEO + " -o {d}/out/t.json --yaw-range -5", "yaw"),
    "georegister: yaw step 0": T(GEO + " -o {d}/out/t.json --yaw-step 0", "yaw"),
    "georegister: voxel size 0": T(GEO + " -o {d}/out/t.json --voxel-size 0", "voxel"),
    "georegister: unrelated clouds": T("georegister {d}/tls.npy {d}/far.npy -o {d}/out/t.json --yaw-range 0",
                                       "fitness", code=1),
    # ---- tlsvox in general
    "tlsvox: no command": T("", "required"),
    "tlsvox: unknown command": T("voxelise {d}/s1.laz", "invalid choice"),
    "tlsvox: unknown option": T(VOX + " -o {d}/out/v.npz --voxelsize 0.2", "unrecognized"),
}


def sha_tree(d: Path) -> dict:
    return {p.relative_to(d).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(d.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def ws(tmp_path_factory):
    """The workspace: small generated inputs of every kind, and copies of the real waveform file."""
    from clsim.validation.testscenes import homogeneous_layer
    from tlsvox.scan import Scan
    from tlsvox.truth.scanner import ScannerPreset, ScanPose, simulate_scan
    from tlsvox.truth.synthetic import make_leaf_slab
    from tlsvox.voxel.amapvox import write_vox

    d = tmp_path_factory.mktemp("corpus")
    (d / "out").mkdir()
    scene = homogeneous_layer(width=4.0, voxel_size=0.5)
    scene.save(d / "scene.npz")
    write_vox(scene, d / "scene.vox")
    lines = (d / "scene.vox").read_text().splitlines()
    first = next(i for i, line in enumerate(lines) if line.split()[:3] == ["0", "0", "4"])
    cells = lines[first].split()
    cells[3] = "-1"
    lines[first] = " ".join(cells)
    (d / "neg.vox").write_text("\n".join(lines) + "\n")
    (d / "bad.vox").write_text("this is not a voxel space\n1 2 3\n")
    (d / "empty.vox").write_text("")
    (d / "notnpz.npz").write_text("not a zip archive")
    np.savez(d / "keys.npz", a=np.zeros(3))
    (d / "bad.toml").write_text("this = is = not toml [\n")
    box = make_leaf_slab(lad=1.0, size=(1.0, 1.0, 1.0), origin=(-0.5, -0.5, 1.0), seed=3)
    preset = ScannerPreset.riegl_vz400(zenith_step_deg=0.4, azimuth_step_deg=0.4, n_subrays=1)
    for i, x in enumerate((-5.0, 5.0)):
        scan = simulate_scan(box, pose=ScanPose(position=(x, 0.0, 1.7)), preset=preset, seed=i, progress=False,
                             name=f"s{i + 1}")
        scan.pose = scan.pose_true
        scan.write(d / f"s{i + 1}.laz")
        if i == 0:
            scan.pose, scan.pose_true, scan.name = None, None, "nopose"
            scan.write(d / "nopose.laz")
    Scan(xyz=np.random.default_rng(0).normal(size=(200, 3)), name="plain").write(d / "plain.las")
    for name, text in (("zero.las", ""), ("zero.laz", ""), ("notlas.las", "hello, I am not a LAS file\n"),
                       ("x.txt", "1,2,3\n"), ("text.csv", "a,b,c\nfoo,bar\n"), ("empty.csv", ""),
                       ("nan.csv", "10,12,nan,90,40,12,10\n"), ("zeros.csv", "0\n0\n0\n0\n"),
                       ("impulse.csv", "0.1\n0.5\n1.0\n0.5\n0.1\n"), ("broken.json", "{\"scans\": [\n"),
                       ("other.json", json.dumps({"hello": "world"})), ("empty.ply", "")):
        (d / name).write_text(text)
    (d / "pulses.txt").write_text("3 0 0 0.1 1 2\n5 0 0 0.1 2 2\n0 9e6 0 0.2 0 0\n4 1 0 0.3 1 1\n")
    (d / "nanmiss.txt").write_text("3 0 0 0.1 1 1\nnan nan nan 0.2 0 0\n")
    (d / "badcount.txt").write_text("3 0 0 0.1 1 2\n5 0 0 0.1 2 3\n")
    (d / "ragged.txt").write_text("3 0 0 0.1 1 1\n5 0 0 0.2 1\n")
    (d / "cloud.xyz").write_text("1 2 3\n2 3 4\n3 4 5\n")
    (d / "othertransforms.json").write_text(json.dumps({"scans": [{"name": "elsewhere", "pose": np.eye(4).tolist()}]}))
    rng = np.random.default_rng(1)
    t = np.linspace(0, 60, 120)
    rows = [10 + 80 * np.exp(-0.5 * ((t - 30 + k) / 2.0) ** 2) + rng.normal(0, 1, t.size) for k in range(5)]
    (d / "return.csv").write_text("\n".join(",".join(f"{v:.2f}" for v in r) for r in rows) + "\n")
    tls = rng.uniform(-5, 5, (3000, 3))
    np.save(d / "tls.npy", tls)
    np.save(d / "als.npy", tls[::3] + [100.0, 50.0, 0.0])
    np.save(d / "far.npy", rng.normal(size=(2000, 3)) * [0.01, 40.0, 0.01] + [500.0, 0.0, 0.0])
    np.save(d / "few.npy", tls[:3])
    np.save(d / "flat.npy", tls[:, :2])
    nanpts = tls.copy()
    nanpts[5, 1] = np.nan
    np.save(d / "nanpts.npy", nanpts)
    assert tlsvox_main(["tree", "-o", str(d / "oak.ply"), "--height", "4", "--crown-radius", "1.2",
                        "--leaf-area", "5", "--seed", "2"]) == 0
    if (REAL / "leica-fwf-las13" / "fwf.las").exists():
        src = REAL / "leica-fwf-las13"
        for sub, files in (("real", ("fwf.las", "fwf.wdp", "fwf.laz")), ("zerowdp", ("fwf.las",)),
                           ("nowdp", ("fwf.las",))):
            (d / sub).mkdir()
            for f in files:
                shutil.copy(src / f, d / sub / f)
        (d / "zerowdp" / "fwf.wdp").write_text("")
    return d


def _run(case: Case, d: Path, capsys):
    argv = [a.replace("{d}", str(d)) for a in case.argv]
    main = tlsvox_main if case.tool == "tlsvox" else clsim_main
    try:
        code = main(argv)
    except SystemExit as stop:  # argparse: usage errors
        code = stop.code
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    return code, err


@pytest.mark.parametrize("name", sorted(CASES))
def test_bad_input(name, ws, capsys):
    case = CASES[name]
    if case.needs_real and not (ws / "real").exists():
        pytest.skip(f"real data absent: {REAL / 'leica-fwf-las13'}")
    before = sha_tree(ws)
    code, err = _run(case, ws, capsys)
    after = sha_tree(ws)
    assert after == before, f"files changed or appeared: {sorted(set(after.items()) ^ set(before.items()))}"
    assert code == case.code, (code, err)
    assert len(err) == 1, err
    assert "Traceback" not in err[0]
    assert case.says.lower() in err[0].lower(), err[0]


def test_corpus_counts():
    """At least 175 cases, across every command of both tools."""
    tools = {(c.tool, next((a for a in c.argv if not a.startswith("{")), "")) for c in CASES.values()}
    assert len(CASES) >= 175, len(CASES)
    commands = {cmd for _, cmd in tools}
    for cmd in ("tree", "scan", "view", "register", "classify", "voxelize", "georegister", "simulate",
                "decompose", "waveforms", "bench"):
        assert cmd in commands, cmd

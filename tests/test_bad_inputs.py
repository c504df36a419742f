"""The bad-input corpus: every entry point given what a user might wrongly give it.

Each case runs the real command in-process on small files generated at test
time (and copies of the real data in ../shared/data where a case needs them)
and checks what the user sees and what is left on disk:

- the exit code: 2 for a usage or input error, 1 for a runtime failure;
- one line on stderr, naming the problem (a fragment of it is checked);
- no traceback (a raw exception fails the test);
- no input changed (sha256 of every file in the workspace before and after);
- no partial output (no file appears in the workspace).

The cases are the lines of ``tests/bad_inputs.txt``.  The counts of the closing note come from ``test_corpus_counts``.
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


CORPUS = Path(__file__).with_name("bad_inputs.txt")


def read_corpus(path: Path = CORPUS) -> dict:
    """The cases of ``path`` by name (format: its header)."""
    cases = {}
    for n, line in enumerate(path.read_text().splitlines(), 1):
        if not line.strip() or line.startswith("#"):
            continue
        tool, name, code, says, argv, *flags = (cell.strip() for cell in line.split("|"))
        assert tool in ("tlsvox", "clsim") and name not in cases and flags in ([], ["real"]), f"{path}:{n}: {line}"
        cases[name] = Case(tool, tuple(argv.split()), int(code), says, flags == ["real"])
    return cases


CASES = read_corpus()


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
                       ("x.txt", "1,2,3\n"), ("x.dat", "1,2,3\n"),
                       ("fw_short.txt", "1 0 0 100 0 0 -1 300 304\n"),
                       ("fw_nan.txt", "1 0 0 100 0 0 -1 300 304 12.5 0 nan 1\n"),
                       ("fw_dir.txt", "1 0 0 100 0 0 -3 300 304 12.5 0 1 1\n"),
                       ("text.csv", "a,b,c\nfoo,bar\n"), ("empty.csv", ""),
                       ("nan.csv", "10,12,nan,90,40,12,10\n"),
                       ("badcell.csv", "1,2,3,4,5\n1,2,x3,4,5\n"), ("zeros.csv", "0\n0\n0\n0\n"),
                       ("impulse.csv", "0.1\n0.5\n1.0\n0.5\n0.1\n"), ("broken.json", "{\"scans\": [\n"),
                       ("other.json", json.dumps({"hello": "world"})), ("empty.ply", "")):
        (d / name).write_text(text)
    (d / "pulses.txt").write_text("3 0 0 0.1 1 2\n5 0 0 0.1 2 2\n0 9e6 0 0.2 0 0\n4 1 0 0.3 1 1\n")
    (d / "nanmiss.txt").write_text("3 0 0 0.1 1 1\nnan nan nan 0.2 0 0\n")
    (d / "badcount.txt").write_text("3 0 0 0.1 1 2\n5 0 0 0.1 2 3\n")
    (d / "ragged.txt").write_text("3 0 0 0.1 1 1\n5 0 0 0.2 1\n")
    # other tools' exports gone wrong: a HELIOS++ point row cut short, a pulse of one miss row and two echoes,
    # coordinates in millimetres (every echo kilometres off its ground), a HELIOS++ LAS without its empty pulses
    (d / "helios_cut.xyz").write_text("3.0 0 0 12.5 1.3 1 1 5000 3 0 1000.0\n4.0 0 0 12.5 1.3 1 1 5001 3 0\n")
    (d / "missalone.txt").write_text("3 0 0 0.1 1 1\n4 0 0 0.2 1 1\n5 0 0 0.3 0 1\n")
    (d / "millimetres.txt").write_text("3000 0 0 0.1 1 1\n3100 200 0 0.2 1 1\n2900 -100 50 0.3 1 1\n")
    import laspy

    h = laspy.LasHeader(point_format=6, version="1.4")
    h.add_extra_dims([laspy.ExtraBytesParams("fullwaveIndex", np.int32), laspy.ExtraBytesParams("hitObjectId", np.int32)])
    hl = laspy.LasData(h)
    pts = np.random.default_rng(2).uniform([8, -1, 0], [10, 1, 2], (300, 3))
    hl.x, hl.y, hl.z = pts.T
    hl.return_number, hl.number_of_returns = np.ones(300, np.uint8), np.ones(300, np.uint8)
    hl.fullwaveIndex = np.arange(300, dtype=np.int32)
    hl.write(str(d / "helios.las"))
    (d / "cloud.xyz").write_text("1 2 3\n2 3 4\n3 4 5\n")
    (d / "othertransforms.json").write_text(json.dumps({"scans": [{"name": "elsewhere", "pose": np.eye(4).tolist()}]}))
    rng = np.random.default_rng(1)
    t = np.linspace(0, 60, 120)
    rows = [10 + 80 * np.exp(-0.5 * ((t - 30 + k) / 2.0) ** 2) + rng.normal(0, 1, t.size) for k in range(5)]
    (d / "return.csv").write_text("\n".join(",".join(f"{v:.2f}" for v in r) for r in rows) + "\n")
    head = "index,bin0_x,bin0_y,bin0_z,bin0_dx,bin0_dy,bin0_dz\n"
    for name, dz, n_geo in (("neonup", 0.15, 5), ("neonrows", -0.15, 3)):  # NEON-style folders gone wrong
        (d / name).mkdir()
        shutil.copy(d / "return.csv", d / name / "return.csv")
        (d / name / "geolocation.csv").write_text(head + "".join(f"{i},{i * 0.4},0,330,0,{0.01 * i},{dz}\n"
                                                                 for i in range(n_geo)))
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
    if (REAL / "neon-harvard-waveforms" / "return.csv").exists():
        shutil.copytree(REAL / "neon-harvard-waveforms", d / "neon")
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
                "decompose", "waveforms", "bench", "replay"):
        assert cmd in commands, cmd

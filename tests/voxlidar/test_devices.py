"""The OpenCL device layer (voxlidar.devices): choice, ranking, broken devices, no device.

Two kinds of test.  The choice logic runs on made-up devices whose probe
verdicts are set by the test.  The failure paths run the real commands in a
subprocess against real runtimes made to fail: PoCL (Debian's and PyPI's) reads
extra compiler flags from POCL_EXTRA_BUILD_FLAGS, and an unknown flag makes
every build on it fail the way an unknown CPU does, while Intel's runtime is
untouched.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import voxlidar.devices as vd
from voxlidar.devices import DeviceInfo, choose_device, rank_devices
from voxlidar.errors import DeviceError


def fake(key, platform, version, kind="CPU", cu=2, clock=0, name="dev"):
    return DeviceInfo(key, platform, version, name, kind, "", "", cu, clock, 2**30, 2**28, True, True)


POCL31 = fake("0:0", "Portable Computing Language", "OpenCL 3.0 PoCL 3.1+debian  Linux", name="pthread-haswell")
INTEL = fake("1:0", "Intel(R) OpenCL", "OpenCL 3.1 LINUX", name="AMD EPYC")
POCL_ON_XEON = fake("4:0", "Portable Computing Language", "OpenCL 3.0 PoCL 5.0+debian  Linux",
                    name="cpu-skylake-avx512-Intel(R) Xeon(R) Processor")
POCL30 = fake("2:0", "Portable Computing Language", "OpenCL 3.0 PoCL 3.0-rc2  Linux", name="pthread")
GPU = fake("3:0", "NVIDIA CUDA", "OpenCL 3.0 CUDA 13.0.98", kind="GPU", cu=132, clock=1980, name="NVIDIA H100")
ALL = [POCL30, INTEL, POCL31, GPU]


@pytest.fixture
def verdicts(monkeypatch):
    """Probe verdicts set by the test: {key: reason or None}; unset keys work."""
    table = {}
    monkeypatch.setattr(vd, "probe", lambda info, kernels=("clsim",): {k: table.get(info.key) for k in kernels})
    monkeypatch.delenv("VOXLIDAR_DEVICE", raising=False)
    monkeypatch.delenv("PYOPENCL_CTX", raising=False)
    return table


def test_ranking_gpu_then_newest_pocl_then_intel():
    assert [d.key for d in rank_devices(ALL)] == ["3:0", "0:0", "2:0", "1:0"]
    assert [d.runtime for d in (POCL31, POCL30)] == ["PoCL 3.1+debian", "PoCL 3.0-rc2"]


def test_best_working_device_skips_broken_ones(verdicts):
    assert choose_device(devices=ALL).key == "3:0"
    verdicts["3:0"] = "kernels do not build: error: x"
    verdicts["0:0"] = "kernels do not build: error: unknown target CPU 'generic'"
    assert choose_device(devices=ALL).key == "2:0"


def test_environment_and_argument_order(verdicts, monkeypatch):
    monkeypatch.setenv("PYOPENCL_CTX", "1:0")
    assert choose_device(devices=ALL).key == "1:0"
    monkeypatch.setenv("VOXLIDAR_DEVICE", "pocl")  # wins over PYOPENCL_CTX; best PoCL first
    assert choose_device(devices=ALL).key == "0:0"
    assert choose_device("cpu", devices=ALL).key == "0:0"  # the argument wins over both
    assert choose_device("gpu", devices=ALL).key == "3:0"
    assert choose_device("2", devices=ALL).key == "2:0"  # "2" means "2:0", as in PYOPENCL_CTX
    assert choose_device(INTEL).key == "1:0"
    # "intel" names Intel's runtime, not PoCL running on an Intel CPU (ranked ahead of it)
    assert choose_device("intel", devices=ALL + [POCL_ON_XEON]).key == "1:0"
    assert choose_device("xeon", devices=ALL + [POCL_ON_XEON]).key == "4:0"  # a device name still works


def test_a_broken_device_asked_for_is_one_line_with_reason_and_fix(verdicts, monkeypatch):
    verdicts["0:0"] = "kernels do not build: error: unknown target CPU 'generic'"
    monkeypatch.setenv("VOXLIDAR_DEVICE", "0:0")
    with pytest.raises(DeviceError) as err:
        choose_device(devices=ALL)
    msg = str(err.value)
    assert "\n" not in msg
    assert "VOXLIDAR_DEVICE" in msg and "unknown target CPU 'generic'" in msg and "fix:" in msg
    with pytest.raises(DeviceError, match="not found; available: 3:0"):
        choose_device("no-such-device", devices=ALL)


def test_no_device_or_none_working(verdicts):
    with pytest.raises(DeviceError, match="no OpenCL device found; fix: install a CPU OpenCL runtime"):
        choose_device(devices=[])
    for d in ALL:
        verdicts[d.key] = "kernels do not build: error: boom"
    with pytest.raises(DeviceError) as err:
        choose_device(devices=ALL)
    msg = str(err.value)
    assert msg.startswith("no OpenCL device works") and msg.count("boom") == 4 and "fix:" in msg


def test_probe_verdicts_are_cached_on_disk(tmp_path, monkeypatch):
    """A verdict is computed once per device and kernel set and kept across processes."""
    if not vd.find_devices():
        pytest.skip("no OpenCL device")
    monkeypatch.setenv("VOXLIDAR_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(vd, "_MEMO", {})
    calls = []
    real = vd._run_probe
    monkeypatch.setattr(vd, "_run_probe", lambda info, k: calls.append((info.key, k)) or real(info, k))
    info = vd.find_devices()[0]
    first = vd.probe(info, ("clsim",))
    assert calls == [(info.key, "clsim")]
    monkeypatch.setattr(vd, "_MEMO", {})  # as a new process would start
    assert vd.probe(info, ("clsim",)) == first and len(calls) == 1
    assert json.loads((tmp_path / "device-probes.json").read_text())


# -- real runtimes made to fail ------------------------------------------------------------
def _run(args, env_extra, cwd):
    env = {k: v for k, v in os.environ.items() if k not in ("VOXLIDAR_DEVICE", "PYOPENCL_CTX")}
    env.update(VOXLIDAR_DEVICE_CACHE="0", **env_extra)
    return subprocess.run([sys.executable, "-m", *args], capture_output=True, text=True, timeout=300,
                          env=env, cwd=cwd)


BROKEN_POCL = {"POCL_EXTRA_BUILD_FLAGS": "-fno-such-flag"}


def _runtimes():
    return {d.runtime.split()[0] for d in vd.find_devices()}


@pytest.fixture(scope="module")
def layer_file(tmp_path_factory):
    from clsim.validation.testscenes import homogeneous_layer

    return homogeneous_layer(width=4.0, voxel_size=0.5).save(tmp_path_factory.mktemp("dev") / "layer.npz")


def test_broken_runtime_beside_a_working_one(layer_file, tmp_path):
    """PoCL broken, Intel's runtime working: every command works on Intel's, and
    `clsim devices` shows the broken ones with the reason from the build log."""
    if not {"PoCL", "Intel"} <= _runtimes():
        pytest.skip(f"needs PoCL and Intel's runtime; found {sorted(_runtimes())}")
    out = _run(["clsim.cli", "devices"], BROKEN_POCL, tmp_path)
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    pocl = [ln for ln in lines if "PoCL" in ln]
    assert pocl and all("BROKEN: kernels do not build: clBuildProgram failed: INVALID_BUILD_OPTIONS" in ln
                        for ln in pocl)
    assert [ln for ln in lines if ln.startswith("*") and "Intel" in ln and ln.endswith("works")]
    assert "Traceback" not in out.stderr
    wf = tmp_path / "wf.npz"
    out = _run(["clsim.cli", "simulate", str(layer_file), "--photons", "3000", "-o", str(wf)], BROKEN_POCL, tmp_path)
    assert out.returncode == 0, out.stderr
    assert "Intel" in json.loads(str(np.load(wf)["settings"]))["device"]
    code = "from tlsvox.voxel.trace import Tracer; print(Tracer().info.runtime)"
    env = {k: v for k, v in os.environ.items() if k not in ("VOXLIDAR_DEVICE", "PYOPENCL_CTX")}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                         env=dict(env, VOXLIDAR_DEVICE_CACHE="0", **BROKEN_POCL))
    assert out.returncode == 0 and out.stdout.startswith("Intel"), out.stderr


def test_asking_for_the_broken_runtime_is_one_clean_line(layer_file, tmp_path):
    if "PoCL" not in _runtimes():
        pytest.skip("needs PoCL")
    env = dict(BROKEN_POCL, VOXLIDAR_DEVICE="pocl")
    out = _run(["clsim.cli", "simulate", str(layer_file), "--photons", "100", "-o", str(tmp_path / "w.npz")],
               env, tmp_path)
    assert out.returncode == 1, (out.stdout, out.stderr)
    err = out.stderr.strip().splitlines()
    assert len(err) == 1 and "Traceback" not in out.stderr, out.stderr
    assert "VOXLIDAR_DEVICE" in err[0] and "INVALID_BUILD_OPTIONS" in err[0] and "fix:" in err[0]
    assert not (tmp_path / "w.npz").exists()


def test_voxelize_on_a_broken_device_is_one_clean_line(tmp_path):
    """The tlsvox command that used to print a raw traceback on a device that cannot build."""
    if "PoCL" not in _runtimes():
        pytest.skip("needs PoCL")
    pytest.importorskip("open3d")
    from tlsvox.truth.scanner import ScannerPreset, ScanPose, simulate_scan
    from tlsvox.truth.synthetic import make_leaf_slab

    box = make_leaf_slab(lad=1.0, size=(1.0, 1.0, 1.0), origin=(-0.5, -0.5, 1.0), seed=3)
    preset = ScannerPreset.riegl_vz400(zenith_step_deg=1.0, azimuth_step_deg=1.0, n_subrays=1)
    scan = simulate_scan(box, pose=ScanPose(position=(-5.0, 0.0, 1.7)), preset=preset, seed=1, progress=False)
    scan.pose = scan.pose_true
    path = tmp_path / "box.laz"
    scan.write(path)
    out = _run(["tlsvox.cli", "voxelize", str(path), "-o", str(tmp_path / "s.npz"), "--voxel-size", "0.5",
                "--device", "pocl", "-q"], BROKEN_POCL, tmp_path)
    assert out.returncode == 1, out.stderr
    err = out.stderr.strip().splitlines()
    assert len(err) == 1 and "INVALID_BUILD_OPTIONS" in err[0] and "fix:" in err[0], out.stderr
    assert not (tmp_path / "s.npz").exists()


def test_no_working_device_at_all(layer_file, tmp_path):
    """Every runtime hidden or broken: each command fails in one line that names the fix."""
    empty = tmp_path / "no-vendors"
    empty.mkdir()
    env = dict(BROKEN_POCL, OCL_ICD_VENDORS=str(empty))  # hides the system's runtimes and Intel's
    out = _run(["clsim.cli", "devices"], env, tmp_path)
    assert out.returncode == 1
    err = out.stderr.strip().splitlines()
    assert len(err) == 1 and "fix:" in err[0] and "install a CPU OpenCL runtime" in err[0], out.stderr
    out = _run(["clsim.cli", "simulate", str(layer_file), "--photons", "100", "-o", str(tmp_path / "w.npz")],
               env, tmp_path)
    assert out.returncode == 1
    err = out.stderr.strip().splitlines()
    assert len(err) == 1 and "fix:" in err[0] and "ReferenceSimulator" in err[0], out.stderr
    out = _run(["clsim.cli", "bench", "--photons", "1000", "--repeats", "1"], env, tmp_path)
    assert out.returncode == 1 and len(out.stderr.strip().splitlines()) == 1, out.stderr
    demo = Path(__file__).resolve().parents[2] / "examples" / "demo.py"  # `make demo`, before any work
    out = subprocess.run([sys.executable, str(demo), "--out", str(tmp_path / "demo")], capture_output=True,
                         text=True, timeout=300, env=dict(os.environ, VOXLIDAR_DEVICE_CACHE="0", **env))
    assert out.returncode == 1 and not (tmp_path / "demo").exists(), out.stderr
    err = out.stderr.strip().splitlines()
    assert len(err) == 1 and "fix:" in err[0], out.stderr


def test_icd_folder_resolves_the_wheel_placeholder(tmp_path, monkeypatch):
    """intel-opencl-rt's ICD file names a library on its build machine; the vendors folder
    names the one in this environment, beside the system's ICD files."""
    prefix = tmp_path / "venv"
    (prefix / "etc" / "OpenCL" / "vendors").mkdir(parents=True)
    (prefix / "lib").mkdir()
    (prefix / "lib" / "libintelocl.so").write_bytes(b"")
    placeholder = "/opt/anaconda1anaconda2anaconda3/lib/libintelocl.so\n"
    (prefix / "etc" / "OpenCL" / "vendors" / "intel-cpu.icd").write_text(placeholder)
    (prefix / "etc" / "OpenCL" / "vendors" / "intel-fpga_emu.icd").write_text("/opt/x/lib/libintelocl_emu.so\n")
    system = tmp_path / "etc-vendors"
    system.mkdir()
    (system / "pocl.icd").write_text("libpocl.so.2\n")
    monkeypatch.setattr(vd.sys, "prefix", str(prefix))
    monkeypatch.setattr(vd, "_SYSTEM_VENDORS", system)
    monkeypatch.setattr(vd, "_ICD_DONE", False)
    monkeypatch.setenv("VOXLIDAR_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setenv("OCL_ICD_VENDORS", "restored-after-the-test")
    monkeypatch.delenv("OCL_ICD_VENDORS")
    folder = Path(vd.prepare_icd_loader())
    assert os.environ["OCL_ICD_VENDORS"] == str(folder)
    libs = sorted(f.read_text().strip() for f in folder.glob("*.icd"))
    assert libs == sorted(["libpocl.so.2", str(prefix / "lib" / "libintelocl.so")])  # no FPGA emulator
    monkeypatch.setattr(vd, "_ICD_DONE", False)
    assert vd.prepare_icd_loader() is None  # OCL_ICD_VENDORS set: the user's (here: ours) is kept

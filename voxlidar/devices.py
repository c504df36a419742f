"""One OpenCL device layer for both stages: find the devices, probe them, choose one.

Every OpenCL runtime on a machine shows up as a platform with devices, and not
every one of them can build the project's kernels: the PoCL from PyPI (LLVM 14)
fails with ``unknown target CPU 'generic'`` on CPUs newer than its LLVM, and a
device without float64 cannot run the tlsvox tracer.  So a device is only
*used* after its kernels have been *built* once on it (a probe; the verdict is
cached per process and on disk), and a device that cannot build is reported
with the reason from its build log instead of crashing a command.

The choice, in order:

1. an explicit argument (a :class:`DeviceInfo`, a ``pyopencl.Device``, an
   index ``"platform:device"``, ``"cpu"``/``"gpu"``, or a name fragment such
   as ``"intel"`` or ``"pocl"``);
2. else the environment variable ``VOXLIDAR_DEVICE``, then ``PYOPENCL_CTX``
   (same forms);
3. else the best working device: a GPU first (most compute units x clock),
   then the CPU runtimes in the order measured fastest (PoCL, newest first,
   then Intel's runtime; docs/benchmarks.md).

Runtimes pip puts into a virtual environment (``intel-opencl-rt``) ship an ICD
file with a placeholder path; :func:`prepare_icd_loader` resolves it and points
the ICD loader at the system's runtimes plus the environment's, before the
first OpenCL call.  Set ``OCL_ICD_VENDORS`` yourself to take over.

Examples
--------
>>> gpu = DeviceInfo("1:0", "NVIDIA CUDA", "OpenCL 3.0 CUDA 13.0.98", "NVIDIA H100", "GPU", "", "",
...                  132, 1980, 0, 0, True, True)
>>> cpu = DeviceInfo("0:0", "Portable Computing Language", "OpenCL 3.0 PoCL 3.1+debian  Linux",
...                  "cpu-haswell", "CPU", "", "", 2, 0, 0, 0, True, True)
>>> [d.key for d in rank_devices([cpu, gpu])], cpu.runtime
(['1:0', '0:0'], 'PoCL 3.1+debian')
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import json
import os
import re
import socket
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

from voxlidar.errors import DeviceError

__all__ = ["DeviceInfo", "FIX_NO_DEVICE", "KERNEL_SETS", "build_program", "choose_device",
           "describe", "device_report", "find_devices", "open_queue", "prepare_icd_loader",
           "probe", "rank_devices", "short_reason", "state_text", "unloadable_runtimes"]

#: The kernels of each stage, probed by building them: name -> "module:function".
#: The function takes a ``pyopencl.Device`` and returns None when the device
#: can run them, or a one-line reason; a build failure raises.
KERNEL_SETS = {
    "clsim": "clsim.transport.simulator:probe_build",
    "decompose": "clsim.waveforms.decompose._batch_cl:probe_build",
    "tlsvox": "tlsvox.voxel.trace:probe_build",
}

FIX_NO_DEVICE = ("install a CPU OpenCL runtime: `sudo apt-get install pocl-opencl-icd` "
                 "(`make setup` does this when run as root), or `pip install intel-opencl-rt`, "
                 "or `pip install pocl-binary-distribution` (CPUs older than 2022)")
_FIX_PICK = ("choose a working device (`clsim devices` lists them) with VOXLIDAR_DEVICE or the "
             "device argument, or " + FIX_NO_DEVICE)

_SYSTEM_VENDORS = Path("/etc/OpenCL/vendors")


def _cache_dir() -> Path:
    env = os.environ.get("VOXLIDAR_CACHE_DIR")
    if env:
        return Path(env)
    base = os.environ.get("XDG_CACHE_HOME")
    if not base:
        try:
            base = str(Path.home() / ".cache")
        except RuntimeError:  # no home directory
            base = tempfile.gettempdir()
    return Path(base) / "voxlidar"


# -- the ICD loader -----------------------------------------------------------------
def _environment_icds() -> list[str]:
    """Libraries named by the ICD files pip put into this environment, with the
    install-time placeholder path of a wheel resolved to the environment's lib folder."""
    out = []
    folder = Path(sys.prefix) / "etc" / "OpenCL" / "vendors"
    if not folder.is_dir():
        return out
    for f in sorted(folder.glob("*.icd")):
        try:
            lib = Path(f.read_text().strip())
        except OSError:
            continue
        if not str(lib) or str(lib) == ".":
            continue
        if not (lib.is_absolute() and lib.exists()):
            lib = Path(sys.prefix) / "lib" / lib.name
            if not lib.exists():
                continue  # a runtime the wheel names but does not ship (the FPGA emulator)
        out.append(str(lib))
    return out


_ICD_DONE = False


def unloadable_runtimes() -> list[tuple[str, str]]:
    """[(library, loader error)] for runtimes installed in this environment that the
    dynamic loader cannot open (a missing dependency): the ICD loader skips those
    silently, so ``clsim devices`` says why they are absent."""
    import ctypes

    out = []
    for lib in _environment_icds():
        try:
            ctypes.CDLL(lib)
        except OSError as err:
            out.append((lib, str(err).splitlines()[0][:200]))
    return out


def prepare_icd_loader() -> str | None:
    """Make the ICD loader see this environment's runtimes beside the system's.

    Writes a vendors folder (the system's ICD files plus one per runtime found
    in ``sys.prefix/etc/OpenCL/vendors``) under the cache folder and sets
    ``OCL_ICD_VENDORS`` to it.  Runs once per process, before the first
    OpenCL call; does nothing when ``OCL_ICD_VENDORS`` is already set or the
    environment has no runtime of its own.  Returns the folder or None.
    """
    global _ICD_DONE
    if _ICD_DONE or "OCL_ICD_VENDORS" in os.environ:
        return None
    _ICD_DONE = True
    extra = _environment_icds()
    if not extra:
        return None
    entries = []
    if _SYSTEM_VENDORS.is_dir():
        for f in sorted(_SYSTEM_VENDORS.glob("*.icd")):
            try:
                entries.append((f.name, f.read_text().strip()))
            except OSError:
                continue
    entries += [(f"env-{i}-{Path(lib).stem}.icd", lib) for i, lib in enumerate(extra)]
    digest = hashlib.sha1(repr(entries).encode()).hexdigest()[:12]
    try:
        folder = _write_vendors(_cache_dir() / f"opencl-vendors-{digest}", entries)
    except OSError:  # no writable cache: the runtimes of the system alone, as without us
        return None
    os.environ["OCL_ICD_VENDORS"] = str(folder)
    return str(folder)


def _write_vendors(folder: Path, entries) -> Path:
    """The vendors folder with ``entries`` [(file name, library)], written once
    (in a temporary folder renamed into place; a race with another process
    keeps whichever folder arrived first)."""
    if folder.is_dir():
        return folder
    try:
        tmp = Path(tempfile.mkdtemp(prefix=folder.name + ".", dir=_ensure(folder.parent)))
    except OSError:
        folder = tmp = Path(tempfile.mkdtemp(prefix="voxlidar-opencl-vendors-"))
    for name, lib in entries:
        (tmp / name).write_text(lib + "\n")
    if tmp != folder:
        try:
            os.rename(tmp, folder)
        except OSError:
            if not folder.is_dir():
                return tmp  # could not rename: use the complete temporary folder
            for f in tmp.iterdir():
                f.unlink()
            tmp.rmdir()
    return folder


def _ensure(path: Path) -> Path:
    path.mkdir(parents=True, exist_ok=True)
    return path


# -- what is there ------------------------------------------------------------------
@dataclass(frozen=True)
class DeviceInfo:
    """One OpenCL device and what the project needs to know of it.

    ``key`` is ``"platform:device"`` (the indices ``PYOPENCL_CTX`` uses);
    ``runtime`` a short name of the implementation (``"PoCL 3.1+debian"``).
    """

    key: str
    platform: str
    platform_version: str
    name: str
    kind: str
    version: str
    driver: str
    compute_units: int
    clock_mhz: int
    global_mem_bytes: int
    max_alloc_bytes: int
    fp64: bool
    int64_atomics: bool
    device: object = field(default=None, compare=False, repr=False)

    @property
    def label(self) -> str:
        return f"{self.platform} / {self.name}"

    @property
    def runtime(self) -> str:
        m = re.search(r"PoCL\s+(\S+)", self.platform_version)
        if m:
            return f"PoCL {m.group(1)}"
        if "intel" in self.platform.lower():
            return f"Intel OpenCL {self.driver.split('_')[0]}"
        rest = re.sub(r"^OpenCL\s+\S+\s*", "", self.platform_version).strip()
        return f"{self.platform} {rest}".strip()

    @property
    def is_gpu(self) -> bool:
        return self.kind == "GPU"


def _attr(dev, name, default):
    try:
        return getattr(dev, name)
    except Exception:  # noqa: BLE001 - a runtime may not answer every query
        return default


def describe(dev, key: str = "?:?") -> DeviceInfo:
    """A :class:`DeviceInfo` for a ``pyopencl.Device``."""
    import pyopencl as cl

    plat = dev.platform
    ext = _attr(dev, "extensions", "")
    t = int(_attr(dev, "type", 0))
    kind = ("GPU" if t & cl.device_type.GPU else "ACCELERATOR" if t & cl.device_type.ACCELERATOR
            else "CPU" if t & cl.device_type.CPU else "OTHER")
    return DeviceInfo(
        key=key, platform=_attr(plat, "name", "?").strip(), platform_version=_attr(plat, "version", "").strip(),
        name=_attr(dev, "name", "?").strip(), kind=kind, version=_attr(dev, "version", "").strip(),
        driver=_attr(dev, "driver_version", "").strip(), compute_units=int(_attr(dev, "max_compute_units", 1)),
        clock_mhz=int(_attr(dev, "max_clock_frequency", 0)), global_mem_bytes=int(_attr(dev, "global_mem_size", 0)),
        max_alloc_bytes=int(_attr(dev, "max_mem_alloc_size", 0)), fp64=bool(_attr(dev, "double_fp_config", 0)),
        int64_atomics="cl_khr_int64_base_atomics" in ext, device=dev)


def find_devices() -> list[DeviceInfo]:
    """Every OpenCL device of every platform, unprobed (cheap); [] when there is none."""
    prepare_icd_loader()
    try:
        import pyopencl as cl
    except ImportError:
        return []
    try:
        platforms = cl.get_platforms()
    except cl.Error:
        return []
    out = []
    for pi, p in enumerate(platforms):
        try:
            devs = p.get_devices()
        except cl.Error:
            continue
        out.extend(describe(d, f"{pi}:{di}") for di, d in enumerate(devs))
    return out


def _version_tuple(text: str) -> tuple:
    m = re.search(r"(\d+(?:\.\d+)*)", text)
    return tuple(int(x) for x in m.group(1).split(".")) if m else ()


def rank_devices(found: list[DeviceInfo]) -> list[DeviceInfo]:
    """Best first: GPUs (most compute units x clock), then CPU runtimes in the
    order measured fastest on the benchmark layer: PoCL (newest first), then
    Intel's runtime, then any other; accelerators and emulators last."""

    def key(d: DeviceInfo):
        if d.is_gpu:
            return (0, -d.compute_units * max(d.clock_mhz, 1), ())
        if d.kind != "CPU":  # accelerators and emulators (an FPGA emulator) last
            return (9, 0, ())
        rt = d.runtime.lower()
        pref = 0 if rt.startswith("pocl") else (1 if rt.startswith("intel") else 2)
        return (1 + pref, 0, tuple(-x for x in _version_tuple(d.runtime.split(" ", 1)[-1])))

    return sorted(found, key=key)


# -- probing ------------------------------------------------------------------------
_MEMO: dict[str, str | None] = {}
_OK = "works"


def _fingerprint(kernel: str) -> str:
    """Hash of what a probe builds: the probe's module and its package's kernels."""
    module = KERNEL_SETS[kernel].split(":")[0]
    top, _, rest = module.partition(".")
    spec = importlib.util.find_spec(top)
    h = hashlib.sha1()
    if spec is not None and spec.submodule_search_locations:
        pkg = Path(list(spec.submodule_search_locations)[0])
        files = [pkg / (rest.replace(".", "/") + ".py")] + sorted((pkg / "kernels").glob("*.cl"))
        for f in files:
            try:
                h.update(f.read_bytes())
            except OSError:
                pass
    return h.hexdigest()


def _probe_key(info: DeviceInfo, kernel: str) -> str:
    try:
        import pyopencl

        pyopencl_version = pyopencl.VERSION_TEXT
    except (ImportError, AttributeError):
        pyopencl_version = "?"
    parts = [socket.gethostname(), info.platform, info.platform_version, info.name, info.version,
             info.driver, pyopencl_version, kernel, _fingerprint(kernel)]
    return hashlib.sha1(json.dumps(parts).encode()).hexdigest()


def _disk_cache_on() -> bool:
    return os.environ.get("VOXLIDAR_DEVICE_CACHE", "1").lower() not in ("0", "off", "no", "false")


def _disk_cache_path() -> Path:
    return _cache_dir() / "device-probes.json"


def _disk_get(key: str):
    if not _disk_cache_on():
        return None
    try:
        verdict = json.loads(_disk_cache_path().read_text()).get(key)
    except (OSError, ValueError, AttributeError, RuntimeError):
        return None
    return verdict if isinstance(verdict, str) else None


def _disk_put(key: str, verdict: str) -> None:
    if not _disk_cache_on():
        return
    path = _disk_cache_path()
    try:
        try:
            data = json.loads(path.read_text())
        except (OSError, ValueError):
            data = {}
        if not isinstance(data, dict):
            data = {}
        data[key] = verdict
        _ensure(path.parent)
        fd, tmp = tempfile.mkstemp(prefix=path.name + ".", dir=path.parent)
        with os.fdopen(fd, "w") as fh:
            json.dump(data, fh, indent=0)
        os.replace(tmp, path)
    except (OSError, RuntimeError):
        pass  # a cache that cannot be written only costs a rebuild next time


def short_reason(err: BaseException) -> str:
    """The first error line of a build log (or of an exception), at most 200 characters.

    >>> short_reason(RuntimeError("clBuildProgram failed: BUILD_PROGRAM_FAILURE - clBuildProgram "
    ...     "failed: BUILD_PROGRAM_FAILURE\\n\\nBuild on <dev>:\\n\\nerror: unknown target CPU 'generic'\\n"))
    "error: unknown target CPU 'generic'"
    >>> short_reason(RuntimeError("clBuildProgram failed: INVALID_BUILD_OPTIONS - clBuildProgram failed: "
    ...     "INVALID_BUILD_OPTIONS"))
    'clBuildProgram failed: INVALID_BUILD_OPTIONS'
    """
    text = str(err)
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    for ln in lines:
        if re.search(r"\berror\b", ln, re.IGNORECASE) and "clBuildProgram failed" not in ln:
            return ln[:200]
    if not lines:
        return type(err).__name__
    first = " - ".join(dict.fromkeys(lines[0].split(" - ")))  # pyopencl repeats itself
    return first[:200]


_LASTING = ("BUILD_PROGRAM_FAILURE", "INVALID_BUILD_OPTIONS", "COMPILER_NOT_AVAILABLE")


def _run_probe(info: DeviceInfo, kernel: str) -> tuple[str | None, bool]:
    """(reason or None, whether the verdict lasts): a build failure or a missing
    capability lasts until the driver or the kernels change; any other failure
    (out of resources, device busy) is kept for this process only."""
    module, func = KERNEL_SETS[kernel].split(":")
    build = getattr(importlib.import_module(module), func)
    try:
        return build(info.device), True
    except Exception as err:  # noqa: BLE001 - whatever a runtime raises marks the device broken
        text = str(err)
        if any(code in text for code in _LASTING):
            return f"kernels do not build: {short_reason(err)}", True
        return f"unusable now: {short_reason(err)}", False


def probe(info: DeviceInfo, kernels=("clsim",)) -> dict[str, str | None]:
    """``{kernel set: None if the device runs it, else the reason}``; each
    verdict is computed once (a build) and cached in the process and on disk."""
    out = {}
    for kernel in kernels:
        if kernel not in KERNEL_SETS:
            raise DeviceError(f"unknown kernel set {kernel!r}; have {sorted(KERNEL_SETS)}")
        key = _probe_key(info, kernel)
        if key not in _MEMO:
            verdict = _disk_get(key)
            if verdict is None:
                reason, lasting = _run_probe(info, kernel)
                verdict = _OK if reason is None else reason
                if lasting:
                    _disk_put(key, verdict)
            _MEMO[key] = None if verdict == _OK else verdict
        out[kernel] = _MEMO[key]
    return out


def _problems(info: DeviceInfo, kernels) -> str:
    return "; ".join(r for r in probe(info, kernels).values() if r)


def build_program(context, source: str, options):
    """``pyopencl.Program(context, source).build(options)`` without the warning
    PyOpenCL raises for any non-empty compiler log (PoCL and Intel's runtime
    print notes on success); a failed build still raises, with its log."""
    import warnings

    import pyopencl as cl

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", cl.CompilerWarning)
        return cl.Program(context, source).build(options=list(options))


def open_queue(info: DeviceInfo):
    """(context, command queue) on a device, or a one-line :class:`DeviceError`."""
    import pyopencl as cl

    try:
        context = cl.Context([info.device])
        return context, cl.CommandQueue(context)
    except cl.Error as err:
        raise DeviceError(f"OpenCL device {info.label} cannot be opened: {short_reason(err)}; "
                          "fix: choose another device (clsim devices)") from err


def state_text(verdict: dict) -> str:
    """One phrase for a device's probe verdicts: ``works``, ``BROKEN: reason``, or
    which kernel sets work when only some do.

    >>> state_text({"clsim": None, "tlsvox": None})
    'works'
    >>> state_text({"clsim": "kernels do not build: x", "tlsvox": "kernels do not build: x"})
    'BROKEN: kernels do not build: x'
    >>> state_text({"clsim": None, "tlsvox": "no float64 support"})
    'works for clsim; not for tlsvox: no float64 support'
    """
    bad = {k: r for k, r in verdict.items() if r}
    if not bad:
        return "works"
    good = [k for k in verdict if k not in bad]
    reasons = list(dict.fromkeys(bad.values()))
    if good:
        return f"works for {', '.join(good)}; " + "; ".join(f"not for {k}: {r}" for k, r in bad.items())
    return "BROKEN: " + (reasons[0] if len(reasons) == 1 else "; ".join(f"{k}: {r}" for k, r in bad.items()))


def device_report(kernels=tuple(KERNEL_SETS), devices=None) -> list[tuple[DeviceInfo, dict]]:
    """Every device found with its probe verdicts, best first (``clsim devices``)."""
    found = find_devices() if devices is None else devices
    return [(d, probe(d, kernels)) for d in rank_devices(found)]


# -- choosing -----------------------------------------------------------------------
def _matches(spec: str, found: list[DeviceInfo]) -> list[DeviceInfo]:
    s = spec.strip()
    low = s.lower()
    if low in ("cpu", "gpu"):
        return [d for d in found if d.is_gpu == (low == "gpu")]
    if re.fullmatch(r"\d*(:\d*)?", s):
        p, _, d = s.partition(":")
        key = f"{p or 0}:{d or 0}"
        return [x for x in found if x.key == key]
    # the runtime or platform first: PoCL's device on an Intel host is named "cpu-...-Intel(R) Xeon"
    by_runtime = [d for d in found if low in d.platform.lower() or low in d.runtime.lower()]
    return by_runtime or [d for d in found if low in d.name.lower()]


def _listing(found) -> str:
    return ", ".join(f"{d.key} = {d.label} ({d.runtime})" for d in rank_devices(found))


def choose_device(spec=None, *, kernels=("clsim",), devices=None) -> DeviceInfo:
    """The device to run ``kernels`` on (see the module docstring for the order).

    Parameters
    ----------
    spec : DeviceInfo, pyopencl.Device, str or None
        ``"0:1"``, ``"cpu"``, ``"gpu"`` or a name fragment; None for
        ``VOXLIDAR_DEVICE``, ``PYOPENCL_CTX``, or the best working device.
    kernels : tuple of str
        Kernel sets the device must build (keys of :data:`KERNEL_SETS`).
    devices : list of DeviceInfo, optional
        Candidates (default: :func:`find_devices`).

    Raises
    ------
    DeviceError
        One line: no device, no such device, or no working one, with the
        reason from the build log and the fix.
    """
    if isinstance(spec, DeviceInfo):
        candidates, source = [spec], "the device argument"
    elif spec is not None and not isinstance(spec, str):
        candidates, source = [describe(spec)], "the device argument"  # a pyopencl.Device
    else:
        found = find_devices() if devices is None else list(devices)
        if not found:
            raise DeviceError("no OpenCL device found; fix: " + FIX_NO_DEVICE)
        source = "the device argument" if spec is not None else None
        if spec is None:
            for var in ("VOXLIDAR_DEVICE", "PYOPENCL_CTX"):
                if os.environ.get(var, "").strip():
                    spec, source = os.environ[var], var
                    break
        if spec is None:
            candidates = rank_devices(found)
        else:
            candidates = rank_devices(_matches(str(spec), found))
            if not candidates:
                raise DeviceError(f"OpenCL device {spec!r} ({source}) not found; available: {_listing(found)}")
    broken = []
    for info in candidates:
        problem = _problems(info, kernels)
        if not problem:
            return info
        broken.append(f"{info.key} {info.label}: {problem}")
    what = f"OpenCL device {spec!r} ({source})" if source else "no OpenCL device works"
    verb = " cannot run the kernels" if source else ""
    raise DeviceError(f"{what}{verb} ({'; '.join(broken)}); fix: {_FIX_PICK}")

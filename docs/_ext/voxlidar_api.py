"""Write the API reference pages (``reference/api/*.rst``) from the packages' ``__all__``.

Each public module below gets one page: its docstring, then every name of its
``__all__`` documented by autodoc. An object exported at several paths (the
top-level verbs are re-exports) is documented once, at the first public path
in ``PUBLIC``'s order; the later pages link to it. The pages are generated at
each build, so a name added to an ``__all__`` appears without editing the docs,
and a public name without a docstring fails the build (``missing_docstrings``).
"""

from __future__ import annotations

import importlib
import inspect
from pathlib import Path

#: the public modules, in the order a reader meets them: (module, one-line title)
PUBLIC = [
    ("voxlidar", "the shared floor: scene, leaf angles, materials, errors"),
    ("voxlidar.scene", "the voxel scene and its file"),
    ("voxlidar.leaf_orientation", "leaf inclination distributions and G(θ)"),
    ("voxlidar.materials", "materials and their optical properties"),
    ("voxlidar.devices", "the OpenCL device layer"),
    ("voxlidar.safeio", "outputs that never lose an input"),
    ("voxlidar.cli", "the command-line conventions"),
    ("tlsvox", "terrestrial scans to a voxel scene"),
    ("tlsvox.scan", "one scan: echoes, pulses, pose"),
    ("tlsvox.readers", "reading scans of every format"),
    ("tlsvox.register", "registration and georegistration"),
    ("tlsvox.register.settings", "the registration's settings, grouped"),
    ("tlsvox.grouped", "settings in groups, and their TOML files"),
    ("tlsvox.classify", "leaf and wood classification"),
    ("tlsvox.classify.settings", "the classification's settings, grouped"),
    ("tlsvox.ground", "the ground plane"),
    ("tlsvox.leafangles", "leaf inclination measured from the scans"),
    ("tlsvox.leafangles.settings", "the leaf-angle measurement's settings, grouped"),
    ("tlsvox.voxel", "the voxel stage"),
    ("tlsvox.voxel.stages", "the voxel stage's stages, one function each"),
    ("tlsvox.voxel.settings", "the voxel stage's settings, grouped by stage"),
    ("tlsvox.voxel.estimators", "LAD estimators, one function each"),
    ("tlsvox.voxel.fills", "occluded voxels filled"),
    ("tlsvox.voxel.weights", "echo weights: how echoes share their pulse"),
    ("tlsvox.voxel.footprint", "echo weights from the beam's footprint, without reflectance"),
    ("tlsvox.voxel.airborne", "scenes from airborne pulses"),
    ("tlsvox.voxel.merged", "merged point clouds without pulses: beams from scan positions, or occupancy"),
    ("tlsvox.voxel.profile", "vertical LAD profiles and their pictures"),
    ("tlsvox.voxel.amapvox", "AMAPVox .vox files"),
    ("tlsvox.voxel.wood", "wood: per voxel, and solid from fitted cylinders"),
    ("tlsvox.voxel.wood.qsm", "cylinders fitted to the wood"),
    ("tlsvox.pipeline", "scans to a scene in one call"),
    ("clsim", "the airborne full-waveform simulator"),
    ("clsim.sensor", "airborne sensors and their presets"),
    ("clsim.transport", "the Monte Carlo photon transport"),
    ("clsim.transport.first_order", "the deterministic first order: single scattering along the beam"),
    ("clsim.survey", "surveys: trajectories, scan patterns, runs, LAS output"),
    ("clsim.survey.helios", "a survey as HELIOS++ files"),
    ("clsim.scenes", "plots of many trees"),
    ("clsim.waveforms.io", "waveform files: LAS packets, PulseWaves, HELIOS++ full waveforms"),
    ("clsim.waveforms.decompose", "Gaussian decomposition of waveforms"),
    ("clsim.waveforms.metrics", "waveform metrics and comparisons"),
    ("clsim.waveforms.pointing", "laser pointing per pulse"),
    ("clsim.replay", "measured pulses replayed and scored"),
    ("clsim.figures", "the simulator's pictures"),
]


def _kind(obj) -> str:
    if inspect.isclass(obj):
        return "exception" if issubclass(obj, BaseException) else "class"
    if callable(obj):
        return "function"
    if inspect.ismodule(obj):
        return "module"
    return "data"


def missing_docstrings() -> list[str]:
    """Public names (in an ``__all__`` of ``PUBLIC``) whose object has no docstring of its own."""
    out = []
    for mod, _ in PUBLIC:
        m = importlib.import_module(mod)
        for name in getattr(m, "__all__", []):
            obj = getattr(m, name)
            if _kind(obj) in ("class", "exception", "function") and not (obj.__doc__ or "").strip():
                out.append(f"{mod}.{name}")
    return out


def _data_doc(mod: str, name: str) -> str | None:
    """The ``#:`` comment above ``name = ...`` in ``mod`` or the module it was imported from."""
    from sphinx.pycode import ModuleAnalyzer

    m = importlib.import_module(mod)
    candidates = [mod] + sorted({v.__module__ for v in vars(m).values()
                                 if getattr(v, "__module__", "").startswith(mod.split(".")[0])} - {mod})
    for where in candidates:
        try:
            docs = ModuleAnalyzer.for_module(where).find_attr_docs()
        except Exception:  # noqa: BLE001 - no source for it: try the next module
            continue
        if ("", name) in docs:
            return "\n".join(docs[("", name)]).strip()
    return None


def write_pages(out: Path) -> list[str]:
    """Write one page per public module under ``out``; return the page names."""
    out.mkdir(parents=True, exist_ok=True)
    seen: dict[int, str] = {}
    pages = []
    for mod, title in PUBLIC:
        m = importlib.import_module(mod)
        lines = [f"``{mod}``: {title}", "=" * (len(mod) + 6 + len(title)), "",
                 f".. automodule:: {mod}", "   :no-members:", "", f".. currentmodule:: {mod}", ""]
        for name in getattr(m, "__all__", []):
            if name.startswith("__"):
                continue
            obj = getattr(m, name)
            kind = _kind(obj)
            first = seen.get(id(obj)) if kind != "data" else None
            if first is not None:
                lines += [f".. py:{'class' if kind == 'exception' else kind}:: {name}", "   :no-index:", "",
                          f"   The same object as :py:obj:`{first}`.", ""]
                continue
            if kind == "module":
                continue
            if kind != "data":
                seen[id(obj)] = f"{mod}.{name}"
            if kind == "data":
                # a constant: its ``#:`` comment (never the docstring of its type) and its value
                doc = _data_doc(mod, name) or "A constant of the module."
                value = repr(obj)
                lines += [f".. py:data:: {name}", ""] + [f"   {ln}" for ln in doc.splitlines()] + [""]
                if len(value) <= 200:
                    lines += ["   ``" + value.replace("`", "'") + "``", ""]
                continue
            directive = {"class": "autoclass", "exception": "autoexception", "function": "autofunction"}[kind]
            lines += [f".. {directive}:: {name}", ""]
        page = mod.replace(".", "_")
        (out / f"{page}.rst").write_text("\n".join(lines) + "\n", encoding="utf-8")
        pages.append(page)
    index = ["API", "===", "", "Every public name of the three packages, from its docstring. The user's verbs sit at",
             "the top of each package (``tlsvox.voxelize``, ``clsim.Simulator``); the modules below",
             "hold the rest.", "", ".. toctree::", "   :maxdepth: 1", ""] + [f"   {p}" for p in pages]
    (out / "index.rst").write_text("\n".join(index) + "\n", encoding="utf-8")
    return pages


def _generate(app) -> None:
    missing = missing_docstrings()
    if missing:
        raise RuntimeError("public names without a docstring: " + ", ".join(missing))
    write_pages(Path(app.srcdir) / "reference" / "api")


def setup(app):
    app.connect("builder-inited", _generate)
    return {"version": "1", "parallel_read_safe": True}

"""Old import paths of modules moved in the 0.2 layout, kept for one release.

``import tlsvox.trace`` still works and gives the very module
``tlsvox.voxel.trace`` (same object, so patches and ``isinstance`` agree),
with a :class:`DeprecationWarning` that names the new path.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys
import warnings

#: old dotted name -> new dotted name (a package maps its submodules too)
MOVED = {
    "tlsvox.scene": "voxlidar.scene",
    "tlsvox.leafangle": "voxlidar.leaf_orientation",
    "voxlidar.leafangle": "voxlidar.leaf_orientation",
    "clsim.waveform": "clsim.digitize",
    "tlsvox.materials": "voxlidar.materials",
    "tlsvox.versions": "voxlidar.versions",
    "clsim.choices": "voxlidar.choices",
    "tlsvox.synthetic": "tlsvox.truth.synthetic",
    "tlsvox.scanner": "tlsvox.truth.scanner",
    "tlsvox.meshtruth": "tlsvox.truth.meshtruth",
    "tlsvox.grid": "tlsvox.voxel.grid",
    "tlsvox.trace": "tlsvox.voxel.trace",
    "tlsvox.pulses": "tlsvox.voxel.pulses",
    "tlsvox.estimators": "tlsvox.voxel.estimators",
    "tlsvox.wood": "tlsvox.voxel.wood",
    "tlsvox.voxelize": "tlsvox.voxel.stages",
    "tlsvox.voxel.voxlad": "tlsvox.voxel.stages",
    "tlsvox.amapvox": "tlsvox.voxel.amapvox",
    "tlsvox.qsm": "tlsvox.voxel.wood.qsm",
    "tlsvox.voxel.solid": "tlsvox.voxel.wood.solid",
    "tlsvox.io": "tlsvox.readers.formats",
    "tlsvox.multireturn": "tlsvox.readers.pulse_text",
    "tlsvox.plots_classify": "tlsvox.classify.plots",
    "clsim.simulator": "clsim.transport.simulator",
    "clsim.bricks": "clsim.transport.bricks",
    "clsim.rng": "clsim.transport.rng",
    "clsim.transport_ref": "clsim.transport.reference",
    "clsim.testscenes": "clsim.validation.testscenes",
    "clsim.meshref": "clsim.validation.meshref",
    "clsim.budget": "clsim.validation.budget",
    "clsim.waveio": "clsim.waveforms.io",
    "clsim.decompose": "clsim.waveforms.decompose",
    "clsim.pointing": "clsim.waveforms.pointing",
    "clsim.metrics": "clsim.waveforms.metrics",
    "clsim.georegister": "tlsvox.register.georegister",
    "clsim.cli_sim": "clsim.cli.simulate",
    "clsim.cli_waveforms": "clsim.cli.waveforms",
    "tlsvox.cli_register": "tlsvox.cli.register",
    "tlsvox.cli_voxelize": "tlsvox.cli.voxelize",
}


def new_name(old: str) -> str | None:
    """The current dotted name of a moved module, or None.

    >>> new_name("clsim.decompose._batch")
    'clsim.waveforms.decompose._batch'
    >>> new_name("clsim.sensor") is None
    True
    """
    for prefix, target in MOVED.items():
        if old == prefix or old.startswith(prefix + "."):
            return target + old[len(prefix):]
    return None


class _Alias(importlib.abc.Loader):
    def __init__(self, target: str):
        self.target = target

    def create_module(self, spec):
        module = importlib.import_module(self.target)
        self.own_spec = module.__spec__
        return module

    def exec_module(self, module):
        module.__spec__ = self.own_spec  # the import system set the alias's spec


class _MovedFinder(importlib.abc.MetaPathFinder):
    def find_spec(self, fullname, path=None, target=None):
        new = new_name(fullname)
        if new is None:
            return None
        warnings.warn(f"{fullname} moved to {new}; import it from there (the old path goes in 0.3)",
                      DeprecationWarning, stacklevel=3)
        return importlib.util.spec_from_loader(fullname, _Alias(new))


def install() -> None:
    """Put the finder first on ``sys.meta_path`` (once)."""
    if not any(isinstance(f, _MovedFinder) for f in sys.meta_path):
        sys.meta_path.insert(0, _MovedFinder())


def renamed(package: str, old: str, module: str, new: str | None):
    """The object an old public name of ``package`` stands for (``new`` in ``module``, or the module itself
    when ``new`` is None), with a :class:`DeprecationWarning` that names it.

    >>> import warnings
    >>> with warnings.catch_warnings(record=True) as w:
    ...     warnings.simplefilter("always")
    ...     obj = renamed("clsim", "Mode", "clsim.transport.setup", "InteractionModel")
    >>> obj.__name__, "clsim.InteractionModel" in str(w[0].message)
    ('InteractionModel', True)
    """
    mod = importlib.import_module(module)
    target = f"{package}.{new}" if new else module  # the package exports the new name
    warnings.warn(f"{package}.{old} is now {target}; use that name (the old one goes in 0.3)",
                  DeprecationWarning, stacklevel=3)
    return mod if new is None else getattr(mod, new)

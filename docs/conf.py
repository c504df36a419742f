"""Sphinx configuration of the voxlidar documentation (``make docs``)."""

from __future__ import annotations

import sys
from importlib.metadata import version as _version
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE / "_ext"))

project = "voxlidar"
author = "the voxlidar developers"
copyright = "2026, the voxlidar developers"
release = _version("voxlidar")
version = ".".join(release.split(".")[:2])

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.mathjax",
    "numpydoc",
    "sphinxarg.ext",
    "voxlidar_api",
]

source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
exclude_patterns = ["_build", "_ext", "**/*.json"]
root_doc = "index"

# MyST: $...$ maths, heading anchors for the pages' links to each other's sections
myst_enable_extensions = ["dollarmath", "colon_fence", "deflist"]
myst_heading_anchors = 4

# autodoc + numpydoc: the docstrings are numpydoc; members in source order
autodoc_member_order = "bysource"
autodoc_typehints = "none"
autodoc_default_options = {"members": True, "undoc-members": False, "show-inheritance": False}
numpydoc_show_class_members = False
numpydoc_class_members_toctree = False
numpydoc_xref_param_type = False

html_theme = "furo"
html_title = f"voxlidar {release}"
html_static_path: list[str] = []
html_logo = None

nitpicky = False
# the benchmark pages are written by the scripts in benchmarks/ and open at level 2
suppress_warnings = ["myst.header"]

"""Sphinx configuration of the sionna_mmir documentation.

Build it with ``python -m sphinx -W --keep-going -b html docs <out>`` (the test
``tests/test_docs.py::test_sphinx_build_has_no_warnings`` does exactly that).
Autodoc imports the package, which configures Dr.Jit's LLVM backend.
"""
from __future__ import annotations

import os
import pathlib
import sys
import warnings

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
os.environ.setdefault("MPLBACKEND", "Agg")

import sionna_mmir  # noqa: E402  (after the path is set)

# numpydoc parses the docstrings of Sionna RT's classes that ours subclass; their
# sections are Sionna's business, not warnings of this build
warnings.filterwarnings("ignore", message="Unknown section", category=UserWarning)

project = "sionna_mmir"
author = "sionna_mmir developers"
release = version = sionna_mmir.__version__

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.mathjax",
    "sphinx.ext.viewcode",
    "numpydoc",
    "myst_parser",
]

source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
root_doc = "index"
exclude_patterns = ["_build"]

autodoc_default_options = {"members": True, "undoc-members": False, "show-inheritance": True,
                           "ignore-module-all": True}   # re-exports: documented where defined
autodoc_member_order = "bysource"
autodoc_typehints = "none"           # types are written in the numpydoc sections
autoclass_content = "class"
numpydoc_show_class_members = False
numpydoc_class_members_toctree = False
numpydoc_xref_param_type = False

myst_heading_anchors = 3

html_theme = "alabaster"
html_static_path: list[str] = []


def _skip_foreign(app, what, name, obj, skip, options):
    """Document only what the package defines (not names it imports from SciPy & co)."""
    module = getattr(obj, "__module__", None)
    if what == "module" and isinstance(module, str) and not module.startswith("sionna_mmir"):
        return True
    return None


def setup(app):
    app.connect("autodoc-skip-member", _skip_foreign)

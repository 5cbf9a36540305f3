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


def _canonical(name: str):
    """``sionna_mmir.scene.RadarScene`` -> ``sionna_mmir.scene.scene.RadarScene``: where a
    re-exported object is defined (and documented)."""
    import importlib

    parts = name.split(".")
    for i in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:i]))
        except Exception:  # noqa: BLE001  (not a module: try a shorter prefix)
            continue
        try:
            for attr in parts[i:]:
                obj = getattr(obj, attr)
        except AttributeError:
            return None
        module = getattr(obj, "__module__", None)
        qualname = getattr(obj, "__qualname__", None)
        if isinstance(obj, type(importlib)):
            return obj.__name__
        return f"{module}.{qualname}" if module and qualname else None
    return None


def _resolve_reexport(app, env, node, contnode):
    """Resolve references to re-exported names and to names relative to the current
    package, so that ``:class:`~sionna_mmir.scene.RadarScene``` links to its page."""
    if node.get("refdomain") != "py":
        return None
    target = node["reftarget"].lstrip("~.")
    module = node.get("py:module") or ""
    candidates = [target]
    while module:
        candidates.append(f"{module}.{target}")
        module = module.rpartition(".")[0]
    domain = env.get_domain("py")
    for cand in candidates:
        if not cand.startswith("sionna_mmir"):
            continue
        canonical = _canonical(cand)
        if canonical and canonical != node["reftarget"]:
            found = domain.resolve_any_xref(env, node.get("refdoc", ""), app.builder, canonical,
                                            node, contnode)
            if found:
                return found[0][1]
    return None


def _compile_numpydoc_template_once():
    """numpydoc compiles its Jinja template anew for every docstring (a sixth
    of this build's time); the template is the same for all of them."""
    from numpydoc import docscrape_sphinx

    base, compiled = docscrape_sphinx.SandboxedEnvironment, {}

    class OnceEnvironment(base):
        def get_template(self, name, *args, **kwargs):
            if name not in compiled:
                compiled[name] = super().get_template(name, *args, **kwargs)
            return compiled[name]

    docscrape_sphinx.SandboxedEnvironment = OnceEnvironment


def setup(app):
    _compile_numpydoc_template_once()
    app.connect("autodoc-skip-member", _skip_foreign)
    app.connect("missing-reference", _resolve_reexport)

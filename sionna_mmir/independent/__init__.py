"""independent truths: code that shares nothing with the model it scores.

Plain NumPy / SciPy (with trimesh for ray-triangle visibility); nothing here
imports :mod:`sionna_mmir.paths`, :mod:`sionna_mmir.bsdf`,
:mod:`sionna_mmir.effects`, Mitsuba or Dr.Jit (tests check the imports), so
what these modules render can score the package's own solver and residual
loop without the score being self-referential.

A reference radar renderer:

``physical_optics``
    :func:`render_reference`, :class:`ReferencePaths`: the renderer (physics
    and its limits in its docstring)
``truth``
    :func:`reference_truth`: a benchmark scene rendered to a
    :class:`~sionna_mmir.captures.Capture`
the other modules (``scatterers`` ... ``constants``)
    its parts: sub-facet sets and visibility, physical-optics weights, the
    exact phase integral over a triangle, per-pair phasors, image-theory
    chains with lit regions by beam tracing, planar pieces, polygon clipping,
    ITU-R P.2040 reflection, rough-surface terms, element gains

An undeclared-effect capture generator:

``undeclared``
    :func:`~.undeclared.make_case`, :func:`~.undeclared.suite`: a room with
    corner reflectors and clutter, with library effects, pairs, a pose
    offset and two effects outside the library planted; ColoRadar writer
``undeclared_scene``, ``undeclared_adc``, ``undeclared_effects``, ``undeclared_io``
    its scene, exact per-pair ADC synthesis, effect physics and writer
"""
import importlib

_LAZY = {"ReferencePaths": "physical_optics", "render_reference": "physical_optics",
         "reference_truth": "truth"}

__all__ = sorted(_LAZY)


def __getattr__(name):
    if name not in _LAZY:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{_LAZY[name]}"), name)
    globals()[name] = value
    return value

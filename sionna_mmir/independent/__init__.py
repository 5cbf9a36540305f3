"""independent truths: code that shares nothing with the model it scores.

A reference radar renderer written in plain NumPy / SciPy, with trimesh for
ray-triangle visibility.  It imports nothing from :mod:`sionna_mmir.paths`,
:mod:`sionna_mmir.bsdf`, Mitsuba or Dr.Jit (a test checks the imports), so
captures rendered with it can score the package's own solver without the
score being self-referential.

=====================  ======================================================
physical_optics        :func:`render_reference`, :class:`ReferencePaths`: the
                       renderer (physics and its limits in its docstring)
truth                  :func:`reference_truth`: a benchmark scene rendered to
                       a :class:`~sionna_mmir.captures.Capture`
scatterers             sub-facet sets of single bounces and image chains,
                       with their visibility
facets                 physical-optics weights and the split into sub-facets
quadrature             sub-facet grids and the exact phase integral over a
                       triangle
accumulate             per-pair phasors, merging into paths
images                 image-theory chains (double / triple bounce), lit
                       regions by beam tracing
planes                 coplanar faces grouped into planar pieces
polygons               convex polygon clipping and central projection
materials              ITU-R P.2040 permittivity, Fresnel and slab reflection
rough                  Rayleigh loss and the Kirchhoff rough-surface sigma0
patterns               isotropic and ``cos^q`` element gains
mesh                   scene assembly, input checks, visibility (ray casts)
phasors                ``exp(j phase)`` of large float64 phase arrays
constants              speed of light, vacuum permittivity
=====================  ======================================================
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

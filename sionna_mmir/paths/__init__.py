"""Differentiable radar paths: ray generation, the Monte Carlo path solver, SMS.

``options``
    :class:`SolverOptions`: the solver's settings and named presets
``solver``
    :class:`RadarPathSolver`, a subclass of Sionna RT's ``PathSolver``
``sampling``
    candidate-ray strategies (random cone, facet quadrature)
``transport``
    the transport stages (surface, connection, coherent, scattered,
    continuation, diffraction, motion)
``assemble``
    per-element legs and factorised paths
``boundary``
    the visibility-boundary term of the geometry and pose gradients
``radar_paths``
    :class:`RadarPaths`, per (tx, rx, path) amplitudes and delays
``render``
    :func:`render`, :func:`render_capture`
``sms``
    specular manifold sampling (Newton walk + IFT gradients)

Importing a submodule initialises the Mitsuba backend.
"""
from .options import SolverOptions  # noqa: E402,F401
from .radar_paths import RadarPaths  # noqa: E402,F401
from .render import render, render_capture, to_numpy  # noqa: E402,F401
from .solver import RadarPathSolver  # noqa: E402,F401

__all__ = ["RadarPaths", "RadarPathSolver", "SolverOptions", "render", "render_capture",
           "to_numpy"]

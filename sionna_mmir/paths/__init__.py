"""Differentiable radar paths: ray generation, the Monte Carlo path solver, SMS.

``solver``  :class:`RadarPathSolver`, a subclass of Sionna RT's ``PathSolver``
``paths``   :class:`RadarPaths`, per (tx, rx, path) amplitudes and delays
``sms``     specular manifold sampling (Newton walk + IFT gradients)

Importing a submodule initialises the Mitsuba backend.
"""
from .radar_paths import RadarPaths  # noqa: E402,F401
from .render import render, to_numpy  # noqa: E402,F401
from .solver import RadarPathSolver  # noqa: E402,F401

__all__ = ["RadarPaths", "RadarPathSolver", "render", "to_numpy"]

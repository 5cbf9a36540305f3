"""Shared Dr.Jit helpers for the lobes of :mod:`sionna_mmir.bsdf`.

All lobes work in the *local shading frame*: the surface normal is ``+z``,
``wi`` points from the surface towards the transmitter (or previous vertex),
``wo`` from the surface towards the receiver / next bounce; both are unit
vectors pointing away from the surface.
"""
from __future__ import annotations

from ..utils.backend import init_backend

init_backend()

import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402

__all__ = ["mi", "dr", "as_float", "reflect_z"]


def as_float(x):
    """Python scalar / ``mi.Float`` -> ``mi.Float`` (keeps AD graphs intact)."""
    return x if isinstance(x, mi.Float) else mi.Float(x)


def reflect_z(w):
    """Mirror direction about the normal ``+z``: ``(-w.x, -w.y, w.z)``."""
    return mi.Vector3f(-w.x, -w.y, w.z)

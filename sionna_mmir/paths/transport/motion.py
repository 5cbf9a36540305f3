"""Delay rates from object and radar velocities (Doppler; not in the paper).

A path's delay rate is ``d tau / dt = sum_l v_l . dL/dx_l / c``: a vertex
``x_l`` moving with ``v_l`` changes the two adjacent segments by
``v_l . (u_in - u_out)``, and a moving radar shortens both end legs by
``v_radar`` projected on them.  Rates are detached (they set Doppler, not a
learned parameter).
"""
from __future__ import annotations

import numpy as np

from ...errors import InputValueError
from ...radio_materials.fresnel import SPEED_OF_LIGHT
from ...utils.backend import init_backend

init_backend()

import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402


def velocity_table(names, velocities):
    """Per-object velocities ``[3 x mi.Float]`` (object order ``names``), or
    ``None`` when nothing moves."""
    if not velocities:
        return None
    table = np.zeros((len(names), 3), dtype=np.float32)
    for i, name in enumerate(names):
        if name in velocities:
            vv = np.asarray(velocities[name], dtype=np.float64).reshape(-1)
            if vv.shape != (3,) or not np.isfinite(vv).all():
                raise InputValueError(f"velocities[{name!r}] must be 3 finite numbers [m/s]")
            table[i] = vv
    return [mi.Float(table[:, c]) for c in range(3)]


def radar_velocity(value):
    """``mi.Vector3f`` radar velocity [m/s] (zero for ``None``)."""
    v = np.asarray(value, dtype=float).reshape(3) if value is not None else np.zeros(3)
    return mi.Vector3f(*(float(c) for c in v))


def vertex_rate(vel, obj, u_in, u_out):
    """``v . (u_in - u_out)`` of the moving vertex on lanes hitting object ``obj``."""
    if vel is None:
        return dr.zeros(mi.Float, dr.width(obj))
    v = mi.Vector3f(*(dr.gather(mi.Float, vel[c], obj) for c in range(3)))
    # dL/dx for the two adjacent segments: unit(x - prev) + unit(x - next)
    return dr.detach(dr.dot(v, u_in - u_out))


def path_rate(ctx, st, k_in, k_t):
    """Delay rate [s/s] of the path ending at the current interaction."""
    r = st.rate_chain + vertex_rate(ctx.velocities, st.it.obj, k_in, k_t)
    # moving radar: both end legs shorten by v . direction to the scene
    r = r - dr.detach(dr.dot(ctx.v_radar, st.k0) + dr.dot(ctx.v_radar, -k_t))
    return r / SPEED_OF_LIGHT

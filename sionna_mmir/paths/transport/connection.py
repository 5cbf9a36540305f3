"""The connection stage: ``x_l -> Tx`` by a deterministic shadow ray.

Every interaction is connected to the transmitter through the array's phase
centre (paper eq. 3: next-event estimation); the per-element legs are formed
later (:mod:`sionna_mmir.paths.assemble`).  Visibility is traced outside AD
and frozen on the tape, so a replay never re-traces it.
"""
from __future__ import annotations

from ...utils.backend import init_backend
from ..polarization import transverse
from .motion import path_rate
from .state import RAY_EPSILON, Connection

init_backend()

import drjit as dr  # noqa: E402


def connect(ctx, st, surf) -> Connection:
    """Direction, cosine, visibility, Tx polarisation and delay rate of the
    connection from ``surf.x`` to the array centre."""
    to_c = ctx.c_w - surf.x
    d_c = dr.norm(to_c)
    k_t = to_c / d_c
    cos_t = dr.dot(surf.n, k_t)
    ok = st.it.valid & (cos_t > 0) & (dr.dot(surf.ng, k_t) > 0) & (surf.cos_in > 0)
    ok &= ctx.tape.freeze_call(ctx.geo.visible, surf.x + surf.ng * RAY_EPSILON, ctx.c_w, ok)
    cos_t = dr.maximum(cos_t, 0.0)
    pose = ctx.pose
    e_t = transverse(pose.to_scene(ctx.ptx.polarization(pose.to_radar(-k_t))), k_t)
    rate = path_rate(ctx, st, surf.k_in, k_t)
    return Connection(k_t=k_t, cos_t=cos_t, ok=ok, e_t=e_t, rate=rate)

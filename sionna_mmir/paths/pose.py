"""Differentiable radar pose: element positions and directions in the scene frame.

The pose is the scene's ``position`` [3] (m) and ``orientation`` [3]
(yaw, pitch, roll; rad) tensors (:class:`~sionna_mmir.scene.RadarScene`),
``R = Rz(yaw) Ry(pitch) Rx(roll)`` (Sionna RT's convention, the same as
:func:`sionna_mmir.radar.config.rotation_matrix`).  Everything here is Dr.Jit
and differentiable w.r.t. both tensors.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..utils.backend import init_backend

init_backend()

import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402


def _component(t, i):
    return dr.gather(mi.Float, t.array if isinstance(t, mi.TensorXf) else t, i)


@dataclass
class Pose:
    """Rotation rows and origin of the radar in the scene (Dr.Jit, AD).

    Parameters
    ----------
    rows : tuple of mi.Vector3f
        the three rows of ``R`` (radar -> scene)
    origin : mi.Point3f
        radar origin in the scene [m]
    """

    rows: tuple
    origin: object

    @classmethod
    def from_tensors(cls, position, orientation) -> "Pose":
        a, b, c = (_component(orientation, i) for i in range(3))
        ca, sa, cb, sb, cc, sc = dr.cos(a), dr.sin(a), dr.cos(b), dr.sin(b), dr.cos(c), dr.sin(c)
        rows = (mi.Vector3f(ca * cb, ca * sb * sc - sa * cc, ca * sb * cc + sa * sc),
                mi.Vector3f(sa * cb, sa * sb * sc + ca * cc, sa * sb * cc - ca * sc),
                mi.Vector3f(-sb, cb * sc, cb * cc))
        origin = mi.Point3f(*(_component(position, i) for i in range(3)))
        return cls(rows=rows, origin=origin)

    def to_scene(self, v):
        """Rotate a radar-frame vector into the scene frame."""
        return mi.Vector3f(dr.dot(self.rows[0], v), dr.dot(self.rows[1], v), dr.dot(self.rows[2], v))

    def to_radar(self, v):
        """Rotate a scene-frame vector into the radar frame (``R^T v``)."""
        r0, r1, r2 = self.rows
        return mi.Vector3f(r0.x * v.x + r1.x * v.y + r2.x * v.z,
                           r0.y * v.x + r1.y * v.y + r2.y * v.z,
                           r0.z * v.x + r1.z * v.y + r2.z * v.z)

    def point(self, local: np.ndarray):
        """Scene positions of radar-frame points ``local`` [n, 3] (m) -> ``mi.Point3f`` [n]."""
        local = np.asarray(local, dtype=np.float32).reshape(-1, 3)
        v = mi.Vector3f(mi.Float(local[:, 0]), mi.Float(local[:, 1]), mi.Float(local[:, 2]))
        return self.origin + self.to_scene(v)

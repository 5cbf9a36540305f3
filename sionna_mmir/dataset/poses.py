"""Radar poses of a dataset: an explicit list, or a straight-line / circular trajectory.

Every pose is a ``dict``::

    position     [3] radar origin in the scene [m]
    orientation  [3] (yaw, pitch, roll) [rad], Sionna's convention
                 (:func:`~sionna_mmir.radar.config.rotation_matrix`)
    velocity     [3] radar velocity in the scene [m/s] (Doppler)
    time         seconds since the first frame [s]

Spec forms (``poses`` of a dataset spec; angles in degrees there):

* ``{"type": "list", "poses": [{"position": [x, y, z], "orientation_deg":
  [yaw, pitch, roll], "velocity": [vx, vy, vz]}, ...]}``:
  ``orientation_deg`` and ``velocity`` default to zero; ``time`` is
  ``k * frame_period``.
* ``{"type": "line", "start": [x, y, z], "direction": [dx, dy, dz], "speed":
  v, "frames": N, "frame_period": T, "orientation_deg": [...]}``: position
  ``start + k T v d`` (``d`` normalised), velocity ``v d``; the radar faces
  along ``d`` unless ``orientation_deg`` is given.
* ``{"type": "circle", "center": [x, y, z], "radius": r, "speed": v,
  "frames": N, "frame_period": T, "start_angle_deg": a0, "facing": "center" |
  "tangent" | "outward"}``: counter-clockwise about ``+z`` at height
  ``center[2]``: angle ``a0 + k T v / r``, velocity ``v`` along the tangent;
  the radar faces the centre (default), along the tangent or outwards, level
  (pitch = roll = 0).

``frame_period`` defaults to 0.1 s.
"""
from __future__ import annotations

import math

import numpy as np

from ..errors import ConfigError

DEFAULT_FRAME_PERIOD_S = 0.1


def _vec(value, key: str, where: str, default=None) -> np.ndarray:
    if value is None and default is not None:
        value = default
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        arr = np.zeros(0)
    if arr.shape != (3,) or not np.isfinite(arr).all():
        raise ConfigError(f"{where}: poses.{key} must be three finite numbers, got {value!r}")
    return arr


def _number(d: dict, key: str, where: str, default=None, positive=True) -> float:
    value = d.get(key, default)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ConfigError(f"{where}: poses.{key} must be a finite number, got {value!r}")
    if positive and value <= 0:
        raise ConfigError(f"{where}: poses.{key} must be > 0, got {value!r}")
    return float(value)


def _frames(d: dict, where: str) -> int:
    n = d.get("frames")
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise ConfigError(f"{where}: poses.frames must be an integer >= 1, got {n!r}")
    return n


def facing(direction) -> np.ndarray:
    """``(yaw, pitch, 0)`` [rad] that points the radar's ``+x`` along ``direction``."""
    d = np.asarray(direction, dtype=np.float64)
    d = d / np.linalg.norm(d)
    return np.array([math.atan2(d[1], d[0]), -math.asin(max(-1.0, min(1.0, d[2]))), 0.0])


def _pose(position, orientation, velocity, time) -> dict:
    return {"position": [float(v) for v in position],
            "orientation": [float(v) for v in orientation],
            "velocity": [float(v) for v in velocity], "time": float(time)}


def line_trajectory(start, direction, speed: float, frames: int,
                    frame_period: float = DEFAULT_FRAME_PERIOD_S, orientation=None) -> list:
    """Poses along a straight line (see module docstring); ``orientation`` in rad."""
    d = np.asarray(direction, dtype=np.float64)
    d = d / np.linalg.norm(d)
    ori = facing(d) if orientation is None else np.asarray(orientation, dtype=np.float64)
    start = np.asarray(start, dtype=np.float64)
    return [_pose(start + d * speed * k * frame_period, ori, d * speed, k * frame_period)
            for k in range(frames)]


def circle_trajectory(center, radius: float, speed: float, frames: int,
                      frame_period: float = DEFAULT_FRAME_PERIOD_S, start_angle: float = 0.0,
                      face: str = "center") -> list:
    """Poses on a circle about ``+z`` (see module docstring); angles in rad."""
    offset = {"center": math.pi, "tangent": math.pi / 2, "outward": 0.0}[face]
    c = np.asarray(center, dtype=np.float64)
    out = []
    for k in range(frames):
        t = k * frame_period
        a = start_angle + speed * t / radius
        pos = c + radius * np.array([math.cos(a), math.sin(a), 0.0])
        vel = speed * np.array([-math.sin(a), math.cos(a), 0.0])
        out.append(_pose(pos, (a + offset, 0.0, 0.0), vel, t))
    return out


def poses_from_spec(spec: dict, where: str) -> list:
    """List of pose dicts from a spec's ``poses`` entry; ``ConfigError`` naming ``where``."""
    if not isinstance(spec, dict):
        raise ConfigError(f"{where}: poses must be an object with a 'type', got {spec!r}")
    kind = spec.get("type")
    period = _number(spec, "frame_period", where, DEFAULT_FRAME_PERIOD_S)
    if kind == "list":
        items = spec.get("poses")
        if not isinstance(items, list) or not items:
            raise ConfigError(f"{where}: poses.poses must be a non-empty list")
        return [_pose(_vec(p.get("position"), "position", where),
                      np.radians(_vec(p.get("orientation_deg"), "orientation_deg", where, [0] * 3)),
                      _vec(p.get("velocity"), "velocity", where, [0] * 3), k * period)
                for k, p in enumerate(items)]
    if kind == "line":
        direction = _vec(spec.get("direction"), "direction", where)
        if np.linalg.norm(direction) == 0:
            raise ConfigError(f"{where}: poses.direction must not be zero")
        ori = spec.get("orientation_deg")
        return line_trajectory(_vec(spec.get("start"), "start", where), direction,
                               _number(spec, "speed", where, positive=False), _frames(spec, where),
                               period, None if ori is None else
                               np.radians(_vec(ori, "orientation_deg", where)))
    if kind == "circle":
        face = spec.get("facing", "center")
        if face not in ("center", "tangent", "outward"):
            raise ConfigError(f"{where}: poses.facing must be center, tangent or outward, "
                              f"got {face!r}")
        return circle_trajectory(_vec(spec.get("center"), "center", where),
                                 _number(spec, "radius", where),
                                 _number(spec, "speed", where, positive=False),
                                 _frames(spec, where), period,
                                 math.radians(_number(spec, "start_angle_deg", where, 0.0, False)),
                                 face)
    raise ConfigError(f"{where}: poses.type must be 'list', 'line' or 'circle', got {kind!r}")

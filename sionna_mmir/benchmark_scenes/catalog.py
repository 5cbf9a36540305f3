"""The benchmark-scene catalog: clean geometry, nominal materials, radar pose.

Every scene is built procedurally by :func:`build_scene` from a handful of
primitives (rectangles, convex polygons, boxes, walls with recessed openings,
faceted cylinders), all in metres, in a world frame with ``+z`` up and the
ground / floor at ``z = 0``.  The radar (a cascade radar, e.g.
``RadarConfig.mmwcas()``) stands at ``(0, 0, 1)`` with orientation
``(yaw, pitch, roll) = (0, 0, 0)``, i.e. it looks along world ``+x`` (radar
frame: ``+x`` boresight, ``+y`` left, ``+z`` up; Sionna's ``R = Rz(yaw)
Ry(pitch) Rx(roll)``).

Geometry rules (checked by :meth:`SceneSpec.field_of_view_violations`):

* every vertex lies at least :data:`MIN_FORWARD_M` (1 m) in front of the radar
  (radar-frame ``x >= 1``), at most :data:`MAX_RANGE_M` (12 m) from it, and
  within ``+/-`` :data:`MAX_AZIMUTH_DEG` (60 deg) of boresight in azimuth.
  Floors, ceilings and grounds are convex polygons clipped to a
  ``+/-58 deg`` wedge and an 11.9 m circle; side walls start where the
  wedge reaches them.  Since the allowed region is convex, a triangle whose
  vertices are inside lies inside entirely;
* triangles are wound so that their normals face the room / the street (the
  side the radar sees); closed boxes face outward; faces resting on the floor
  or against a wall are left out (they are never visible);
* vertices are shared only *within* a flat piece (a wall with its openings, a
  box side): pieces meeting at a crease have their own vertices, so trimesh's
  vertex normals equal the face normals on every flat part.  Faceted
  cylinders (poles) share their side vertices (smooth normals);
* each object has one nominal ITU-R P.2040 material valid at 77 GHz
  (:data:`SceneSpec.materials`); the ground-truth, spatially varying material
  is :func:`sionna_mmir.benchmark_scenes.materials.true_vertex_materials`.

``seed`` moves furniture, doors, windows and cars by a few decimetres (and
picks e.g. which parking stall is empty); the layout of each scene is
otherwise fixed.  The same ``(name, seed)`` always gives the same geometry.
See the package docstring (:mod:`sionna_mmir.benchmark_scenes`) for the per-scene table.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import trimesh

from ..errors import InputValueError
from ..radio_materials import available_materials

#: Closest forward distance of any scene vertex from the radar [m].
MIN_FORWARD_M = 1.0
#: Farthest distance of any scene vertex from the radar [m].
MAX_RANGE_M = 12.0
#: Largest azimuth of any scene vertex [deg].
MAX_AZIMUTH_DEG = 60.0
#: Design frequency of the catalog's materials [Hz].
FREQUENCY_HZ = 77e9
#: Height of the radar above the floor [m].
RADAR_HEIGHT_M = 1.0

_WEDGE_TAN = np.tan(np.radians(58.0))  # floors / grounds stay 2 deg inside the FOV
_CLIP_RADIUS = 11.9                   # horizontal radius of the ground clip polygon


# --------------------------------------------------------------------------
# SceneSpec
# --------------------------------------------------------------------------
@dataclass
class SceneSpec:
    """One benchmark scene.

    Parameters
    ----------
    name : str
        Catalog key, e.g. ``"hallway"``.
    objects : dict
        Name -> ``trimesh.Trimesh`` (clean geometry, metres, world frame).
    materials : dict
        Name -> nominal ITU-R P.2040 material class (what a user would
        assign; valid at 77 GHz).
    radar_position : numpy.ndarray
        ``(3,)`` radar position [m].
    radar_orientation : numpy.ndarray
        ``(3,)`` radar ``(yaw, pitch, roll)`` [rad], Sionna convention.
    description : str
        How the scene is laid out (one paragraph).
    lidar_positions : numpy.ndarray, optional
        ``(S, 3)`` positions of the simulated LiDAR scans [m] (input of
        :func:`sionna_mmir.benchmark_scenes.lidar.lidarize`).
    seed : int, optional
        The layout seed it was built with.
    indoor : bool, optional
        True for rooms, False for street-type scenes.
    """

    name: str
    objects: dict
    materials: dict
    radar_position: np.ndarray
    radar_orientation: np.ndarray
    description: str
    lidar_positions: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    seed: int = 0
    indoor: bool = True

    # -- summaries ---------------------------------------------------------
    @property
    def n_triangles(self) -> int:
        """Total number of clean triangles."""
        return int(sum(len(m.faces) for m in self.objects.values()))

    @property
    def n_vertices(self) -> int:
        """Total number of clean vertices."""
        return int(sum(len(m.vertices) for m in self.objects.values()))

    def surface_area(self) -> float:
        """Total clean surface area [m^2]."""
        return float(sum(m.area for m in self.objects.values()))

    def radar_rotation(self) -> np.ndarray:
        """(3, 3) rotation radar frame -> world frame, ``Rz(yaw) Ry(pitch) Rx(roll)``."""
        return rotation_matrix(*np.asarray(self.radar_orientation, dtype=float))

    def to_radar_frame(self, points) -> np.ndarray:
        """World points (N, 3) -> radar-frame points (N, 3)."""
        p = np.asarray(points, dtype=float) - np.asarray(self.radar_position, dtype=float)
        return p @ self.radar_rotation()  # R^T p for row vectors

    def field_of_view_violations(self, min_forward=MIN_FORWARD_M, max_range=MAX_RANGE_M,
                                 max_azimuth_deg=MAX_AZIMUTH_DEG, tol=1e-6) -> list[str]:
        """Objects with vertices outside the radar's field of view (empty list: all fine)."""
        out = []
        for name, mesh in self.objects.items():
            q = self.to_radar_frame(mesh.vertices)
            rng = np.linalg.norm(q, axis=1)
            az = np.degrees(np.arctan2(np.abs(q[:, 1]), q[:, 0]))
            if q[:, 0].min() < min_forward - tol:
                out.append(f"{name}: forward distance {q[:, 0].min():.3f} m < {min_forward} m")
            if rng.max() > max_range + tol:
                out.append(f"{name}: range {rng.max():.3f} m > {max_range} m")
            if az.max() > max_azimuth_deg + tol:
                out.append(f"{name}: azimuth {az.max():.2f} deg > {max_azimuth_deg} deg")
        return out

    def refined(self, max_edge: float = 0.25) -> dict:
        """Clean objects subdivided until no edge exceeds ``max_edge`` [m].

        The geometry is identical; only vertices are added (creases stay
        unshared), so that per-vertex ground-truth materials
        (:func:`~sionna_mmir.benchmark_scenes.materials.true_vertex_materials`) vary
        across large walls when rendered.  Returns a new ``dict`` name ->
        ``trimesh.Trimesh``.
        """
        if not np.isfinite(max_edge) or max_edge <= 0:
            raise InputValueError(f"refined: max_edge must be > 0 m, got {max_edge!r}")
        out = {}
        for name, mesh in self.objects.items():
            v, f = trimesh.remesh.subdivide_to_size(mesh.vertices, mesh.faces,
                                                    max_edge=max_edge, max_iter=20)
            out[name] = trimesh.Trimesh(vertices=v, faces=f, process=False)
        return out

    def summary(self) -> str:
        """One line per object: name, material, triangles."""
        lines = [f"{self.name} (seed {self.seed}): {len(self.objects)} objects, "
                 f"{self.n_triangles} triangles, {self.surface_area():.1f} m^2"]
        for name, mesh in self.objects.items():
            lines.append(f"  {name:<16s} {self.materials[name]:<14s} {len(mesh.faces):5d} tri")
        return "\n".join(lines)


def rotation_matrix(yaw: float, pitch: float, roll: float) -> np.ndarray:
    """``Rz(yaw) Ry(pitch) Rx(roll)`` (Sionna RT convention), radians."""
    cy, sy = np.cos(yaw), np.sin(yaw)
    cp, sp = np.cos(pitch), np.sin(pitch)
    cr, sr = np.cos(roll), np.sin(roll)
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    return rz @ ry @ rx


# --------------------------------------------------------------------------
# Geometry primitives: each returns (vertices (N,3), faces (M,3))
# --------------------------------------------------------------------------
_Z = np.array([0.0, 0.0, 1.0])


def _rect(origin, a, b, normal):
    """Rectangle ``origin + s a + t b`` (s, t in [0, 1]) wound to face ``normal``."""
    origin, a, b = (np.asarray(x, dtype=float) for x in (origin, a, b))
    if np.dot(np.cross(a, b), normal) < 0:
        a, b = b, a
    v = np.array([origin, origin + a, origin + a + b, origin + b])
    return v, np.array([[0, 1, 2], [0, 2, 3]])


def _polygon(points, normal):
    """Convex planar polygon (any vertex order around it), fan-triangulated to face ``normal``."""
    p = np.asarray(points, dtype=float)
    c = p.mean(axis=0)
    n = np.asarray(normal, dtype=float) / np.linalg.norm(normal)
    u = p[0] - c
    u -= n * np.dot(u, n)
    u /= np.linalg.norm(u)
    w = np.cross(n, u)
    ang = np.arctan2((p - c) @ w, (p - c) @ u)
    p = p[np.argsort(ang)]  # counter-clockwise around n
    faces = np.array([[0, k, k + 1] for k in range(1, len(p) - 1)])
    return p, faces


def _box(lo, hi, skip=(), yaw=0.0, pivot=None):
    """Axis-aligned box [lo, hi], optionally turned by ``yaw`` about ``pivot`` (its centre).

    ``skip``: sides to leave out, among ``"+x" "-x" "+y" "-y" "+z" "-z"``
    (in the box's own, un-rotated frame).  Normals face outward.
    """
    lo, hi = np.asarray(lo, dtype=float), np.asarray(hi, dtype=float)
    dx, dy, dz = hi - lo
    ex, ey, ez = np.array([dx, 0, 0]), np.array([0, dy, 0]), np.array([0, 0, dz])
    sides = {
        "+x": (np.array([hi[0], lo[1], lo[2]]), ey, ez, [1, 0, 0]),
        "-x": (lo, ey, ez, [-1, 0, 0]),
        "+y": (np.array([lo[0], hi[1], lo[2]]), ex, ez, [0, 1, 0]),
        "-y": (lo, ex, ez, [0, -1, 0]),
        "+z": (np.array([lo[0], lo[1], hi[2]]), ex, ey, [0, 0, 1]),
        "-z": (lo, ex, ey, [0, 0, -1]),
    }
    parts = [_rect(o, a, b, n) for key, (o, a, b, n) in sides.items() if key not in skip]
    v, f = _concat(parts)
    if yaw:
        pivot = (lo + hi) / 2 if pivot is None else np.asarray(pivot, dtype=float)
        rot = rotation_matrix(yaw, 0.0, 0.0)
        v = (v - pivot) @ rot.T + pivot
    return v, f


def _cylinder(x, y, z0, z1, radius, n_sides=12, top=True):
    """Vertical faceted cylinder (no bottom cap), side vertices shared (smooth)."""
    ang = 2 * np.pi * np.arange(n_sides) / n_sides
    ring = np.column_stack([x + radius * np.cos(ang), y + radius * np.sin(ang)])
    lower = np.column_stack([ring, np.full(n_sides, z0)])
    upper = np.column_stack([ring, np.full(n_sides, z1)])
    v = np.vstack([lower, upper])
    k = np.arange(n_sides)
    k1 = (k + 1) % n_sides
    faces = np.vstack([np.column_stack([k, k1, n_sides + k1]),
                       np.column_stack([k, n_sides + k1, n_sides + k])])
    parts = [(v, faces)]
    if top:
        parts.append(_polygon(upper, _Z))
    return _concat(parts)


def _wall(origin, u_dir, width, height, openings=(), normal=None):
    """Vertical wall with rectangular recessed openings.

    Parameters
    ----------
    origin : array_like
        ``(3,)`` bottom corner of the wall [m].
    u_dir : array_like
        ``(3,)`` horizontal direction along the wall (unit after
        normalising).
    width, height : float
        Wall length along ``u_dir`` and height along ``+z`` [m].
    openings : sequence of tuple, optional
        ``(u0, u1, v0, v1, depth)`` each: an opening from ``u0`` to ``u1``
        along the wall and ``v0`` to ``v1`` up, recessed ``depth`` into the
        wall [m].
    normal : array_like, optional
        ``(3,)`` side the wall faces (default ``u_dir x z``).

    Returns
    -------
    wall : tuple
        The wall: its face with holes plus the four reveals of every opening.
    panes : list
        One rectangle per opening (the pane / door at the back of the recess,
        facing like the wall).
    """
    o = np.asarray(origin, dtype=float)
    u = np.asarray(u_dir, dtype=float)
    u = u / np.linalg.norm(u)
    n = np.cross(u, _Z) if normal is None else np.asarray(normal, dtype=float)
    n = n / np.linalg.norm(n)
    us = sorted({0.0, float(width), *[float(x) for op in openings for x in op[:2]]})
    vs = sorted({0.0, float(height), *[float(x) for op in openings for x in op[2:4]]})
    grid = np.array([[o + a * u + b * _Z for b in vs] for a in us])  # (nu, nv, 3)
    nv = len(vs)
    faces = []
    for i in range(len(us) - 1):
        for j in range(len(vs) - 1):
            cu, cv = (us[i] + us[i + 1]) / 2, (vs[j] + vs[j + 1]) / 2
            if any(op[0] < cu < op[1] and op[2] < cv < op[3] for op in openings):
                continue
            a, b, c, d = i * nv + j, (i + 1) * nv + j, (i + 1) * nv + j + 1, i * nv + j + 1
            faces += [[a, b, c], [a, c, d]]
    v = grid.reshape(-1, 3)
    f = np.array(faces)
    if np.dot(np.cross(v[f[0, 1]] - v[f[0, 0]], v[f[0, 2]] - v[f[0, 0]]), n) < 0:
        f = f[:, ::-1]
    parts = [_compact(v, f)]
    panes = []
    for (u0, u1, v0, v1, depth) in openings:
        a = o + u0 * u + v0 * _Z
        du, dv, dd = (u1 - u0) * u, (v1 - v0) * _Z, -depth * n
        if depth > 0:
            parts.append(_rect(a, du, dd, _Z))                 # sill / threshold, faces up
            parts.append(_rect(a + dv, du, dd, -_Z))           # head, faces down
            parts.append(_rect(a, dv, dd, u))                  # side at u0, faces +u
            parts.append(_rect(a + du, dv, dd, -u))            # side at u1, faces -u
        panes.append(_rect(a + dd, du, dv, n))
    return _concat(parts), panes


def _compact(v, f):
    used = np.unique(f)
    remap = np.full(len(v), -1)
    remap[used] = np.arange(len(used))
    return v[used], remap[f]


def _concat(parts):
    vs, fs, off = [], [], 0
    for v, f in parts:
        vs.append(np.asarray(v, dtype=float))
        fs.append(np.asarray(f, dtype=np.int64) + off)
        off += len(v)
    if not vs:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    return np.vstack(vs), np.vstack(fs)


def _clip_convex(poly, halfplanes):
    """Clip a convex 2-D polygon by half-planes ``a x + b y <= c`` (Sutherland-Hodgman)."""
    pts = [np.asarray(p, dtype=float) for p in poly]
    for a, b, c in halfplanes:
        out = []
        for k in range(len(pts)):
            p, q = pts[k], pts[(k + 1) % len(pts)]
            fp, fq = a * p[0] + b * p[1] - c, a * q[0] + b * q[1] - c
            if fp <= 0:
                out.append(p)
            if fp * fq < 0:
                out.append(p + (q - p) * fp / (fp - fq))
        pts = out
        if not pts:
            break
    return np.array(pts)


def _fov_halfplanes(x_min=MIN_FORWARD_M, radius=_CLIP_RADIUS, n_circle=32):
    """Half-planes of the radar's ground footprint: x >= x_min, |y| <= tan(58) x, r <= radius."""
    hp = [(-1.0, 0.0, -x_min), (-_WEDGE_TAN, 1.0, 0.0), (-_WEDGE_TAN, -1.0, 0.0)]
    # inscribed regular polygon of the circle: every vertex within `radius`
    apothem = radius * np.cos(np.pi / n_circle)
    for k in range(n_circle):
        t = 2 * np.pi * (k + 0.5) / n_circle
        hp.append((np.cos(t), np.sin(t), apothem))
    return hp


def _plane_in_fov(rect_xy, z, normal, extra=(), radius=_CLIP_RADIUS):
    """Horizontal convex polygon: rectangle ``(x0, x1, y0, y1)`` clipped to the FOV at height z."""
    x0, x1, y0, y1 = rect_xy
    poly = _clip_convex([(x0, y0), (x1, y0), (x1, y1), (x0, y1)],
                        _fov_halfplanes(radius=radius) + list(extra))
    p3 = np.column_stack([poly, np.full(len(poly), z)])
    return _polygon(p3, normal)


def _wall_start(half_width):
    """x where the FOV wedge reaches a side wall at |y| = half_width."""
    return max(MIN_FORWARD_M, half_width / _WEDGE_TAN)


# --------------------------------------------------------------------------
# Scene assembly helper
# --------------------------------------------------------------------------
class _Builder:
    def __init__(self):
        self.parts: dict[str, list] = {}
        self.materials: dict[str, str] = {}

    def add(self, name, material, *parts):
        if name in self.materials and self.materials[name] != material:
            raise AssertionError(f"object {name} re-added with another material")
        self.materials[name] = material
        self.parts.setdefault(name, []).extend(parts)

    def objects(self):
        out = {}
        for name, parts in self.parts.items():
            v, f = _concat(parts)
            out[name] = trimesh.Trimesh(vertices=v, faces=f, process=False)
        return out


def _room_shell(b, width, depth, height, floor_mat, wall_mat, ceiling_mat, end_mat,
                left_openings=(), right_openings=(), end_openings=(),
                left_pane=None, right_pane=None, end_pane=None, ceiling=True):
    """Floor, ceiling, side walls (y = +/- width/2) and end wall (x = depth).

    Side walls start where the radar's wedge reaches them.  Opening ``u``
    coordinates are world ``x`` for both side walls and world ``-y`` (from
    the left wall) for the end wall; ``*_pane``: ``(object, material)``
    receiving the recess panes.
    """
    hw = width / 2
    xs = _wall_start(hw)
    b.add("floor", floor_mat, _plane_in_fov((MIN_FORWARD_M, depth, -hw, hw), 0.0, _Z))
    if ceiling:
        b.add("ceiling", ceiling_mat, _plane_in_fov((MIN_FORWARD_M, depth, -hw, hw), height, -_Z))
    # left wall (y = +hw) faces -y; u along +x from x = xs
    lw, lp = _wall((xs, hw, 0), (1, 0, 0), depth - xs, height,
                   [(a - xs, c - xs, d, e, f) for a, c, d, e, f in left_openings], normal=(0, -1, 0))
    b.add("wall_left", wall_mat, lw)
    # right wall (y = -hw) faces +y; u along +x
    rw, rp = _wall((xs, -hw, 0), (1, 0, 0), depth - xs, height,
                   [(a - xs, c - xs, d, e, f) for a, c, d, e, f in right_openings], normal=(0, 1, 0))
    b.add("wall_right", wall_mat, rw)
    # end wall (x = depth) faces -x; u along -y starting at the left wall
    ew, ep = _wall((depth, hw, 0), (0, -1, 0), width, height, list(end_openings), normal=(-1, 0, 0))
    b.add("wall_end", end_mat, ew)
    for panes, target in ((lp, left_pane), (rp, right_pane), (ep, end_pane)):
        if panes:
            b.add(target[0], target[1], *panes)


def _car(b, prefix_body, prefix_cabin, prefix_tyres, x0, y0, length=4.2, width=1.8, yaw=0.0):
    """A parked car: metal body box, glass cabin box, four tyre boxes.

    ``(x0, y0)``: rear-right corner before turning by ``yaw`` about the centre.
    Body 0.25-1.0 m high, cabin 1.0-1.45 m (inset 0.1 m, 55 % of the length,
    set back from the front), tyres 0.62 m tall, protruding 1 cm sideways.
    """
    x1, y1 = x0 + length, y0 + width
    pivot = np.array([(x0 + x1) / 2, (y0 + y1) / 2, 0.0])
    b.add(prefix_body, "metal", _box((x0, y0, 0.25), (x1, y1, 1.0), skip=("-z",), yaw=yaw, pivot=pivot))
    cab_len = 0.55 * length
    cx0 = x0 + 0.2 * length
    b.add(prefix_cabin, "glass", _box((cx0, y0 + 0.1, 1.0), (cx0 + cab_len, y1 - 0.1, 1.45),
                                      skip=("-z",), yaw=yaw, pivot=pivot))
    tyres = []
    for xc in (x0 + 0.7, x1 - 0.8):
        for ya, yb in ((y0 - 0.01, y0 + 0.21), (y1 - 0.21, y1 + 0.01)):
            tyres.append(_box((xc - 0.31, ya, 0.0), (xc + 0.31, yb, 0.62), skip=("-z",),
                              yaw=yaw, pivot=pivot))
    b.add(prefix_tyres, "chipboard", *tyres)


# --------------------------------------------------------------------------
# The six scenes
# --------------------------------------------------------------------------
def _hallway(rng):
    b = _Builder()
    width, depth, height = 2.4, 11.0, 2.7
    hw = width / 2
    d1 = 4.0 + rng.uniform(-0.4, 0.4)
    d2 = 8.0 + rng.uniform(-0.4, 0.4)
    d3 = 6.0 + rng.uniform(-0.4, 0.4)
    _room_shell(
        b, width, depth, height, "concrete", "plasterboard", "ceiling_board", "concrete",
        left_openings=[(d1, d1 + 0.9, 0.0, 2.1, 0.08), (d2, d2 + 0.9, 0.0, 2.1, 0.08)],
        right_openings=[(d3, d3 + 0.9, 0.0, 2.1, 0.08)],
        end_openings=[(0.7, 1.7, 0.0, 2.2, 0.05)],
        left_pane=("doors", "wood"), right_pane=("doors", "wood"), end_pane=("glass_door", "glass"))
    lx = d1 + 1.2 + rng.uniform(0.0, 0.4)
    b.add("locker", "metal", _box((lx, hw - 0.45, 0.0), (lx + 0.9, hw, 1.9), skip=("-z", "+y")))
    rx = 2.0 + rng.uniform(-0.3, 0.3)
    b.add("radiator", "metal", _box((rx, -hw, 0.15), (rx + 1.0, -hw + 0.1, 0.75), skip=("-y",)))
    bx = 8.0 + rng.uniform(-0.3, 0.8)
    b.add("bench", "wood",
          _box((bx, -hw, 0.42), (bx + 1.5, -hw + 0.38, 0.47), skip=("-y",)),
          _box((bx + 0.1, -hw + 0.05, 0.0), (bx + 0.16, -hw + 0.33, 0.42), skip=("-z", "+z")),
          _box((bx + 1.34, -hw + 0.05, 0.0), (bx + 1.40, -hw + 0.33, 0.42), skip=("-z", "+z")))
    nx = 3.2 + rng.uniform(-0.5, 0.5)
    b.add("notice_board", "chipboard", _box((nx, -hw, 1.1), (nx + 1.2, -hw + 0.02, 1.9), skip=("-y",)))
    desc = ("Hallway 2.4 m wide, 2.7 m high, walls from x = 1 m to an end wall at x = 11 m "
            "with a recessed glass door; three recessed wooden doors in the side walls, a "
            "metal locker and a notice board, a metal radiator and a wooden bench.")
    lidar = np.array([[0.0, 0.0, 1.3], [0.0, 0.6, 1.6], [0.0, -0.6, 1.0]])
    return b, desc, lidar


def _lab(rng):
    b = _Builder()
    width, depth, height = 6.0, 9.0, 3.0
    hw = width / 2
    w0 = 3.0 + rng.uniform(-0.3, 0.3)
    door = 2.5 + rng.uniform(-0.3, 0.3)
    _room_shell(
        b, width, depth, height, "concrete", "plasterboard", "ceiling_board", "plasterboard",
        left_openings=[(door, door + 1.0, 0.0, 2.1, 0.1)],
        right_openings=[(w0, w0 + 1.4, 0.9, 2.3, 0.15), (w0 + 2.4, w0 + 3.8, 0.9, 2.3, 0.15)],
        end_openings=[],
        left_pane=("door", "wood"), right_pane=("windows", "glass"))
    # whiteboard on the end wall, metal locker and equipment rack
    wb = 1.2 + rng.uniform(-0.3, 0.3)  # from the left end of the end wall
    b.add("whiteboard", "chipboard",
          _box((depth - 0.02, hw - wb - 2.0, 0.9), (depth, hw - wb, 2.1), skip=("+x",)))
    b.add("locker", "metal", _box((4.0, hw - 0.5, 0.0), (4.9, hw, 1.95), skip=("-z", "+y")))
    b.add("rack", "metal", _box((depth - 0.8, -hw + 0.1, 0.0), (depth - 0.05, -hw + 0.7, 2.0),
                                skip=("-z",)))
    # benches: worktop (wood) on a cabinet (chipboard); monitors (glass)
    tops, cabinets, monitors = [], [], []
    bench_specs = [
        (2.7 + rng.uniform(-0.2, 0.2), -hw + 0.05, 2.4, 0.8),        # along the right wall
        (4.3 + rng.uniform(-0.3, 0.3), -0.4 + rng.uniform(-0.3, 0.3), 2.4, 0.9),  # island
        (6.2 + rng.uniform(-0.2, 0.2), hw - 0.85, 1.8, 0.8),         # along the left wall
    ]
    for bx, by, blen, bdep in bench_specs:
        tops.append(_box((bx, by, 0.86), (bx + blen, by + bdep, 0.9)))
        cabinets.append(_box((bx + 0.05, by + 0.05, 0.0), (bx + blen - 0.05, by + bdep - 0.05, 0.86),
                             skip=("-z", "+z")))
        mx = bx + 0.4 + rng.uniform(0, blen - 1.2)
        my = by + bdep / 2 - 0.275
        monitors.append(_box((mx, my, 0.9), (mx + 0.05, my + 0.55, 1.25), skip=("-z",)))
    b.add("worktops", "wood", *tops)
    b.add("cabinets", "chipboard", *cabinets)
    b.add("monitors", "glass", *monitors)
    desc = ("Laboratory 6 m wide, 3 m high, end wall at x = 9 m: three benches (wooden "
            "worktops on chipboard cabinets, a glass-fronted monitor on each), a metal "
            "equipment rack and locker, a whiteboard on the end wall, two recessed windows "
            "in the right wall and a recessed door in the left.")
    lidar = np.array([[0.0, 0.0, 1.3], [0.5, 1.2, 1.7], [0.5, -1.2, 1.7]])
    return b, desc, lidar


def _classroom(rng):
    b = _Builder()
    width, depth, height = 7.0, 10.0, 3.0
    hw = width / 2
    xs = _wall_start(hw)
    w0 = 3.2 + rng.uniform(-0.2, 0.2)
    door = 8.3 + rng.uniform(-0.3, 0.2)
    _room_shell(
        b, width, depth, height, "floorboard", "plasterboard", "ceiling_board", "concrete",
        left_openings=[(w0 + 2.0 * k, w0 + 2.0 * k + 1.3, 0.9, 2.4, 0.2) for k in range(3)],
        right_openings=[(door, door + 1.0, 0.0, 2.1, 0.1)],
        end_openings=[],
        left_pane=("windows", "glass"), right_pane=("door", "wood"))
    assert w0 + 5.3 < depth and w0 > xs
    # whiteboard on the front (end) wall
    b.add("whiteboard", "chipboard",
          _box((depth - 0.03, -1.8, 0.9), (depth, 1.8, 2.1), skip=("+x",)))
    # 3 x 3 desks: chipboard tops on metal legs
    tops, legs = [], []
    for row, xr in enumerate((4.0, 5.6, 7.2)):
        for yc in (-2.2, 0.0, 2.2):
            x0 = xr + rng.uniform(-0.15, 0.15)
            y0 = yc - 0.6 + rng.uniform(-0.15, 0.15)
            tops.append(_box((x0, y0, 0.72), (x0 + 0.6, y0 + 1.2, 0.75)))
            for lx, ly in ((x0 + 0.03, y0 + 0.03), (x0 + 0.53, y0 + 0.03),
                           (x0 + 0.03, y0 + 1.13), (x0 + 0.53, y0 + 1.13)):
                legs.append(_box((lx, ly, 0.0), (lx + 0.04, ly + 0.04, 0.72), skip=("-z", "+z")))
    b.add("desk_tops", "chipboard", *tops)
    b.add("desk_legs", "metal", *legs)
    tx = 8.6 + rng.uniform(-0.1, 0.2)
    b.add("teacher_desk", "wood", _box((tx, -0.8, 0.0), (tx + 0.7, 0.8, 0.76), skip=("-z",)))
    b.add("cabinet", "wood", _box((5.0, -hw, 0.0), (6.2, -hw + 0.45, 1.1), skip=("-z", "-y")))
    b.add("locker", "metal", _box((depth - 0.5, -hw, 0.0), (depth, -hw + 0.9, 1.9), skip=("-z", "-y", "+x")))
    desc = ("Classroom 7 m wide, 3 m high, front wall at x = 10 m with a whiteboard: "
            "3 x 3 desks (chipboard tops on thin metal legs), a wooden teacher's desk "
            "and cabinet, a metal locker, three recessed windows in the left wall and a "
            "recessed door in the right; wooden floor and ceiling tiles.")
    lidar = np.array([[0.0, 0.0, 1.3], [0.5, 1.5, 1.8], [0.5, -1.5, 1.8]])
    return b, desc, lidar


def _street(rng):
    b = _Builder()
    road_hw, kerb_w, kerb_h, walk_w, facade_h = 3.5, 0.15, 0.15, 1.85, 4.0
    b.add("road", "concrete", _plane_in_fov((MIN_FORWARD_M, 12.0, -road_hw, road_hw), 0.0, _Z))
    kerbs, walks = [], []
    y_face = road_hw + kerb_w + walk_w  # facade plane |y|
    for s in (1.0, -1.0):
        y_in, y_out = s * road_hw, s * (road_hw + kerb_w)
        x0 = _wall_start(road_hw + kerb_w)
        x1 = np.sqrt((_CLIP_RADIUS - 0.1) ** 2 - (road_hw + kerb_w) ** 2)
        kerbs.append(_box((x0, min(y_in, y_out), 0.0), (x1, max(y_in, y_out), kerb_h),
                          skip=("-z", "+y" if s > 0 else "-y")))
        walks.append(_plane_in_fov((MIN_FORWARD_M, 12.0, min(s * (road_hw + kerb_w), s * y_face),
                                    max(s * (road_hw + kerb_w), s * y_face)), kerb_h, _Z))
    b.add("kerbs", "concrete", *kerbs)
    b.add("sidewalks", "concrete", *walks)
    xf0 = _wall_start(y_face)
    xf1 = np.sqrt(MAX_RANGE_M ** 2 - y_face ** 2 - (facade_h - RADAR_HEIGHT_M) ** 2) - 0.1
    flen = xf1 - xf0
    # left facade (y = +y_face) faces -y; right facade faces +y
    wl = 0.6 + rng.uniform(-0.2, 0.2)
    dl = 3.3 + rng.uniform(-0.3, 0.3)
    left_open = [(wl, wl + 1.2, 1.0, 2.4, 0.12), (dl, dl + 1.1, 0.0, 2.3, 0.35)]
    left_open += [(dl + 1.6, dl + 2.8, 1.0, 2.4, 0.12)] if dl + 2.8 < flen - 0.2 else []
    lf, lp = _wall((xf0, y_face, kerb_h), (1, 0, 0), flen, facade_h - kerb_h,
                   [(a, c, d - kerb_h if d else 0.0, e - kerb_h, f) for a, c, d, e, f in left_open],
                   normal=(0, -1, 0))
    wr = 1.0 + rng.uniform(-0.3, 0.3)
    right_open = [(wr, wr + 1.5, 1.0, 2.4, 0.12), (wr + 2.3, wr + 3.8, 1.0, 2.4, 0.12)]
    rf, rp = _wall((xf0, -y_face, kerb_h), (1, 0, 0), flen, facade_h - kerb_h,
                   [(a, c, d - kerb_h, e - kerb_h, f) for a, c, d, e, f in right_open],
                   normal=(0, 1, 0))
    b.add("facade_left", "concrete", lf)
    b.add("facade_right", "concrete", rf)
    b.add("windows", "glass", lp[0], *lp[2:], *rp)
    b.add("door", "wood", lp[1])
    # parked cars: two along the right kerb, one on the left
    c1 = 2.9 + rng.uniform(0.0, 0.3)
    _car(b, "car1_body", "car1_cabin", "car1_tyres", c1, -3.3, length=4.2)
    c2 = c1 + 4.2 + 0.5 + rng.uniform(0.0, 0.2)
    _car(b, "car2_body", "car2_cabin", "car2_tyres", c2, -3.2, length=min(4.0, 11.2 - c2))
    c3 = 5.0 + rng.uniform(-0.5, 0.5)
    _car(b, "car3_body", "car3_cabin", "car3_tyres", c3, 1.5, length=4.3, yaw=np.radians(2.0))
    px = 6.5 + rng.uniform(-0.5, 0.5)
    b.add("pole", "metal", _cylinder(px, -(road_hw + kerb_w + 0.4), kerb_h, 3.5, 0.05),
          _box((px - 0.08, -(road_hw + kerb_w + 0.7), 2.5), (px - 0.06, -(road_hw + kerb_w + 0.1), 3.1)))
    desc = ("Street 7 m wide between 0.15 m kerbs and 1.85 m sidewalks, 4 m-high "
            "concrete facades on both sides (x = 3.4-10.3 m) with recessed glass windows "
            "and a recessed wooden door; two cars parked along the right kerb and one on "
            "the left (metal bodies, glass cabins, tyres), a metal sign pole on the right "
            "sidewalk.")
    lidar = np.array([[0.0, 0.0, 1.5], [0.0, 1.5, 1.8], [0.0, -1.5, 1.8]])
    return b, desc, lidar


def _parking_lot(rng):
    b = _Builder()
    b.add("ground", "concrete", _plane_in_fov((MIN_FORWARD_M, 12.0, -9.0, 9.0), 0.0, _Z))
    empty = int(rng.integers(0, 3))
    stalls = [-4.5, -2.0, 0.5]
    n_car = 0
    stops = []
    for k, yc in enumerate(stalls):
        stops.append(_box((10.3, yc - 0.8, 0.0), (10.45, yc + 0.8, 0.12), skip=("-z",)))
        if k == empty:
            continue
        n_car += 1
        x0 = 5.7 + rng.uniform(0.0, 0.2)
        y0 = yc - 0.9 + rng.uniform(-0.15, 0.15)
        _car(b, f"car{n_car}_body", f"car{n_car}_cabin", f"car{n_car}_tyres", x0, y0,
             length=4.3, yaw=np.radians(rng.uniform(-3, 3)))
    b.add("wheel_stops", "concrete", *stops)
    # a third car driving along the aisle on the left
    _car(b, "car3_body", "car3_cabin", "car3_tyres", 4.0 + rng.uniform(-0.3, 0.3),
         2.6 + rng.uniform(-0.1, 0.1), length=4.1, width=1.75, yaw=np.radians(rng.uniform(-6, 6)))
    lx, ly = 8.2 + rng.uniform(-0.3, 0.3), -6.2
    b.add("lamp_pole", "metal", _cylinder(lx, ly, 0.0, 5.0, 0.08),
          _box((lx - 0.05, ly, 4.85), (lx + 0.05, ly + 1.2, 4.95)),
          _box((lx - 0.15, ly + 1.0, 4.7), (lx + 0.15, ly + 1.5, 4.85)))
    b.add("lamp_base", "concrete", _box((lx - 0.3, ly - 0.3, 0.0), (lx + 0.3, ly + 0.3, 0.4),
                                        skip=("-z",)))
    desc = ("Open parking lot: concrete ground clipped to the radar's footprint, a row of "
            "three 2.5 m stalls at x = 5.7-10.5 m, y = -5.4..1.4 m (one empty, chosen by "
            "the seed) with concrete wheel stops, two cars parked nose-in, a third car "
            "driving along the aisle on the left, a 5 m metal lamp pole with arm and head "
            "on a concrete base.")
    lidar = np.array([[0.0, 0.0, 1.5], [0.0, 2.0, 1.8], [0.0, -2.0, 1.8]])
    return b, desc, lidar


def _building_corner(rng):
    b = _Builder()
    cx = 6.0 + rng.uniform(-0.3, 0.3)
    corner = np.array([cx, 0.0, 0.0])
    s2 = 1 / np.sqrt(2)
    d_a, d_b = np.array([s2, s2, 0.0]), np.array([s2, -s2, 0.0])
    n_a, n_b = np.array([-s2, s2, 0.0]), np.array([-s2, -s2, 0.0])
    height = 4.0
    # facades as long as the 12 m range allows for their top far corners
    r_h = np.sqrt((MAX_RANGE_M - 0.05) ** 2 - (height - RADAR_HEIGHT_M) ** 2)
    t = (-2 * cx + np.sqrt(4 * cx ** 2 - 8 * (cx ** 2 - r_h ** 2))) / 4  # (cx+t)^2 + t^2 = r_h^2
    length = float(np.floor(t * np.sqrt(2) * 100) / 100)
    # ground: the footprint minus the building wedge x - cx >= |y|, as two convex halves,
    # ending where the facades end
    left = _plane_in_fov((MIN_FORWARD_M, 12.0, 0.0, 9.0), 0.0, _Z, extra=[(1.0, -1.0, cx)], radius=r_h)
    right = _plane_in_fov((MIN_FORWARD_M, 12.0, -9.0, 0.0), 0.0, _Z, extra=[(1.0, 1.0, cx)], radius=r_h)
    b.add("ground", "concrete", left, right)
    # facade A (left, runs from the corner along d_a), built from its far end towards the corner
    dr = 1.2 + rng.uniform(-0.2, 0.3)  # door recess position from the corner
    wa = 3.3 + rng.uniform(-0.2, 0.2)
    open_a = [(length - dr - 1.2, length - dr, 0.0, 2.3, 0.5),      # door recess
              (length - wa - 1.2, length - wa, 1.0, 2.4, 0.12)]
    fa, pa = _wall(corner + length * d_a, -d_a, length, height, open_a, normal=n_a)
    ws = 0.8 + rng.uniform(-0.2, 0.2)
    open_b = [(ws, ws + 1.2, 1.0, 2.4, 0.12), (2.5, 4.5, 0.0, 2.6, 0.25)]  # window, shutter
    fb, pb = _wall(corner, d_b, length, height, open_b, normal=n_b)
    b.add("facade_a", "concrete", fa)
    b.add("facade_b", "concrete", fb)
    b.add("door", "wood", pa[0])
    b.add("windows", "glass", pa[1], pb[0])
    b.add("shutter", "metal", pb[1])
    # a downpipe on facade B near the corner and two bollards in front of the door
    pp = corner + 0.4 * d_b + 0.08 * n_b
    b.add("downpipe", "metal", _cylinder(pp[0], pp[1], 0.0, height - 0.05, 0.05, n_sides=10))
    door_mid = corner + (dr + 0.6) * d_a + 1.2 * n_a
    bollards = [_cylinder(*(door_mid + k * 0.9 * d_a)[:2], 0.0, 0.9, 0.1) for k in (-1, 1)]
    b.add("bollards", "metal", *bollards)
    desc = ("Exterior corner of a building pointing at the radar (corner at x = 6 m on "
            "boresight): two 5 m x 4 m concrete facades at +/-45 deg, facade A with a "
            "0.5 m-deep door recess (wooden door) and a recessed window, facade B with a "
            "window and a metal roller shutter in a recess, a metal downpipe, two metal "
            "bollards, and concrete ground around the building.")
    lidar = np.array([[0.0, 0.0, 1.5], [0.5, 2.5, 1.8], [0.5, -2.5, 1.8]])
    return b, desc, lidar


#: Registry: name -> (builder, indoor).  Builders take a ``numpy.random.Generator``.
SCENES = {
    "hallway": (_hallway, True),
    "lab": (_lab, True),
    "classroom": (_classroom, True),
    "street": (_street, False),
    "parking_lot": (_parking_lot, False),
    "building_corner": (_building_corner, False),
}


def build_scene(name: str, seed: int = 0) -> SceneSpec:
    """Build catalog scene ``name`` (see :data:`SCENES`) with layout seed ``seed``.

    Raises :class:`~sionna_mmir.errors.InputValueError` for an unknown name or
    a seed that is not a non-negative integer.
    """
    if name not in SCENES:
        raise InputValueError(f"unknown scene {name!r}; choose one of {sorted(SCENES)}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise InputValueError(f"build_scene: seed must be a non-negative int, got {seed!r}")
    builder, indoor = SCENES[name]
    rng = np.random.default_rng([int(seed), _name_key(name)])
    b, desc, lidar = builder(rng)
    objects = b.objects()
    valid = set(available_materials(FREQUENCY_HZ))
    for obj, mat in b.materials.items():
        if mat not in valid:  # a catalog bug, not user input
            raise AssertionError(f"{name}/{obj}: material {mat} not valid at 77 GHz")
    return SceneSpec(name=name, objects=objects, materials=dict(b.materials),
                     radar_position=np.array([0.0, 0.0, RADAR_HEIGHT_M]),
                     radar_orientation=np.zeros(3), description=desc,
                     lidar_positions=np.asarray(lidar, dtype=float), seed=int(seed),
                     indoor=indoor)


def _name_key(name: str) -> int:
    """Stable (process-independent) integer of a string."""
    import zlib

    return zlib.crc32(name.encode("utf-8"))


def scene_radar(spec, num_chirps: int = 1):
    """The cascade radar at the scene's pose."""
    from ..radar.config import RadarConfig

    return RadarConfig.mmwcas(num_chirps=num_chirps, position=tuple(spec.radar_position),
                              orientation=tuple(spec.radar_orientation))

"""The truth scene: a room with corner reflectors, diffuse clutter and its mesh.

Independence: plain NumPy + trimesh; material constants, Fresnel
coefficients, corner-reflector RCS and the clutter statistics are written
here, not taken from the package's radio-material or BSDF code.

Scene frame (the package's conventions): ``+z`` up, the floor at ``z = 0``;
the nominal radar stands at :data:`RADAR_POSITION` ``(0, 0, 1)`` m with
orientation ``(0, 0, 0)``, i.e. it looks along ``+x`` with ``+y`` to its left.

What the user gets and what the truth is
----------------------------------------
* The **mesh** (:attr:`Scene.meshes`): floor, ceiling, four walls, a cabinet
  (a box against the left wall) and every corner reflector as real
  triangles (a trihedral's three right-isosceles plates, a dihedral's two
  rectangles) at the true place and orientation.  Normals face the room.
* The **truth**: (1) diffuse clutter -- :math:`N` points drawn uniformly by
  area on the front-facing surfaces, moved off them along the normal by
  ``U(-2, 2)`` cm, each a Rayleigh scatterer of mean RCS ``sigma0(theta) A``
  with the Lambert law ``sigma0 = gamma cos^2 theta`` (``theta`` the
  incidence angle, ``gamma`` per material, :data:`LAMBERT_DB`, ``A`` the area
  per point); points hidden behind the cabinet or a corner are dropped;
  (2) the corner reflectors as point scatterers at their phase centres (a
  trihedral's apex, the middle of a dihedral's seam) with an aspect pattern
  (:meth:`Corner.rcs`); (3) the specular return of every front-facing plane
  surface, by the image of each Tx in the plane (exact per pair, kept only
  where the specular point lies on the surface; only the far wall has one
  inside the antennas' beams), with the Fresnel coefficient at normal
  incidence times the coherent-reflection factor ``exp(-(2 k h cos i)^2 / 2)``
  of an RMS surface height ``h`` (:data:`ROUGHNESS_M`).

Materials are ITU-R P.2040-3 Table 3 classes at 77 GHz
(``eps = a f^b - j c f^d / (2 pi f eps0)``, ``f`` in GHz); the horizontal
(TE, E along the surface) Fresnel coefficient is used throughout.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import trimesh

from .undeclared_adc import C0, MirrorPaths, PointPaths

#: Nominal radar position in the scene frame [m].
RADAR_POSITION = np.array([0.0, 0.0, 1.0])
EPS0 = 8.8541878128e-12
#: ITU-R P.2040-3 Table 3 ``(a, b, c, d)``: ``eps' = a f^b``, ``sigma = c f^d`` (f in GHz).
ITU_ABCD = {"concrete": (5.24, 0.0, 0.0462, 0.7822),
            "plasterboard": (2.73, 0.0, 0.0085, 0.9395),
            "wood": (1.99, 0.0, 0.0047, 1.0718),
            "ceiling_board": (1.48, 0.0, 0.0011, 1.0750)}
#: Lambert coefficient ``gamma`` [dB] of ``sigma0 = gamma cos^2(theta)`` at 77 GHz.
#: Order-of-magnitude values for building surfaces at mm-wave (-10 to -25 dB
#: m^2/m^2 at moderate incidence); smooth metal scatters little diffusely.
LAMBERT_DB = {"concrete": -12.0, "plasterboard": -15.0, "wood": -14.0,
              "ceiling_board": -16.0, "metal": -25.0}
#: RMS surface height [m] setting the coherent (specular) reflection loss.
ROUGHNESS_M = {"concrete": 5e-4, "plasterboard": 1.5e-4, "wood": 2e-4,
               "ceiling_board": 5e-4, "metal": 1e-5}
#: Half-power half-width of a trihedral's RCS pattern about its axis [deg].
TRIHEDRAL_HALF_WIDTH_DEG = 20.0


def permittivity(material: str, freq_hz: float) -> complex:
    """Complex relative permittivity ``eps' - j sigma / (2 pi f eps0)`` (ITU-R P.2040-3)."""
    a, b, c, d = ITU_ABCD[material]
    f_ghz = freq_hz / 1e9
    return a * f_ghz ** b - 1j * c * f_ghz ** d / (2 * np.pi * freq_hz * EPS0)


def fresnel_te(material: str, freq_hz: float, cos_i) -> np.ndarray:
    """TE (horizontal) Fresnel reflection coefficient; ``-1`` for metal."""
    cos_i = np.asarray(cos_i, float)
    if material == "metal":
        return -np.ones_like(cos_i, dtype=complex)
    root = np.sqrt(permittivity(material, freq_hz) - (1.0 - cos_i ** 2))
    return (cos_i - root) / (cos_i + root)


def coherent_factor(material: str, freq_hz: float, cos_i) -> np.ndarray:
    """Specular amplitude factor ``exp(-(2 k h cos i)^2 / 2)`` of a rough surface."""
    k = 2 * np.pi * freq_hz / C0
    return np.exp(-0.5 * (2 * k * ROUGHNESS_M[material] * np.asarray(cos_i)) ** 2)


@dataclasses.dataclass
class Rect:
    """Rectangle ``origin + a edge_u + b edge_v``, ``a, b in [0, 1]``, normal ``edge_u x edge_v``."""

    name: str
    origin: np.ndarray
    edge_u: np.ndarray
    edge_v: np.ndarray
    material: str

    @property
    def normal(self) -> np.ndarray:
        n = np.cross(self.edge_u, self.edge_v)
        return n / np.linalg.norm(n)

    @property
    def area(self) -> float:
        return float(np.linalg.norm(np.cross(self.edge_u, self.edge_v)))

    @property
    def centre(self) -> np.ndarray:
        return self.origin + 0.5 * (self.edge_u + self.edge_v)

    def triangles(self) -> np.ndarray:
        """Two triangles ``[2, 3, 3]`` wound along the normal."""
        o, u, v = self.origin, self.edge_u, self.edge_v
        return np.array([[o, o + u, o + u + v], [o, o + u + v, o + v]])


def _rect(name, origin, edge_u, edge_v, material) -> Rect:
    return Rect(name, np.asarray(origin, float), np.asarray(edge_u, float),
                np.asarray(edge_v, float), material)


def _mesh(triangles: np.ndarray) -> trimesh.Trimesh:
    tri = np.asarray(triangles, float).reshape(-1, 3, 3)
    verts = tri.reshape(-1, 3)
    faces = np.arange(verts.shape[0]).reshape(-1, 3)
    return trimesh.Trimesh(vertices=verts, faces=faces, process=False)


def _unit(v) -> np.ndarray:
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


def _rodrigues(v, axis, angle) -> np.ndarray:
    k = _unit(axis)
    return (v * math.cos(angle) + np.cross(k, v) * math.sin(angle)
            + k * (k @ v) * (1 - math.cos(angle)))


@dataclasses.dataclass
class Corner:
    """A corner reflector: ``kind`` ``"trihedral"`` or ``"dihedral"``.

    ``centre`` ``[3]`` phase centre [m] (trihedral apex, dihedral seam
    middle); ``axis`` ``[3]`` unit boresight (out of the opening);
    ``size`` the trihedral's edge or the dihedral's plate width [m];
    ``height`` the dihedral's seam length [m].  The seam of a dihedral is
    perpendicular to ``axis`` in the vertical plane through it.
    """

    kind: str
    centre: np.ndarray
    axis: np.ndarray
    size: float
    height: float = 0.0

    def _up(self) -> np.ndarray:
        up = np.array([0.0, 0.0, 1.0])
        return _unit(up - (up @ self.axis) * self.axis)

    def rcs_max(self, lam: float) -> float:
        """Peak RCS [m^2]: ``4 pi a^4 / (3 lambda^2)`` or ``8 pi w^2 h^2 / lambda^2``."""
        if self.kind == "trihedral":
            return 4 * np.pi * self.size ** 4 / (3 * lam ** 2)
        return 8 * np.pi * self.size ** 2 * self.height ** 2 / lam ** 2

    def rcs(self, direction, lam: float) -> float:
        """Monostatic RCS [m^2] seen from unit ``direction`` (corner -> radar).

        Trihedral: ``sigma_max 2^-(psi / 20 deg)^2`` for ``psi < 55 deg`` (``psi``
        off the axis), else 0.  Dihedral: ``sigma_max 2 sin^2(45 deg - |psi|)``
        in the plane across the seam times the plate pattern
        ``sinc^2(k h sin eps)`` along it (``eps`` the angle to that plane).
        """
        d = _unit(direction)
        if self.kind == "trihedral":
            psi = math.degrees(math.acos(np.clip(d @ self.axis, -1, 1)))
            if psi >= 55.0:
                return 0.0
            return self.rcs_max(lam) * 2.0 ** (-(psi / TRIHEDRAL_HALF_WIDTH_DEG) ** 2)
        seam = self._up()
        sin_eps = float(d @ seam)
        flat = _unit(d - sin_eps * seam)
        psi = math.acos(np.clip(flat @ self.axis, -1, 1))
        if psi >= np.pi / 4:
            return 0.0
        x = 2 * np.pi / lam * self.height * sin_eps
        plate = 1.0 if abs(x) < 1e-12 else (math.sin(x) / x) ** 2
        return self.rcs_max(lam) * 2.0 * math.sin(np.pi / 4 - psi) ** 2 * plate

    def bistatic_factor(self, beta: float, lam: float) -> float:
        """Loss of the retro-reflection at bistatic angle ``beta`` [rad].

        ``1 / (1 + (pi a sin(beta) / lambda)^2)``: the envelope of the
        aperture's ``sinc^2`` pattern (main lobe ~``lambda / a`` wide, sidelobes
        falling as ``1 / x^2``), without its nulls.
        """
        x = np.pi * self.size * math.sin(beta) / lam
        return 1.0 / (1.0 + x * x)

    def triangles(self) -> np.ndarray:
        """The plates as triangles ``[n, 3, 3]``, normals into the opening."""
        c, a = self.centre, self.size
        if self.kind == "trihedral":
            alpha = math.acos(1.0 / math.sqrt(3.0))
            ez = math.cos(alpha) * self.axis + math.sin(alpha) * self._up()
            ex = _rodrigues(ez, self.axis, 2 * np.pi / 3)
            ey = _rodrigues(ez, self.axis, -2 * np.pi / 3)
            tri = [[c, c + a * ex, c + a * ey], [c, c + a * ey, c + a * ez],
                   [c, c + a * ez, c + a * ex]]
        else:
            seam = self._up()
            side = np.cross(seam, self.axis)
            tri = []
            for sgn in (1.0, -1.0):
                p = (self.axis + sgn * side) / math.sqrt(2.0)
                o = c - 0.5 * self.height * seam
                tri += list(_rect("", o, a * p, self.height * seam, "metal").triangles())
        return _facing(np.array(tri), self.axis)

    def to_dict(self, lam: float) -> dict:
        """JSON-ready description (RCS in dBsm at wavelength ``lam``)."""
        return {"kind": self.kind, "centre_m": self.centre.tolist(), "axis": self.axis.tolist(),
                "size_m": self.size, "seam_m": self.height,
                "rcs_max_dbsm": 10 * math.log10(self.rcs_max(lam))}


def _facing(tri: np.ndarray, towards: np.ndarray) -> np.ndarray:
    """Triangles with their winding flipped where the normal points away from ``towards``."""
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    flip = n @ towards < 0
    tri = tri.copy()
    tri[flip, 1], tri[flip, 2] = tri[flip, 2].copy(), tri[flip, 1].copy()
    return tri


def segment_blocked(origin, points, triangles, eps: float = 1e-3) -> np.ndarray:
    """True where the segment ``origin -> points[p]`` crosses one of ``triangles``.

    Moller-Trumbore test, ``points`` ``[P, 3]``, ``triangles`` ``[F, 3, 3]``;
    hits within ``eps`` of either end are ignored.  Returns ``[P]`` bool.
    """
    points = np.asarray(points, float)
    if len(triangles) == 0:
        return np.zeros(points.shape[0], bool)
    d = points - origin                                        # [P, 3], t in [0, 1]
    v0 = triangles[:, 0]
    e1, e2 = triangles[:, 1] - v0, triangles[:, 2] - v0
    h = np.cross(d[:, None, :], e2[None])                      # [P, F, 3]
    det = np.einsum("fk,pfk->pf", e1, h)
    ok = np.abs(det) > 1e-12
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    s = origin - v0                                            # [F, 3]
    u = np.einsum("fk,pfk->pf", s, h) * inv
    q = np.cross(s, e1)                                        # [F, 3]
    v = np.einsum("pk,fk->pf", d, q) * inv
    t = np.einsum("fk,fk->f", e2, q)[None, :] * inv
    length = np.linalg.norm(d, axis=1, keepdims=True)
    hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > eps / length) & (t < 1 - eps / length)
    return hit.any(axis=1)


def _oriented(name, origin, edge_u, edge_v, material, towards) -> Rect:
    """A rectangle whose normal points at ``towards``."""
    r = _rect(name, origin, edge_u, edge_v, material)
    if r.normal @ (np.asarray(towards, float) - r.centre) < 0:
        r = _rect(name, origin, edge_v, edge_u, material)
    return r


def room_rects(bounds: dict) -> list:
    """Floor, ceiling and walls of the axis-aligned room ``bounds``, normals inwards."""
    x0, x1, y0, y1, h = (bounds[k] for k in ("x_back", "x_far", "y_right", "y_left", "height"))
    mid = np.array([(x0 + x1) / 2, (y0 + y1) / 2, h / 2])
    lx, ly = x1 - x0, y1 - y0
    spec = [("floor", (x0, y0, 0), (lx, 0, 0), (0, ly, 0), "concrete"),
            ("ceiling", (x0, y0, h), (lx, 0, 0), (0, ly, 0), "ceiling_board"),
            ("wall_left", (x0, y1, 0), (lx, 0, 0), (0, 0, h), "plasterboard"),
            ("wall_right", (x0, y0, 0), (lx, 0, 0), (0, 0, h), "plasterboard"),
            ("wall_far", (x1, y0, 0), (0, ly, 0), (0, 0, h), "concrete"),
            ("wall_back", (x0, y0, 0), (0, ly, 0), (0, 0, h), "concrete")]
    return [_oriented(n, o, u, v, m, mid) for n, o, u, v, m in spec]


def box_rects(name: str, lo, hi, material: str, skip=("bottom",)) -> list:
    """Faces of the box ``lo``-``hi`` (corners [m]) with outward normals, minus ``skip``."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    size, out = hi - lo, []
    centre = (lo + hi) / 2
    ex, ey, ez = np.diag(size)
    faces = {"bottom": (lo, ex, ey), "top": (lo + ez, ex, ey), "front": (lo, ey, ez),
             "back": (lo + ex, ey, ez), "right": (lo, ex, ez), "left": (lo + ey, ex, ez)}
    for key, (o, u, v) in faces.items():
        if key in skip:
            continue
        r = _rect(f"{name}_{key}", o, u, v, material)
        if r.normal @ (r.centre - centre) < 0:
            r = _rect(f"{name}_{key}", o, v, u, material)
        out.append(r)
    return out


@dataclasses.dataclass
class Scene:
    """A drawn room: surfaces, cabinet, corners and the clutter truth.

    ``rects`` mesh surfaces (room + cabinet), each with an ``object`` name in
    ``objects``; ``corners`` the reflectors; ``clutter`` the diffuse points
    (:class:`PointPaths`, not strong) with ``clutter_info`` (material index,
    mean RCS [m^2]) for the truth; ``bounds`` the room [m].
    """

    rects: list
    objects: list
    corners: list
    clutter: PointPaths
    clutter_info: dict
    bounds: dict

    def meshes(self) -> dict:
        """``name -> trimesh.Trimesh`` of every object (scene frame, metres)."""
        out = {}
        for obj in dict.fromkeys(self.objects):
            tri = np.concatenate([r.triangles() for r, o in zip(self.rects, self.objects)
                                  if o == obj])
            out[obj] = _mesh(tri)
        for k, c in enumerate(self.corners):
            out[f"corner_{k}"] = _mesh(c.triangles())
        return out

    def materials(self) -> dict:
        """``name -> ITU material class`` of every mesh."""
        out = {o: r.material for r, o in zip(self.rects, self.objects)}
        out.update({f"corner_{k}": "metal" for k in range(len(self.corners))})
        return out

    def corner_paths(self, lam: float, radar_pos) -> PointPaths:
        """The corners as point scatterers (RCS toward ``radar_pos``), strong paths."""
        pos = np.array([c.centre for c in self.corners])
        sig = np.array([c.rcs(np.asarray(radar_pos) - c.centre, lam) for c in self.corners])
        phase = np.array([np.pi if c.kind == "trihedral" else 0.0 for c in self.corners])
        coef = lam * np.sqrt(sig) * np.exp(1j * phase) / (4 * np.pi) ** 1.5
        return PointPaths(pos, pos, coef)

    def mirror_paths(self, freq_hz: float) -> list:
        """Specular (image-Tx) returns of every plane surface at normal incidence."""
        out = []
        for r in self.rects:
            g = fresnel_te(r.material, freq_hz, 1.0) * coherent_factor(r.material, freq_hz, 1.0)
            out.append(MirrorPaths(r.origin, r.edge_u, r.edge_v, complex(g)))
        return out

    def occluders(self, exclude: str | None = None) -> np.ndarray:
        """Triangles ``[F, 3, 3]`` of the cabinet and the corners (except object ``exclude``)."""
        tri = [r.triangles() for r, o in zip(self.rects, self.objects)
               if o == "cabinet" and exclude != "cabinet"]
        tri += [c.triangles() for k, c in enumerate(self.corners) if exclude != f"corner_{k}"]
        return np.concatenate(tri) if tri else np.zeros((0, 3, 3))


def draw_room(rng, scale: float = 1.0) -> tuple:
    """Room bounds and the cabinet: ``(bounds, rects, objects)``.

    Room ``x in [-1, 9..10]``, ``y in [-(3.5..4.5), 3.5..4.5]``, height
    2.8-3.2 m; a 1.0 x 0.5 m cabinet, 1.6-2.0 m high, wood or metal, against
    the left wall at ``x = 3..6`` m.  ``scale`` stretches the floor plan
    (the far wall, the side walls and the cabinet's place; not the height
    or the cabinet itself): a hall at ``scale = 2.5`` reaches 25 m.
    """
    b = {"x_back": -1.0, "x_far": scale * float(rng.uniform(9.0, 10.0)),
         "y_right": -scale * float(rng.uniform(3.5, 4.5)),
         "y_left": scale * float(rng.uniform(3.5, 4.5)),
         "height": float(rng.uniform(2.8, 3.2))}
    x_c = scale * float(rng.uniform(3.0, 6.0))
    lo = (x_c, b["y_left"] - 0.5, 0.0)
    hi = (x_c + 1.0, b["y_left"], float(rng.uniform(1.6, 2.0)))
    material = "metal" if rng.uniform() < 0.5 else "wood"
    b["cabinet_lo"], b["cabinet_hi"], b["cabinet_material"] = list(lo), list(hi), material
    rects = room_rects(b)
    objects = [r.name for r in rects]
    cab = box_rects("cabinet", lo, hi, material, skip=("bottom", "left"))
    return b, rects + cab, objects + ["cabinet"] * len(cab)


def _inside_room(p, b, margin) -> bool:
    lo, hi = np.array(b["cabinet_lo"]), np.array(b["cabinet_hi"])
    in_cab = np.all(p[:2] > lo[:2] - margin) and np.all(p[:2] < hi[:2] + margin)
    return (b["x_back"] + margin < p[0] < b["x_far"] - margin
            and b["y_right"] + margin < p[1] < b["y_left"] - margin and not in_cab)


def _corner_position(rng, radar_pos, scale=1.0):
    r = scale * rng.uniform(2.0, 8.0)
    az = np.radians(rng.uniform(-45.0, 45.0))
    dz = rng.uniform(-0.15, 0.25)
    rh = math.sqrt(r * r - dz * dz)
    return radar_pos + np.array([rh * math.cos(az), rh * math.sin(az), dz]), r, az


def _aim(centre, radar_pos, rng, az_err_deg, el_err_deg) -> np.ndarray:
    axis = _unit(radar_pos - centre)
    axis = _rodrigues(axis, [0, 0, 1], np.radians(rng.normal(0, az_err_deg)))
    side = np.cross([0.0, 0.0, 1.0], axis)
    return _unit(_rodrigues(axis, side, np.radians(rng.normal(0, el_err_deg))))


def draw_corners(rng, bounds, occluders, n: int, radar_pos=RADAR_POSITION,
                 scale: float = 1.0) -> list:
    """``n`` corners at 2-8 m, azimuth +-45 deg, pairwise >= 0.6 m apart in range and
    >= 18 deg in azimuth, in the room, clear of the cabinet and in its line of sight.
    ``scale`` (:func:`draw_room`) multiplies the ranges and the reflectors'
    edges by ``sqrt(scale)``, which keeps their radar cross-section's ratio to
    the clutter on the walls (``A ~ scale^2``) at the room's.

    The first is a trihedral; the others trihedral (70 %) or dihedral.  Edge
    0.06-0.12 m (trihedral, 6-18 dBsm) or plates 0.05-0.08 m (dihedral);
    aimed at the radar within N(0, 4 deg) in azimuth and N(0, 2 deg)
    (dihedral 0.2 deg) in elevation.
    """
    corners, ranges, azs = [], [], []
    for _ in range(5000):
        if len(corners) == n:
            break
        p, r, az = _corner_position(rng, radar_pos, scale)
        ok = _inside_room(p, bounds, 0.5) and not segment_blocked(radar_pos, p[None], occluders)[0]
        ok = ok and all(abs(r - r2) >= 0.6 and abs(az - a2) >= np.radians(18)
                        for r2, a2 in zip(ranges, azs))
        if not ok:
            continue
        tri = not corners or rng.uniform() < 0.7
        axis = _aim(p, radar_pos, rng, 4.0, 2.0 if tri else 0.2)
        size = np.sqrt(scale) * (rng.uniform(0.06, 0.12) if tri else rng.uniform(0.05, 0.08))
        corners.append(Corner("trihedral" if tri else "dihedral", p, axis, float(size),
                              0.0 if tri else float(size)))
        ranges.append(r)
        azs.append(az)
    if len(corners) < n:
        raise RuntimeError("could not place the corner reflectors")
    return corners


def _clip_front(r: Rect, x_min: float) -> Rect | None:
    """The part of an axis-aligned rectangle with ``x >= x_min`` (None if empty)."""
    key = "edge_u" if abs(r.edge_u[0]) > 0 else "edge_v"
    edge = getattr(r, key)
    x0, x1 = r.origin[0], r.origin[0] + edge[0]
    if max(x0, x1) <= x_min:
        return None
    if min(x0, x1) >= x_min:
        return r
    if edge[0] > 0:
        t0 = (x_min - x0) / edge[0]
        return dataclasses.replace(r, origin=r.origin + t0 * edge, **{key: (1 - t0) * edge})
    t1 = (x0 - x_min) / -edge[0]
    return dataclasses.replace(r, **{key: t1 * edge})


MATERIAL_NAMES = ("concrete", "plasterboard", "wood", "ceiling_board", "metal")


def draw_clutter(rng, rects, objects, corners_tri, lam, n: int,
                 radar_pos=RADAR_POSITION) -> tuple:
    """``n`` diffuse clutter points on the front-facing surfaces (``x >= 0.3`` m).

    Returns ``(PointPaths, info)`` with ``info`` = ``{"material": [P] int
    (index into MATERIAL_NAMES), "sigma_mean_m2": [P], "area_per_point_m2"}``.
    Points are uniform by area, offset along the normal by ``U(-2, 2)`` cm;
    each is complex Gaussian with ``E|sigma| = gamma cos^2(theta) A / n``.
    Occluded points (behind the cabinet or a corner plate) and points on
    surfaces facing away are dropped after the draw, so fewer than ``n``
    may remain.
    """
    cand = []
    for r, o in zip(rects, objects):
        c = _clip_front(r, 0.3)
        if o != "wall_back" and c is not None and c.normal @ (radar_pos - c.centre) > 0:
            cand.append((c, o))
    areas = np.array([c.area for c, _ in cand])
    pick = rng.choice(len(cand), size=n, p=areas / areas.sum())
    ab = rng.uniform(size=(n, 2))
    off = rng.uniform(-0.02, 0.02, size=n)
    pts = np.empty((n, 3))
    normals = np.empty((n, 3))
    for k, (c, _) in enumerate(cand):
        m = pick == k
        pts[m] = c.origin + ab[m, :1] * c.edge_u + ab[m, 1:] * c.edge_v
        normals[m] = c.normal
    pts += off[:, None] * normals
    to_radar = radar_pos - pts
    cos_i = np.einsum("pk,pk->p", normals, to_radar) / np.linalg.norm(to_radar, axis=1)
    obj = np.array([cand[k][1] for k in pick])
    blocked = np.zeros(n, bool)
    for name, tri in (("cabinet", corners_tri[0]), ("other", corners_tri[1])):
        m = obj == "cabinet" if name == "cabinet" else obj != "cabinet"
        blocked[m] = segment_blocked(radar_pos, pts[m], tri)
    mat = np.array([MATERIAL_NAMES.index(cand[k][0].material) for k in pick])
    gamma = 10 ** (np.array([LAMBERT_DB[MATERIAL_NAMES[i]] for i in mat]) / 10)
    area = areas.sum() / n
    sigma = gamma * np.clip(cos_i, 0, None) ** 2 * area
    keep = ~blocked & (cos_i > 0)
    g = (rng.normal(size=n) + 1j * rng.normal(size=n)) / math.sqrt(2.0)
    coef = lam * np.sqrt(sigma) * g / (4 * np.pi) ** 1.5
    paths = PointPaths(pts[keep], pts[keep], coef[keep], strong=False)
    return paths, {"material": mat[keep], "sigma_mean_m2": sigma[keep],
                   "area_per_point_m2": float(area)}


def build_scene(rng, lam: float, n_corners: int, n_clutter: int, scale: float = 1.0) -> Scene:
    """Draw a room (its floor plan stretched by ``scale``, :func:`draw_room`),
    its corners and clutter with generator ``rng``; ``lam`` [m]."""
    bounds, rects, objects = draw_room(rng, scale)
    cab_tri = np.concatenate([r.triangles() for r, o in zip(rects, objects) if o == "cabinet"])
    corners = draw_corners(rng, bounds, cab_tri, n_corners, scale=scale)
    corner_tri = np.concatenate([c.triangles() for c in corners])
    clutter, info = draw_clutter(rng, rects, objects,
                                 (corner_tri, np.concatenate([cab_tri, corner_tri])), lam,
                                 n_clutter)
    return Scene(rects, objects, corners, clutter, info, bounds)

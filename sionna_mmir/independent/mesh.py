"""Scene assembly, input checks and visibility (segment occlusion by ray casts).

Visibility uses trimesh's Embree ray API (``trimesh.ray.ray_pyembree``, needs
the optional ``embreex`` package) when it is installed, and otherwise a
chunked NumPy Moller-Trumbore test of every segment against every triangle
(exact, but slow on scenes of thousands of triangles).  Surfaces are
two-sided and opaque: a segment is blocked by any triangle it crosses.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

from ..errors import ConfigError, InputValueError
from .materials import material_function

#: Triangles smaller than this are dropped [m^2].
MIN_AREA = 1e-12
#: Segment ends closer than this to a surface are not tested there [m].
RAY_EPS = 1e-5


@dataclass
class SceneMesh:
    """All objects of a scene in one triangle soup (world frame, metres).

    Attributes
    ----------
    vertices : numpy.ndarray
        ``[V, 3]`` float64 [m].
    faces : numpy.ndarray
        ``[F, 3]`` int64 vertex indices.
    face_object : numpy.ndarray
        ``[F]`` int64 index into ``names``.
    names : list of str
        Object names.
    materials : list of callable
        Per object, ``points [N, 3] -> parameters [N, 6]``.
    """

    vertices: np.ndarray
    faces: np.ndarray
    face_object: np.ndarray
    names: list
    materials: list

    @property
    def triangles(self) -> np.ndarray:
        """``[F, 3, 3]`` corner positions [m]."""
        return self.vertices[self.faces]

    @property
    def normals(self) -> np.ndarray:
        """``[F, 3]`` unit normals (right-hand winding)."""
        t = self.triangles
        n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
        return n / np.linalg.norm(n, axis=1, keepdims=True)

    def parameters(self, face: np.ndarray, points: np.ndarray) -> np.ndarray:
        """Material parameters ``[N, 6]`` at ``points [N, 3]`` lying on faces ``face [N]``."""
        out = np.empty((len(face), 6))
        obj = self.face_object[face]
        for k in np.unique(obj):
            sel = obj == k
            out[sel] = self.materials[k](points[sel])
        return out


def _as_arrays(name, mesh):
    if isinstance(mesh, trimesh.Trimesh):
        v, f = np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces)
    else:
        try:
            v, f = mesh
        except (TypeError, ValueError):
            raise InputValueError(f"mesh {name!r} must be a trimesh.Trimesh or (V, F) arrays") from None
        v, f = np.asarray(v, dtype=np.float64), np.asarray(f)
    if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3:
        raise InputValueError(f"mesh {name!r}: vertices must be [V, 3] and faces [F, 3], "
                              f"got {v.shape} and {f.shape}")
    if len(f) == 0 or len(v) == 0:
        raise InputValueError(f"mesh {name!r} is empty (no faces)")
    if not np.isfinite(v).all():
        raise InputValueError(f"mesh {name!r}: vertices hold NaN or Inf")
    if f.min() < 0 or f.max() >= len(v) or not np.issubdtype(f.dtype, np.integer):
        raise InputValueError(f"mesh {name!r}: face indices out of range 0..{len(v) - 1}")
    return v, f.astype(np.int64)


def assemble(meshes: dict, materials: dict, frequency_hz: float,
             allow_out_of_band: bool = False) -> SceneMesh:
    """Validate meshes and materials and join them into a :class:`SceneMesh`.

    Parameters
    ----------
    meshes : dict
        Name -> ``trimesh.Trimesh`` or ``(vertices [V, 3], faces [F, 3])`` [m].
    materials : dict
        Name -> material spec (see
        :func:`~sionna_mmir.independent.materials.material_function`).
    frequency_hz : float
        Frequency of the ITU-R P.2040 evaluation [Hz].
    allow_out_of_band : bool
        Extrapolate ITU fits outside their bands.

    Returns
    -------
    SceneMesh

    Raises
    ------
    InputValueError
        No meshes, an empty mesh, NaN / Inf vertices, bad faces, or a mesh
        whose triangles are all degenerate.
    ConfigError
        A missing, unknown or invalid material.
    """
    if not isinstance(meshes, dict) or not meshes:
        raise InputValueError("render_reference: meshes must be a non-empty dict name -> mesh")
    extra = sorted(set(materials) - set(meshes))
    if extra:
        raise ConfigError(f"materials given for unknown objects {extra}")
    verts, faces, owner, names, mats = [], [], [], [], []
    offset = 0
    for k, (name, mesh) in enumerate(meshes.items()):
        if name not in materials:
            raise ConfigError(f"no material for object {name!r}")
        v, f = _as_arrays(name, mesh)
        t = v[f]
        area = 0.5 * np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1)
        f = f[area > MIN_AREA]
        if len(f) == 0:
            raise InputValueError(f"mesh {name!r}: all triangles are degenerate (zero area)")
        verts.append(v)
        faces.append(f + offset)
        owner.append(np.full(len(f), k))
        names.append(name)
        mats.append(material_function(materials[name], name, frequency_hz, allow_out_of_band))
        offset += len(v)
    return SceneMesh(np.concatenate(verts), np.concatenate(faces), np.concatenate(owner),
                     names, mats)


class Occlusion:
    """Segment occlusion against a :class:`SceneMesh` (see the module docstring).

    Parameters
    ----------
    scene : SceneMesh
        The occluding geometry.
    use_embree : bool or None
        Force (True) or forbid (False) Embree; ``None`` picks it when available.
    """

    def __init__(self, scene: SceneMesh, use_embree: bool | None = None):
        self.tri = scene.triangles
        has = bool(getattr(trimesh.ray, "has_embree", False))
        if use_embree and not has:
            raise ConfigError("use_embree=True but embreex is not installed "
                              "(pip install embreex, or the 'reference' extra)")
        self.embree = has if use_embree is None else bool(use_embree)
        if self.embree:
            from trimesh.ray.ray_pyembree import RayMeshIntersector

            m = trimesh.Trimesh(scene.vertices, scene.faces, process=False)
            self._rays = RayMeshIntersector(m)
            self._normals = scene.normals

    def blocked(self, start: np.ndarray, end: np.ndarray) -> np.ndarray:
        """True where the open segment ``start -> end`` crosses a triangle.

        Parameters
        ----------
        start, end : numpy.ndarray
            ``[N, 3]`` segment ends [m].

        Returns
        -------
        numpy.ndarray
            ``[N]`` bool.
        """
        d = end - start
        length = np.linalg.norm(d, axis=1)
        u = d / np.maximum(length, 1e-300)[:, None]
        o = start + RAY_EPS * u
        reach = length - 2 * RAY_EPS
        out = np.zeros(len(start), dtype=bool)
        step = 500_000 if self.embree else max(1, 4_000_000 // max(1, len(self.tri)))
        for s in range(0, len(start), step):
            sl = slice(s, s + step)
            hit_t = self._first_hit(o[sl], u[sl])
            out[sl] = hit_t < reach[sl]
        return out

    def _first_hit(self, o, u):
        """Distance to the first triangle along each ray (``inf`` if none)."""
        t = np.full(len(o), np.inf)
        if self.embree:
            face = self._rays.intersects_first(o, u)
            ray = np.flatnonzero(face >= 0)
            if len(ray):
                p0, n = self.tri[face[ray], 0], self._normals[face[ray]]
                t[ray] = np.einsum("ij,ij->i", p0 - o[ray], n) / np.einsum("ij,ij->i", u[ray], n)
            return t
        return _moller_trumbore(o, u, self.tri)


def _moller_trumbore(o, u, tri):
    """Nearest positive hit distance of rays ``o + t u`` on triangles ``tri [F, 3, 3]``."""
    e1, e2, p0 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0], tri[:, 0]
    p = np.cross(u[:, None, :], e2[None])                      # [N, F, 3]
    det = np.einsum("nfk,fk->nf", p, e1)
    ok = np.abs(det) > 1e-14
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    s = o[:, None, :] - p0[None]
    a = np.einsum("nfk,nfk->nf", s, p) * inv
    q = np.cross(s, e1[None])
    b = np.einsum("nk,nfk->nf", u, q) * inv
    t = np.einsum("fk,nfk->nf", e2, q) * inv
    hit = ok & (a >= 0) & (b >= 0) & (a + b <= 1) & (t > 0)
    return np.where(hit, t, np.inf).min(axis=1)

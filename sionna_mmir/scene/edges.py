"""Diffracting edges of a triangle mesh and a spatial index over them (NumPy + SciPy).

The free-space diffraction (FSD) lobe (:mod:`sionna_mmir.bsdf.fsd`) needs, at
every ray hit, the mesh edges near the hit point that can bound the geometry
projected onto the virtual screen.  This module finds those edges once per
mesh and answers "which edges lie within ``r`` of these points" queries.

Edge classes
------------
Every undirected mesh edge ``{a, b}`` is shared by ``m`` non-degenerate
faces:

==========  ================================================================
``m == 1``  **boundary edge** (``kind == 0``): the surface ends here; always
            kept
``m == 2``  interior edge; kept as a **crease** (``kind == 1``) when the angle
            between the two unit face normals exceeds ``crease_angle_deg``.
            The normals are compared *orientation-independently*: when both
            faces traverse the edge in the same direction (inconsistent
            winding, common in LiDAR meshes) one normal is flipped first
``m > 2``   non-manifold edge: kept as a crease (``kind == 1``); its
            ``faces`` / ``apex`` columns name the first two faces
==========  ================================================================

Edge suppression (mmIR paper, "Free-space diffraction BSDF", item iii).
A LiDAR surface reconstruction of a flat wall is a tessellation whose
vertex noise tilts neighbouring triangles by a few degrees.  Every such
interior edge would be a (spurious) diffracting crease for a zero threshold.
The filter keeps only creases with a dihedral normal angle above
``crease_angle_deg`` (default 60 deg, far above tessellation noise, below
the 90 deg of real building corners) and drops edges shorter than
``min_length`` (default 0: keep all).  No merging of collinear edges is done.

Split vertices.  Adjacency is by vertex id.  A mesh whose faces do not share
vertices where the surface goes on (flat-shaded or per-face-normal meshes,
such as the LiDAR scaffold: 38k ground triangles on 115k vertices) would make
every triangle side a boundary edge and diffract at every seam of a flat
wall.  ``weld_tol > 0`` makes vertices closer than ``weld_tol`` one vertex for
the adjacency (the edges keep the id of the first of them, at the same
position); the renderer's diffraction passes :data:`WELD_TOL`, the tolerance
the lit-footprint clipping welds with.
Degenerate faces (area < :data:`sionna_mmir.scene.mesh_io.DEGENERATE_AREA_M2`)
are ignored when counting adjacency.

``apex0`` / ``apex1`` are the vertices opposite the edge in its two adjacent
faces (``apex1 == apex0`` for boundary edges): on the FSD screen they tell on
which side of a projected edge the opaque geometry lies, and whether the
edge is a silhouette there (both apexes on the same side).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputValueError
from .mesh_io import DEGENERATE_AREA_M2

__all__ = ["EdgeSet", "EdgeIndex", "find_diffracting_edges", "point_segment_distance",
           "weld_vertices", "BOUNDARY", "CREASE", "WELD_TOL"]

#: vertices closer than this [m] are one vertex for the renderer's edges
#: (the tolerance of :mod:`sionna_mmir.paths.transport.clip_lines`)
WELD_TOL = 1e-6
#: query points per chunk of :meth:`EdgeIndex.query` (bounds its memory)
QUERY_CHUNK = 32_768

#: ``EdgeSet.kind`` codes
BOUNDARY = 0
CREASE = 1


@dataclass
class EdgeSet:
    """Diffracting edges of a mesh (``E`` edges; all positions in metres).

    Parameters
    ----------
    p0, p1 : numpy.ndarray
        ``float64 [E, 3]`` endpoints (``v0 < v1``)
    v0, v1 : numpy.ndarray
        ``int64 [E]`` endpoint vertex ids
    kind : numpy.ndarray
        ``int8 [E]``: 0 boundary (one face), 1 crease / non-manifold
    faces : numpy.ndarray
        ``int64 [E, 2]`` adjacent face ids (``-1`` for none)
    a0, a1 : numpy.ndarray
        ``int64 [E]`` apex (opposite) vertex ids in faces 0 / 1
        (``a1 == a0`` for boundary edges)
    apex0, apex1 : numpy.ndarray
        ``float64 [E, 3]`` positions of ``a0`` / ``a1``
    dihedral : numpy.ndarray
        ``float64 [E]`` angle between adjacent face normals [deg]
        (0 for boundary edges, 180 for non-manifold ones)
    """

    p0: np.ndarray
    p1: np.ndarray
    v0: np.ndarray
    v1: np.ndarray
    kind: np.ndarray
    faces: np.ndarray
    a0: np.ndarray
    a1: np.ndarray
    apex0: np.ndarray
    apex1: np.ndarray
    dihedral: np.ndarray

    def __len__(self) -> int:
        return int(self.p0.shape[0])

    @property
    def length(self) -> np.ndarray:
        """Edge lengths ``[E]`` [m]."""
        return np.linalg.norm(self.p1 - self.p0, axis=1)

    @property
    def midpoint(self) -> np.ndarray:
        """Edge midpoints ``[E, 3]`` [m]."""
        return 0.5 * (self.p0 + self.p1)


def _validate(vertices, faces):
    v = np.asarray(vertices, dtype=np.float64)
    if v.ndim != 2 or v.shape[1] != 3:
        raise InputValueError(f"vertices: expected shape (Nv, 3), got {v.shape}")
    if not np.all(np.isfinite(v)):
        raise InputValueError("vertices: contain NaN or Inf")
    f = np.asarray(faces)
    if f.ndim != 2 or f.shape[1] != 3:
        raise InputValueError(f"faces: expected shape (Nf, 3), got {f.shape}")
    if f.size and not np.issubdtype(f.dtype, np.integer):
        if not np.all(np.isfinite(f)) or np.any(f != np.round(f)):
            raise InputValueError("faces: indices must be integers")
    f = f.astype(np.int64)
    if f.size and (f.min() < 0 or f.max() >= len(v)):
        raise InputValueError(f"faces: indices out of range [0, {len(v)})")
    return v, f


def weld_vertices(vertices, tol: float) -> np.ndarray:
    """``[Nv]`` representative vertex id of every vertex: the first vertex of the
    cell of side ``tol`` [m] it falls in (vertices closer than ``tol`` share
    one unless a cell boundary separates them)."""
    v = np.asarray(vertices, dtype=np.float64)
    if len(v) == 0:
        return np.zeros(0, dtype=np.int64)
    _, first, inv = np.unique(np.round(v / tol).astype(np.int64), axis=0,
                              return_index=True, return_inverse=True)
    return first[inv.reshape(-1)].astype(np.int64)


def find_diffracting_edges(vertices, faces, crease_angle_deg: float = 60.0,
                           min_length: float = 0.0, weld_tol: float = 0.0) -> EdgeSet:
    """Boundary and crease edges of a triangle mesh (see the module docstring).

    Parameters
    ----------
    vertices : array_like
        ``[Nv, 3]`` positions [m]
    faces : array_like
        ``[Nf, 3]`` vertex indices
    crease_angle_deg : float, optional
        keep interior edges whose face normals differ by more
        than this [deg] (edge suppression of LiDAR noise)
    min_length : float, optional
        drop edges shorter than this [m]
    weld_tol : float, optional
        vertices closer than this [m] are one vertex for the adjacency
        (0: by vertex id only; see "Split vertices" in the module docstring)

    Returns
    -------
    EdgeSet

    Raises
    ------
    InputValueError
        Bad shapes, NaN/Inf vertices, out-of-range indices or a negative
        threshold.
    """
    v, f = _validate(vertices, faces)
    if not np.isfinite(crease_angle_deg) or not 0.0 <= crease_angle_deg <= 180.0:
        raise InputValueError(f"crease_angle_deg must be in [0, 180], got {crease_angle_deg!r}")
    if not np.isfinite(min_length) or min_length < 0:
        raise InputValueError(f"min_length must be >= 0, got {min_length!r}")
    if not np.isfinite(weld_tol) or weld_tol < 0:
        raise InputValueError(f"weld_tol must be >= 0, got {weld_tol!r}")
    if weld_tol > 0 and f.size:
        f = weld_vertices(v, weld_tol)[f]

    cr = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]) if len(f) else np.zeros((0, 3))
    area2 = np.linalg.norm(cr, axis=1)
    keep = 0.5 * area2 >= DEGENERATE_AREA_M2
    fid = np.nonzero(keep)[0]
    normals = np.zeros_like(cr)
    normals[keep] = cr[keep] / area2[keep, None]

    # half-edges: (face, a, b, apex) for the three sides of every kept face
    fk = f[fid]
    a = np.concatenate([fk[:, 0], fk[:, 1], fk[:, 2]])
    b = np.concatenate([fk[:, 1], fk[:, 2], fk[:, 0]])
    c = np.concatenate([fk[:, 2], fk[:, 0], fk[:, 1]])
    hf = np.concatenate([fid, fid, fid])
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    forward = a < b                                     # traversal direction
    order = np.lexsort((hf, hi, lo))
    lo, hi, c, hf, forward = lo[order], hi[order], c[order], hf[order], forward[order]
    new = np.ones(len(lo), dtype=bool)
    new[1:] = (lo[1:] != lo[:-1]) | (hi[1:] != hi[:-1])
    start = np.nonzero(new)[0]
    count = np.diff(np.append(start, len(lo)))

    s0 = start
    s1 = np.where(count >= 2, start + 1, start)
    n0 = normals[hf[s0]]
    n1 = normals[hf[s1]].copy()
    same_dir = forward[s0] == forward[s1]               # inconsistent winding
    n1[same_dir & (count == 2)] *= -1.0
    cosang = np.clip(np.sum(n0 * n1, axis=1), -1.0, 1.0)
    dihedral = np.where(count == 1, 0.0, np.degrees(np.arccos(cosang)))
    dihedral = np.where(count > 2, 180.0, dihedral)

    boundary = count == 1
    crease = (count > 2) | ((count == 2) & (dihedral > crease_angle_deg))
    sel = boundary | crease
    ev0, ev1 = lo[s0][sel], hi[s0][sel]
    p0, p1 = v[ev0], v[ev1]
    if min_length > 0:
        ok = np.linalg.norm(p1 - p0, axis=1) >= min_length
    else:
        ok = np.ones(len(ev0), dtype=bool)
    ap0, ap1 = c[s0][sel][ok], c[s1][sel][ok]
    faces_out = np.stack([hf[s0][sel], np.where(boundary[sel], -1, hf[s1][sel])], axis=1)[ok]
    return EdgeSet(p0=p0[ok], p1=p1[ok], v0=ev0[ok], v1=ev1[ok],
                   kind=np.where(boundary[sel], BOUNDARY, CREASE).astype(np.int8)[ok],
                   faces=faces_out.astype(np.int64), a0=ap0, a1=ap1,
                   apex0=v[ap0], apex1=v[ap1], dihedral=dihedral[sel][ok])


def point_segment_distance(points, p0, p1) -> np.ndarray:
    """Euclidean distance from ``points [..., 3]`` to segments ``p0, p1 [..., 3]``."""
    seg = p1 - p0
    l2 = np.sum(seg * seg, axis=-1)
    t = np.sum((points - p0) * seg, axis=-1) / np.where(l2 > 0, l2, 1.0)
    t = np.clip(np.where(l2 > 0, t, 0.0), 0.0, 1.0)
    return np.linalg.norm(points - (p0 + t[..., None] * seg), axis=-1)


class EdgeIndex:
    """Nearest-edge queries over an :class:`EdgeSet`.

    Every edge is cut into ``ceil(L / piece)`` equal pieces (``piece`` the
    median edge length unless given); a ``scipy.spatial.cKDTree`` on the piece
    midpoints is searched with ``radius + half the longest piece`` (a segment
    within ``radius`` of ``x`` has a piece whose midpoint is within that
    distance), and the candidates are then filtered and ranked by the exact
    point-to-segment distance.  Cutting keeps the search ball from growing with
    the longest edge of the mesh, and the candidate pairs come from a tree of
    the query points (``sparse_distance_matrix``), not per-point lists.
    """

    def __init__(self, edge_set: EdgeSet, piece: float | None = None):
        from scipy.spatial import cKDTree

        self.edges = edge_set
        self._tree = None
        if not len(edge_set):
            return
        length = edge_set.length
        piece = float(np.median(length)) if piece is None else float(piece)
        piece = piece if piece > 0 else max(float(length.max()), 1e-9)
        n_pc = np.maximum(np.ceil(length / piece), 1).astype(np.int64)
        self._edge_of = np.repeat(np.arange(len(edge_set)), n_pc)
        first = np.cumsum(n_pc) - n_pc
        frac = (np.arange(len(self._edge_of)) - first[self._edge_of] + 0.5) / n_pc[self._edge_of]
        p0, p1 = edge_set.p0[self._edge_of], edge_set.p1[self._edge_of]
        self._hmax = float(np.max(0.5 * length / n_pc))
        self._tree = cKDTree(p0 + frac[:, None] * (p1 - p0))

    def query(self, points, radius: float, max_edges: int = 4, return_distance: bool = False):
        """Up to ``max_edges`` edges within ``radius`` of each point, nearest first.

        Parameters
        ----------
        points : array_like
            ``[N, 3]`` query points [m]
        radius : float
            search radius [m] (> 0)
        max_edges : int, optional
            ``K``, the number of columns returned
        return_distance : bool, optional
            also return the distances

        Returns
        -------
        idx : numpy.ndarray
            ``[N, K]`` int64 edge indices; padding has ``idx == 0``
            (safe for gathers)
        valid : numpy.ndarray
            ``[N, K]`` bool; ``False`` for padding
        dist : numpy.ndarray
            ``[N, K]`` distances [m] (inf where invalid); only with
            ``return_distance``
        """
        pts = np.asarray(points, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise InputValueError(f"points: expected shape (N, 3), got {pts.shape}")
        if not np.all(np.isfinite(pts)):
            raise InputValueError("points: contain NaN or Inf")
        if not (np.isfinite(radius) and radius > 0):
            raise InputValueError(f"radius must be finite and > 0, got {radius!r}")
        if int(max_edges) < 1:
            raise InputValueError(f"max_edges must be >= 1, got {max_edges!r}")
        n, k = len(pts), int(max_edges)
        idx = np.zeros((n, k), dtype=np.int64)
        valid = np.zeros((n, k), dtype=bool)
        dist = np.full((n, k), np.inf)
        if self._tree is not None:
            for lo in range(0, n, QUERY_CHUNK):    # the candidate lists stay small
                sl = slice(lo, min(n, lo + QUERY_CHUNK))
                self._query_chunk(pts[sl], radius, idx[sl], valid[sl], dist[sl])
        return (idx, valid, dist) if return_distance else (idx, valid)

    def _query_chunk(self, pts, radius, idx, valid, dist) -> None:
        """:meth:`query` of the points ``pts``, written into the views ``idx``,
        ``valid``, ``dist``."""
        from scipy.spatial import cKDTree

        k = idx.shape[1]
        pairs = cKDTree(pts).sparse_distance_matrix(self._tree, radius + self._hmax,
                                                    output_type="ndarray")
        if not len(pairs):
            return
        key = np.unique(pairs["i"].astype(np.int64) * len(self.edges)
                        + self._edge_of[pairs["j"]])        # (point, edge), pieces merged
        pi, e = key // len(self.edges), key % len(self.edges)
        dd = point_segment_distance(pts[pi], self.edges.p0[e], self.edges.p1[e])
        m = dd <= radius
        e, pi, dd = e[m], pi[m], dd[m]
        order = np.lexsort((e, dd, pi))
        e, pi, dd = e[order], pi[order], dd[order]
        first = np.searchsorted(pi, pi, side="left")
        rank = np.arange(len(pi)) - first
        m = rank < k
        idx[pi[m], rank[m]] = e[m]
        valid[pi[m], rank[m]] = True
        dist[pi[m], rank[m]] = dd[m]

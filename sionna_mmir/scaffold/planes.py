"""Snap the planar parts of a reconstructed mesh onto fitted planes.

A LiDAR mesh keeps millimetres of range noise after local denoising: the MLS
fit of :mod:`.denoise` averages over a neighbourhood of a few dozen samples,
which leaves 0.3-0.45 mm rms on the benchmark street and parking lot.  At
77 GHz that is 1-1.5 rad of round-trip phase, so a large flat panel seen
face-on (a car door, a façade) returns only a fraction of its specular power
coherently (``exp(-(4 pi sigma / lambda)^2)`` of it, 0.2 at 0.4 mm).  Fitting
one plane to the whole panel averages over thousands of samples instead; on
the street and parking lot, larger MLS radii alone lifted the true-material
correlation ceiling from 0.665 / 0.661 to 0.70-0.76 / 0.88-0.90.

Algorithm (region growing with a smoothness constraint, Rabbani, van den
Heuvel & Vosselman 2006, "Segmentation of point clouds using smoothness
constraint", ISPRS Archives 36(5); plane fit by total least squares):

1. Faces are visited in order of increasing roughness (the largest angle to
   an edge-adjacent face).  An unassigned face seeds a region, which grows
   across shared edges: a face joins when its normal is within
   ``angle_deg`` of the region's (area-weighted mean) normal and its three
   vertices are within ``distance`` of the region's plane.
2. A region of at least ``min_area`` is a plane: its normal is the
   least-variance direction of its vertices (total least squares), its
   offset their mean.  Smaller regions (curved surfaces, small parts) are
   left alone.
3. A face outside every plane joins an edge-adjacent plane when its three
   vertices are within ``distance`` of it, whatever its normal (up to three
   passes: noise spikes, the rounded strips a denoiser leaves along edges).
4. Each vertex touching at least one plane moves to
   ``argmin_x sum_j (n_j . x - d_j)^2 + mu |x - x_0|^2`` over the planes ``j``
   of its faces (``mu`` = :data:`_MU`): onto the plane, onto the line where
   two planes meet (a box edge), onto the point where three meet (a corner).
   Where that point is more than ``2 distance`` away (nearly parallel
   planes) the vertex takes the mean of its projections onto each plane.

Curved surfaces: the growth follows a surface of curvature radius ``rho``
until it sags by ``distance`` from the region's plane, i.e. over strips
``2 sqrt(2 rho distance)`` wide (35 mm for a 0.3 m column at 2 mm), so a
large, gently curved object would be cut into planar strips.  Shape alone
cannot tell that from the bowing a denoiser leaves on a flat panel (the
benchmark cars' faces: 0.6-0.9 mm rms, nearly all of it quadratic), so
:func:`.scaffold.prepare_scaffold` leaves the objects
:func:`.shading.curved_fraction` calls curved out of this step.

Only vertex positions change: same vertices (count and order), same faces,
same metadata; vertex normals are recomputed from the new faces (shade with
:mod:`.shading` afterwards).

======================  ======================================================
``mesh``                ``trimesh.Trimesh`` [m] or ``dict`` name -> mesh
``angle_deg``           largest normal deviation from a region's normal, in
                        ``(0, 45]`` [deg] (5)
``distance``            largest vertex distance from a region's plane, ``> 0``
                        [m] (2 mm: 4-5x the denoised scan's residual)
``min_area``            smallest region snapped, ``>= 0`` [m^2] (0.05)
returns                 the same type; the planes found are in
                        ``mesh.metadata["planes"]`` (``count``, ``area_m2``)
======================  ======================================================
"""
from __future__ import annotations

import math
import numbers

import numpy as np
import trimesh

from ..errors import InputValueError
from ..scene.mesh_io import trimesh_arrays

#: weight of the stay-put term of the vertex least squares (plane terms weigh
#: 1 each): a vertex keeps mu / (1 + mu) of its offset from a single plane
_MU = 1e-3


def snap_planes(mesh, angle_deg: float = 5.0, distance: float = 0.002,
                min_area: float = 0.05):
    """See module docstring."""
    cos_a, tol, amin = _check(angle_deg, distance, min_area)
    if isinstance(mesh, dict):
        if not mesh:
            raise InputValueError("snap_planes: empty dict of meshes")
        return {name: _snap(m, name, cos_a, tol, amin) for name, m in mesh.items()}
    return _snap(mesh, "mesh", cos_a, tol, amin)


def _real(name, v):
    if isinstance(v, bool) or not isinstance(v, numbers.Real) or not math.isfinite(float(v)):
        raise InputValueError(f"snap_planes: {name} must be a finite number, got {v!r}")
    return float(v)


def _check(angle_deg, distance, min_area):
    a = _real("angle_deg", angle_deg)
    if not 0.0 < a <= 45.0:
        raise InputValueError(f"snap_planes: angle_deg must be in (0, 45] [deg], got {a}")
    d = _real("distance", distance)
    if d <= 0.0:
        raise InputValueError(f"snap_planes: distance must be > 0 [m], got {d}")
    m = _real("min_area", min_area)
    if m < 0.0:
        raise InputValueError(f"snap_planes: min_area must be >= 0 [m^2], got {m}")
    return math.cos(math.radians(a)), d, m


def _snap(mesh, name, cos_a, tol, amin):
    faces, verts = trimesh_arrays(mesh, name, "snap_planes")
    geom = _face_geometry(verts, faces)
    label = _grow(verts, faces, geom, mesh.face_adjacency, cos_a, tol)
    planes = _planes(verts, faces, geom[1], label, amin, tol)
    label = _absorb(verts, faces, mesh.face_adjacency, label, planes, tol)
    new = _project(verts, faces, label, planes, tol)
    out = trimesh.Trimesh(new, faces.copy(), process=False)
    out.metadata.update(mesh.metadata)
    out.metadata["planes"] = dict(count=len(planes),
                                  area_m2=[round(p[2], 4) for p in planes.values()])
    return out


def _face_geometry(verts, faces):
    tri = verts[faces]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norm = np.linalg.norm(cross, axis=1)
    n = np.divide(cross, norm[:, None], out=np.zeros_like(cross), where=norm[:, None] > 0)
    return n, 0.5 * norm, tri.mean(axis=1)


def _grow(verts, faces, geom, adjacency, cos_a, tol) -> np.ndarray:
    """Region label per face (``-2``: degenerate face, never assigned);
    ``geom``: :func:`_face_geometry`."""
    F = len(faces)
    n, area, cen = geom
    adjacency = np.asarray(adjacency, dtype=np.int64).reshape(-1, 2)
    # neighbour lists (CSR) and roughness = largest angle to a neighbour
    src = np.concatenate([adjacency[:, 0], adjacency[:, 1]])
    dst = np.concatenate([adjacency[:, 1], adjacency[:, 0]])
    order = np.argsort(src, kind="stable")
    src, dst = src[order], dst[order]
    start = np.searchsorted(src, np.arange(F + 1))
    rough = np.full(F, -1.0)
    if len(src):
        np.maximum.at(rough, src, -np.einsum("ij,ij->i", n[src], n[dst]))
    seeds = np.lexsort((-area, rough))
    label = np.full(F, -1, dtype=np.int64)
    label[area <= 0] = -2
    nl, vl, dl = n.tolist(), verts.tolist(), dst.tolist()
    fl, al, cl, st = faces.tolist(), area.tolist(), cen.tolist(), start.tolist()
    region = 0
    for s in seeds.tolist():
        if label[s] != -1:
            continue
        label[s] = region
        a = al[s]
        sn = [a * nl[s][0], a * nl[s][1], a * nl[s][2]]          # sum A n
        sc = [a * cl[s][0], a * cl[s][1], a * cl[s][2]]          # sum A c
        sa = a
        queue = [s]
        while queue:
            f = queue.pop()
            inv = 1.0 / math.sqrt(sn[0] ** 2 + sn[1] ** 2 + sn[2] ** 2)
            rn = (sn[0] * inv, sn[1] * inv, sn[2] * inv)
            d = (rn[0] * sc[0] + rn[1] * sc[1] + rn[2] * sc[2]) / sa
            for g in dl[st[f]:st[f + 1]]:
                if label[g] != -1:
                    continue
                ng = nl[g]
                if rn[0] * ng[0] + rn[1] * ng[1] + rn[2] * ng[2] < cos_a:
                    continue
                if any(abs(rn[0] * vl[v][0] + rn[1] * vl[v][1] + rn[2] * vl[v][2] - d) > tol
                       for v in fl[g]):
                    continue
                label[g] = region
                ag, cg = al[g], cl[g]
                sn = [sn[0] + ag * ng[0], sn[1] + ag * ng[1], sn[2] + ag * ng[2]]
                sc = [sc[0] + ag * cg[0], sc[1] + ag * cg[1], sc[2] + ag * cg[2]]
                sa += ag
                queue.append(g)
        region += 1
    return label


def _planes(verts, faces, area, label, amin, tol) -> dict:
    """region -> (unit normal, offset, area) of the regions that are planes."""
    ok = label >= 0
    sums = np.bincount(label[ok], weights=area[ok])
    out = {}
    for r in np.flatnonzero(sums >= max(amin, 1e-300)):
        v = verts[np.unique(faces[label == r])]
        mean = v.mean(axis=0)
        _, _, vt = np.linalg.svd(v - mean, full_matrices=False)
        nrm = vt[-1]
        d = float(nrm @ mean)
        if np.max(np.abs(v @ nrm - d)) > 2.0 * tol:        # not a plane after all
            continue
        out[int(r)] = (nrm, d, float(sums[r]))
    return out


def _absorb(verts, faces, adjacency, label, planes, tol, passes: int = 3) -> np.ndarray:
    """Faces outside every plane join an edge-adjacent plane whose surface
    holds all three of their vertices (within ``tol``), whatever their normal:
    a noise spike's fan of tilted faces, the rounded strip a denoiser leaves
    along a box edge."""
    if not planes:
        return label
    label = label.copy()
    adjacency = np.asarray(adjacency, dtype=np.int64).reshape(-1, 2)
    pairs = np.concatenate([adjacency, adjacency[:, ::-1]])          # (face, neighbour)
    for _ in range(passes):
        in_plane = np.isin(label, np.fromiter(planes, dtype=np.int64))
        cand = pairs[~in_plane[pairs[:, 0]] & in_plane[pairs[:, 1]]]
        if not len(cand):
            break
        r = label[cand[:, 1]]
        nrm = np.stack([planes[int(k)][0] for k in r])
        off = np.array([planes[int(k)][1] for k in r])
        dist = np.abs(np.einsum("fij,fj->fi", verts[faces[cand[:, 0]]], nrm) - off[:, None])
        ok = dist.max(axis=1) <= tol
        if not ok.any():
            break
        f, r = cand[ok, 0], r[ok]
        first = np.unique(f, return_index=True)[1]                    # one plane per face
        label[f[first]] = r[first]
    return label


def _project(verts, faces, label, planes, tol) -> np.ndarray:
    """Least-squares move of each vertex onto the planes of its faces."""
    new = verts.copy()
    if not planes:
        return new
    is_plane = np.zeros(label.max() + 2, dtype=bool)
    ids = np.fromiter(planes, dtype=np.int64)
    is_plane[ids] = True
    lab = np.where(label >= 0, label, -1)          # -1: is_plane's last entry, always False
    keep = is_plane[lab]
    pairs = np.unique(np.stack([faces[keep].ravel(), np.repeat(lab[keep], 3)], axis=1), axis=0)
    if not len(pairs):
        return new
    vid, rid = pairs[:, 0], pairs[:, 1]
    lut_n = np.zeros((len(is_plane), 3))
    lut_d = np.zeros(len(is_plane))
    for r, (nrm, d, _) in planes.items():
        lut_n[r], lut_d[r] = nrm, d
    nv, dv = lut_n[rid], lut_d[rid]
    V = len(verts)
    M = np.zeros((V, 3, 3))
    b = np.zeros((V, 3))
    np.add.at(M, vid, nv[:, :, None] * nv[:, None, :])
    np.add.at(b, vid, nv * dv[:, None])
    touched = np.unique(vid)
    Mt = M[touched] + _MU * np.eye(3)
    bt = b[touched] + _MU * verts[touched]
    x = np.linalg.solve(Mt, bt[..., None])[..., 0]
    far = np.linalg.norm(x - verts[touched], axis=1) > 2.0 * tol
    if far.any():                       # nearly parallel planes: mean of the projections
        off = np.einsum("ij,ij->i", nv, verts[vid]) - dv
        step = np.zeros((V, 3))
        np.add.at(step, vid, off[:, None] * nv)
        cnt = np.bincount(vid, minlength=V)[touched[far]]
        x[far] = verts[touched[far]] - step[touched[far]] / cnt[:, None]
    new[touched] = x
    return new

"""Feature-preserving denoising of LiDAR-derived meshes (moving-least-squares planes).

A LiDAR reconstruction (:func:`sionna_mmir.benchmark_scenes.lidarize`) keeps ~1 mm rms
of position noise along the surface normal and face normals tilted by a few
degrees (tens of degrees in mm-sized triangles); at 77 GHz (lambda = 3.9 mm)
that noise scrambles the coherent specular return of flat walls.
:func:`denoise_mesh` moves every vertex onto a plane fitted to its
surroundings without rounding the creases and corners between planes.  It
is a moving-least-squares plane projection (Alexa et al. 2003, "Computing
and rendering point set surfaces", IEEE TVCG 9(1)) with the spatial x
influence weights of feature-preserving bilateral smoothing (Jones, Durand &
Desbrun 2003, "Non-iterative, feature-preserving mesh smoothing", ACM TOG
22(3)), restricted to neighbours on the same side of a crease; reference
normals are filtered bilaterally (Zheng et al. 2011, "Bilateral normal
filtering for mesh denoising", IEEE TVCG 17(10)); vertices on a crease move
to the least-squares intersection of their neighbours' planes (the quadric
of Garland & Heckbert 1997, "Surface simplification using quadric error
metrics").  Written from the equations of those papers.

Each of the ``iterations`` passes (normals recomputed from the previous
result); ``R = radius``, ``sigma = R / 2``, ``theta = crease_angle_deg``
(the crease tests use ``0.9 theta``: reference normals are good to ~1 deg,
and a crease of exactly ``theta`` -- the 30 deg between the facets of a
12-sided pole -- must not be split by chance):

1. **Samples.**  The surface samples are the face *centroids* ``c_f``
   weighted by face *area* ``A_f`` (dense patches, where the scan has many
   small triangles, do not outweigh sparse ones); zero-area faces are
   ignored.
2. **Reference normals.**  Observed normal of a face: its own, or, for a
   face smaller than ``R / 8``, that of the vector area ``sum A_f n_f`` of
   the faces in its cube of side ``R / 8`` (the tilts of mm-sized triangles
   cancel in it).  Smoothed over the faces within ``R`` with weights
   ``A exp(-d^2 / 2 sigma^2)``, first among normals within ``theta / 2`` of
   each other (the two sides of a crease never mix), then within ``theta``.
   Vertex reference normal ``r_v``: area-weighted mean of its faces'.  A
   vertex is a **crease vertex** (it lies on two or more planes) when faces
   holding >= 1/4 of its area have reference normals more than ``theta / 2``
   from ``r_v``; for the others ``r_v`` is recomputed without such faces.
3. **Plane fit** of every other vertex ``v`` (position ``x_v``): the faces
   within ``R`` whose reference normal is within ``theta`` of ``r_v``,
   weighted by ``A_f exp(-|c_f - x_v|^2 / 2 sigma^2) exp(-h_f^2 / 2
   sigma_h^2)``, ``h_f = r_v . (c_f - x_v)`` the height above the vertex's
   tangent plane (the influence weight of Jones et al.: parallel planes --
   recesses, steps, boards on a wall -- do not mix).  The plane passes
   through the weighted centroid ``mu``; its normal ``n`` is the eigenvector
   of the smallest eigenvalue of the weighted covariance plus a weak prior
   ``(R^2 / 64) (I - r_v r_v^T)`` (a neighbourhood of a few collinear faces
   falls back to ``r_v`` instead of tilting at random), oriented like
   ``r_v``.  A first fit with ``sigma_h = R / 8`` gives the noise ``s^2``
   (median smallest eigenvalue; per mesh, at most 16 x the value pooled
   over the meshes denoised together); the kept fit uses ``sigma_h =
   clip(6 s, R / 100, R / 8)``.  It needs >= 3 faces, ``n`` within
   ``theta`` of ``r_v`` and an rms residual <= 4 ``s`` (else the fit is
   redone within ``R / 2``, else the vertex is left unchanged: small curved
   or faceted parts).  The vertex moves to ``x_v - n (n . (x_v - mu))``; its
   vertex normal is ``n``.
4. **Crease vertices** move to ``argmin_x sum_j (n_j . (x - p_j))^2`` over
   the planes ``(n_j, p_j)`` of their fitted edge neighbours (one-ring),
   solved in the eigenbasis of ``sum_j n_j n_j^T`` along the directions
   whose eigenvalue exceeds 2 % of the largest (across the crease, not
   along it); normal: the normalised mean of the ``n_j``.  Without such a
   plane, or for a step longer than ``R / 4``, the vertex is left unchanged.

Speed: faces and vertices are pooled into cells (cubes of side ``R / 4``,
split where normals differ by more than ``theta / 2``); the weights of
step 3 are evaluated between cell centroids while the area moments (``sum
A``, ``sum A c``, ``sum A c c^T``) are summed exactly, so each fit is exact
for planar data and the cost grows with area / ``R^2``, not with the number
of triangles in dense patches.  Vertices of one cell share one fit.  About
1.5 s for a 95 000-vertex LiDAR hallway and ~7 s for a 200 000-vertex
1 cm grid with ``R`` = 5 cm, on two loaded CPU cores.

Choosing ``radius``: 2.5-3.5 point spacings of the scan (LiDAR meshes
record it in ``metadata["lidar"]["point_spacing"]``); the default 5 cm
suits 1-2 cm scans.  Noise falls roughly as 1 / sqrt(number of faces
within ``R / 2``).  Limitations: a plane is fitted, so curved surfaces
shrink (a 1 mm-noise cylinder of radius 1 m / 0.3 m by 0.4 / 1.4 mm at
``R`` = 5 cm); facets at about ``theta`` (12-sided poles with the default
30 deg) may be smoothed together -- use ``crease_angle_deg`` = 20-25 for
them; parts smaller than a point spacing have no interior samples and are
mostly left unchanged.
"""
from __future__ import annotations

import copy
import numbers
from typing import TYPE_CHECKING

import numpy as np

from ..errors import InputValueError

if TYPE_CHECKING:
    import trimesh

# trimesh and scipy are imported where used: importing sionna_mmir.scene
# stays light (see sionna_mmir/scene/__init__.py)

_CELL_FRACTION = 1.0 / 4.0   # cell side / radius
_HEIGHT_FRACTION = 1.0 / 8.0  # sigma_h / radius (influence weight)
_MIN_SAMPLES = 3              # fewer usable faces: vertex left unchanged
_NOISE_MIN_NEFF = 6.0         # fits that estimate the noise: >= this many effective faces
_MIN_WEIGHT = 1e-3            # a face counts as usable from this weight on (max 1)
_PRIOR_SPREAD = 1.0 / 64.0    # tangent-plane prior of a fit / radius^2
_NOISE_FACTOR = 6.0           # sigma_h of the second fit / noise estimate
_MIN_HEIGHT_FRACTION = 1.0 / 100.0  # smallest sigma_h / radius
_NOISE_SPREAD = 16.0          # largest noise variance of a mesh / pooled variance
_PLANARITY = 4.0              # largest rms residual of a kept fit / noise estimate
_OBS_CELL = 0.5               # cube side for the normal of small faces / cell side
_SMOOTH_CELL = 2.0            # cell side of the normal smoothing / cell side
_MAX_CLUSTERS = 8             # normal clusters per cube (faceted poles: up to ~6)
_CREASE_MARGIN = 0.9          # the crease tests use this fraction of the crease angle
_CREASE_AREA = 0.25           # area fraction of off-normal faces that makes a crease vertex
_CREASE_RANK = 0.02           # eigenvalue ratio of a determined crease direction
_MAX_CREASE_STEP = 0.25       # largest crease-vertex step / radius


# --------------------------------------------------------------------------
# Input checks
# --------------------------------------------------------------------------
def _check(mesh, radius, crease_angle_deg, iterations):
    import trimesh

    if not isinstance(mesh, trimesh.Trimesh):
        raise InputValueError("denoise_mesh: mesh must be a trimesh.Trimesh, "
                              f"got {type(mesh).__name__}")
    if len(mesh.faces) == 0:
        raise InputValueError("denoise_mesh: mesh has no faces")
    if not np.isfinite(np.asarray(mesh.vertices, dtype=float)).all():
        raise InputValueError("denoise_mesh: mesh has NaN/Inf vertices")
    try:
        r = float(radius)
    except (TypeError, ValueError):
        raise InputValueError(f"denoise_mesh: radius must be a number [m], "
                              f"got {radius!r}") from None
    if not np.isfinite(r) or r <= 0:
        raise InputValueError(f"denoise_mesh: radius must be finite and > 0 [m], got {radius!r}")
    try:
        a = float(crease_angle_deg)
    except (TypeError, ValueError):
        raise InputValueError("denoise_mesh: crease_angle_deg must be a number [deg], "
                              f"got {crease_angle_deg!r}") from None
    if not (0 < a <= 90):  # also rejects NaN
        raise InputValueError(f"denoise_mesh: crease_angle_deg must be in (0, 90] [deg], "
                              f"got {crease_angle_deg!r}")
    if (isinstance(iterations, bool) or not isinstance(iterations, numbers.Real)
            or not np.isfinite(float(iterations)) or float(iterations) != int(iterations)
            or int(iterations) < 1):
        raise InputValueError("denoise_mesh: iterations must be an integer >= 1, "
                              f"got {iterations!r}")
    return r, a, int(iterations)


# --------------------------------------------------------------------------
# Cells: group rows by integer keys
# --------------------------------------------------------------------------
def _group(keys):
    """(inverse (N,), number of groups) of the distinct rows of int64 ``keys`` (N, k)."""
    if len(keys) == 0:
        return np.zeros(0, dtype=np.int64), 0
    keys = keys - keys.min(axis=0)
    span = keys.max(axis=0) + 1
    if np.prod(span.astype(float)) < 2.0 ** 62:  # one linear index per row
        lin = np.zeros(len(keys), dtype=np.int64)
        for k in range(keys.shape[1]):
            lin = lin * span[k] + keys[:, k]
        _, inv = np.unique(lin, return_inverse=True)
    else:
        _, inv = np.unique(keys, axis=0, return_inverse=True)
    inv = inv.ravel()
    return inv, int(inv.max()) + 1


def _sum(inv, n, values):
    """Per-group sums of ``values`` (N,) or (N, k)."""
    if values.ndim == 1:
        return np.bincount(inv, weights=values, minlength=n)
    return np.stack([np.bincount(inv, weights=values[:, k], minlength=n)
                     for k in range(values.shape[1])], axis=1)


def _unit(v):
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return np.divide(v, n, out=np.zeros_like(v), where=n > 0)


def _pairs(tree_a, tree_b, radius):
    """(i, j, distance) of all pairs within ``radius`` (self pairs included)."""
    if tree_a.n == 0 or tree_b.n == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros(0)
    p = tree_a.sparse_distance_matrix(tree_b, radius, output_type="ndarray")
    return (np.ascontiguousarray(p["i"]), np.ascontiguousarray(p["j"]),
            np.ascontiguousarray(p["v"]))


def _dot(a, i, b, j, dtype=np.float32):
    """Row-wise dot products ``a[i] . b[j]`` (pairs), gathered one column at a time."""
    out = np.zeros(len(i), dtype=dtype)
    for k in range(a.shape[1]):
        out += np.take(a[:, k].astype(dtype), i) * np.take(b[:, k].astype(dtype), j)
    return out


def _matrix(w, i, j, shape):
    """Sparse matrix of weights ``w`` on pairs (COO: products need no sorting)."""
    from scipy.sparse import coo_matrix

    return coo_matrix((w, (i, j)), shape=shape)


def _clusters(vox, normals, weights, cos_split):
    """Cell index (N,) and count: cubes ``vox`` split by normal direction.

    In each cube the largest-weight element's normal seeds a cluster of the
    elements within the split angle of it; the rest is split the same way
    (at most ``_MAX_CLUSTERS``, then one for what is left).  Noise does not
    split a plane into several cells; a crease does."""
    vinv, nvox = _group(vox)
    label = np.full(len(vox), _MAX_CLUSTERS, dtype=np.int64)
    left = np.ones(len(vox), dtype=bool)
    for k in range(_MAX_CLUSTERS):
        idx = np.flatnonzero(left)
        if idx.size == 0:
            break
        order = idx[np.lexsort((-weights[idx], vinv[idx]))]    # by cube, heaviest first
        first = np.ones(len(order), dtype=bool)
        first[1:] = vinv[order[1:]] != vinv[order[:-1]]
        top = np.zeros(len(vox), dtype=bool)
        top[order[first]] = True                                # one seed per cube
        top = top[idx]
        seed = np.zeros((nvox, 3))
        seed[vinv[idx[top]]] = normals[idx[top]]
        member = np.einsum("ij,ij->i", normals[idx], seed[vinv[idx]]) >= cos_split
        # re-centre on the members' mean (a noisy seed would leave out part
        # of its own plane); the seed always stays in
        mean = np.zeros((nvox, 3))
        np.add.at(mean, vinv[idx[member]], normals[idx[member]] * weights[idx[member], None])
        member = (np.einsum("ij,ij->i", normals[idx], _unit(mean)[vinv[idx]]) >= cos_split) | top
        label[idx[member]] = k
        left[idx[member]] = False
    return _group(np.column_stack([vinv, label]))


_OUTER = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))


def _sym3(m6):
    """(N, 6) upper-triangle entries -> (N, 3, 3) symmetric matrices."""
    out = np.empty((len(m6), 3, 3))
    for k, (a, b) in enumerate(_OUTER):
        out[:, a, b] = m6[:, k]
        out[:, b, a] = m6[:, k]
    return out


# --------------------------------------------------------------------------
# One pass
# --------------------------------------------------------------------------
def _plane_fit(w, i, j, nt, ns, moments, s_cnt, t_r, reg):
    """Weighted PCA planes of the target cells.

    ``s_cnt`` (ns, 2): faces and sum of squared areas per source cell.
    Returns (mu, n, residual variance, usable faces); the residual variance
    (smallest eigenvalue) is scaled by ``N / (N - 3)`` (``N``: effective
    number of weighted faces, a plane has 3 parameters) where ``N > 3.5``."""
    wmat = _matrix(w, i, j, (nt, ns))
    acc = wmat @ moments
    W, m1, m2 = acc[:, 0], acc[:, 1:4], acc[:, 4:]
    wmat.data = w * w
    sq = wmat @ s_cnt[:, 1]
    wmat.data = (w >= _MIN_WEIGHT).astype(float)     # usable: weight >= 0.001
    cnt = wmat @ s_cnt[:, 0]
    Wd = np.where(W > 0, W, 1.0)
    mu = m1 / Wd[:, None]
    cov = _sym3(m2 / Wd[:, None]) - mu[:, :, None] * mu[:, None, :]
    # prior: spread reg in the reference tangent plane (weak neighbourhoods
    # fall back to the reference normal instead of a random tilt)
    cov += reg * (np.eye(3) - t_r[:, :, None] * t_r[:, None, :])
    evals, evecs = np.linalg.eigh(cov)
    n = evecs[:, :, 0]
    n *= np.where(np.einsum("ij,ij->i", n, t_r) < 0, -1.0, 1.0)[:, None]
    cnt = np.where(W > 0, cnt, 0.0)
    neff = np.divide(W * W, sq, out=np.zeros(nt), where=sq > 0)
    lam0 = np.maximum(evals[:, 0], 0.0)
    lam0 = np.where(neff > 3.5, lam0 * neff / np.maximum(neff - 3.0, 0.5), lam0)
    return mu, n, lam0, cnt, neff


def _prepare(x, faces, radius, cos_crease, cos_half):
    """Steps 1-3 up to fit A; returns the state :func:`_finish` completes."""
    from scipy.spatial import cKDTree

    nv = len(x)
    h = radius * _CELL_FRACTION
    sigma2 = 2.0 * (radius / 2.0) ** 2

    # -- 1. faces ---------------------------------------------------------------
    tri = x[faces]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    dbl = np.linalg.norm(cross, axis=1)
    fid = np.flatnonzero(dbl > 0)
    if fid.size == 0:
        return None
    tri, cross = tri[fid], cross[fid]
    a_g = 0.5 * dbl[fid]
    n_g = cross / dbl[fid, None]
    c_g = tri.mean(axis=1)
    longest = np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2).max(axis=1)
    vox = np.floor(c_g / h).astype(np.int64)

    # -- 2. reference normals -------------------------------------------------------
    # observed normal: a face smaller than R / 8 (dense patches: mm-sized
    # triangles tilted by tens of degrees) is represented by the vector area of
    # its cube of side R / 8 (sum A n: the interior noise cancels), a larger
    # face by its own
    fine = _OBS_CELL * h
    vinv, nvox = _group(np.floor(c_g / fine).astype(np.int64))
    vox_n = _unit(_sum(vinv, nvox, cross))
    obs = np.where((longest < fine)[:, None], vox_n[vinv], n_g)
    # smoothing on coarse cells (cubes of side R / 2 split at creases)
    inv, nc = _clusters(np.floor(c_g / (_SMOOTH_CELL * h)).astype(np.int64), obs, a_g, cos_half)
    ca = _sum(inv, nc, a_g)
    cc = _sum(inv, nc, c_g * a_g[:, None]) / ca[:, None]
    cr = _unit(_sum(inv, nc, obs * a_g[:, None]))
    tree = cKDTree(cc)
    i, j, d = _pairs(tree, tree, radius)
    g = np.exp(-d * d / sigma2) * np.take(ca, j)
    # crease-aware (bilateral) smoothing: neighbours within half the crease
    # angle (the two sides of a crease never mix), then within the crease
    # angle (the now accurate normals of one plane all agree)
    for cos_range in (cos_half, cos_crease):
        ok = _dot(cr, i, cr, j) >= cos_range
        cr = _unit(_matrix(np.where(ok, g, 0.0), i, j, (nc, nc)) @ cr)
    r_g = cr[inv]                                 # per face: its cell's reference normal

    # per vertex: area-weighted mean; crease flag
    corner_v = faces[fid].ravel()
    corner_f = np.repeat(np.arange(len(fid)), 3)
    r_v = _unit(_sum(corner_v, nv, r_g[corner_f] * a_g[corner_f, None]))
    has_area = np.bincount(corner_v, weights=a_g[corner_f], minlength=nv) > 0
    # crease vertex: faces holding >= 1/4 of its area are more than theta / 2
    # off r_v (one face tilted by a noisy vertex does not make a crease)
    off_side = np.einsum("ij,ij->i", r_g[corner_f], r_v[corner_v]) < cos_half
    area_off = np.bincount(corner_v, weights=a_g[corner_f] * off_side, minlength=nv)
    area_all = np.bincount(corner_v, weights=a_g[corner_f], minlength=nv)
    crease = has_area & (area_off >= _CREASE_AREA * area_all)
    # the others take their reference normal from their main side only
    keep = ~off_side & ~crease[corner_v]
    r_main = _unit(_sum(corner_v, nv, r_g[corner_f] * (a_g[corner_f] * keep)[:, None]))
    fix = has_area & ~crease & (area_off > 0)
    r_v[fix] = r_main[fix]
    smooth = has_area & ~crease

    # -- 3. plane fits ------------------------------------------------------------
    # source cells: cubes of side h split at creases, exact area moments
    inv, ns = _clusters(vox, r_g, a_g, cos_half)
    s_a = _sum(inv, ns, a_g)
    s_m1 = _sum(inv, ns, c_g * a_g[:, None])
    moments = np.column_stack([s_a, s_m1, _sum(inv, ns, np.column_stack(
        [c_g[:, a] * c_g[:, b] * a_g for a, b in _OUTER]))])
    s_cnt = np.column_stack([np.bincount(inv, minlength=ns), _sum(inv, ns, a_g * a_g)])
    s_c = s_m1 / s_a[:, None]
    s_r = _unit(_sum(inv, ns, r_g * a_g[:, None]))
    # target cells: the other (non-crease) vertices, cubes of side h split at
    # creases; the vertices of one cell share one fit
    vid = np.flatnonzero(smooth)
    tinv, nt = _clusters(np.floor(x[vid] / h).astype(np.int64), r_v[vid], np.ones(len(vid)),
                         cos_half)
    t_cnt = np.bincount(tinv, minlength=nt)
    t_x = _sum(tinv, nt, x[vid]) / t_cnt[:, None]
    t_r = _unit(_sum(tinv, nt, r_v[vid]))

    i, j, d = _pairs(cKDTree(t_x), cKDTree(s_c), radius)
    ok = _dot(t_r, i, s_r, j) >= cos_crease
    i, j, d = i[ok], j[ok], d[ok]
    g = np.exp(-d * d / sigma2)
    reg = _PRIOR_SPREAD * radius ** 2
    # fit A: heights above the reference tangent plane, sigma_h = R / 8
    hgt = (_dot(t_r, i, s_c, j, np.float64)
           - np.take(np.einsum("ij,ij->i", t_r, t_x), i))
    sh = radius * _HEIGHT_FRACTION
    mu, n_t, lam0, cnt, neff = _plane_fit(g * np.exp(-0.5 * (hgt / sh) ** 2), i, j, nt, ns,
                                          moments, s_cnt, t_r, reg)
    return dict(x=x, faces=faces, radius=radius, cos_crease=cos_crease, nv=nv, r_v=r_v,
                crease=crease, has_area=has_area, vid=vid, tinv=tinv, nt=nt, ns=ns, i=i, j=j,
                d=d, g=g, hgt=hgt, sh=sh, sigma2=sigma2, moments=moments, s_cnt=s_cnt,
                t_r=t_r, reg=reg, lam0=lam0[(cnt >= _MIN_SAMPLES) & (neff >= _NOISE_MIN_NEFF)])


def _finish(st, noise2):
    """Fit B, projection and crease vertices of a :func:`_prepare` state.

    ``noise2``: reference residual variance (median smallest eigenvalue of
    fit A, pooled over the meshes denoised together)."""
    (x, faces, radius, cos_crease, nv, r_v, crease, has_area, vid, tinv, nt, ns, i, j, d, g,
     hgt, sigma2, moments, s_cnt, t_r, reg) = (
        st[k] for k in ("x", "faces", "radius", "cos_crease", "nv", "r_v", "crease", "has_area",
                        "vid", "tinv", "nt", "ns", "i", "j", "d", "g", "hgt", "sigma2",
                        "moments", "s_cnt", "t_r", "reg"))
    noise2 = max(noise2, (1e-6 * radius) ** 2)
    # fit B: sigma_h from the noise, so that parallel planes a few noise
    # levels apart (steps, recesses) do not mix
    sh = min(st["sh"], max(_NOISE_FACTOR * np.sqrt(noise2), radius * _MIN_HEIGHT_FRACTION))
    wh = np.exp(-0.5 * (hgt / sh) ** 2)
    mu, n_t, lam0, cnt, _ = _plane_fit(g * wh, i, j, nt, ns, moments, s_cnt, t_r, reg)
    # a fit is kept when its neighbourhood is a plane to within the noise
    fit = ((cnt >= _MIN_SAMPLES) & (np.einsum("ij,ij->i", n_t, t_r) >= cos_crease)
           & (lam0 <= _PLANARITY ** 2 * noise2))
    # the others (small curved or faceted parts: poles, edges of boxes) are
    # fitted again on half the radius
    sel = np.flatnonzero(~fit[i] & (d < 0.5 * radius))
    if sel.size:
        w2 = np.exp(-d[sel] ** 2 / (0.25 * sigma2)) * wh[sel]
        mu2, n2, lam2, cnt2, _ = _plane_fit(w2, i[sel], j[sel], nt, ns, moments, s_cnt, t_r,
                                         0.25 * reg)
        ok2 = (~fit & (cnt2 >= _MIN_SAMPLES) & (np.einsum("ij,ij->i", n2, t_r) >= cos_crease)
               & (lam2 <= _PLANARITY ** 2 * noise2))
        mu[ok2], n_t[ok2] = mu2[ok2], n2[ok2]
        fit |= ok2

    new_x = x.copy()
    normals = r_v.copy()
    fitted = np.zeros(nv, dtype=bool)
    v_fit = fit[tinv]
    v = vid[v_fit]
    nt_v, mu_v = n_t[tinv[v_fit]], mu[tinv[v_fit]]
    new_x[v] = x[v] - nt_v * np.einsum("ij,ij->i", nt_v, x[v] - mu_v)[:, None]
    normals[v] = nt_v
    fitted[v] = True

    # -- 4. crease vertices: intersection of the one-ring planes ------------------
    if crease.any():
        e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
        e = np.sort(e[crease[e[:, 0]] | crease[e[:, 1]]], axis=1)
        key = np.unique(e[:, 0] * nv + e[:, 1])
        e = np.column_stack([key // nv, key % nv])
        e = np.concatenate([e, e[:, ::-1]])          # (crease vertex, neighbour)
        e = e[crease[e[:, 0]] & fitted[e[:, 1]]]
        if len(e):
            a, b = e[:, 0], e[:, 1]
            nb = normals[b]
            off = np.einsum("ij,ij->i", nb, new_x[b])
            K = _sym3(_sum(a, nv, np.column_stack([nb[:, p] * nb[:, r] for p, r in _OUTER])))
            k = _sum(a, nv, nb * off[:, None])
            sum_n = _sum(a, nv, nb)
            cv = np.flatnonzero(crease & (np.bincount(a, minlength=nv) > 0))
            lam, vec = np.linalg.eigh(K[cv])
            resid = k[cv] - np.einsum("nij,nj->ni", K[cv], x[cv])
            proj = np.einsum("nik,ni->nk", vec, resid)             # e_k . resid
            use = lam > _CREASE_RANK * lam[:, -1:]
            coef = np.where(use, proj / np.where(use, lam, 1.0), 0.0)
            step = np.einsum("nik,nk->ni", vec, coef)
            ok = np.linalg.norm(step, axis=1) <= _MAX_CREASE_STEP * radius
            cv, step = cv[ok], step[ok]
            new_x[cv] = x[cv] + step
            nrm = _unit(sum_n[cv])
            good_n = np.linalg.norm(nrm, axis=1) > 0
            normals[cv[good_n]] = nrm[good_n]
    return new_x, normals, has_area


# --------------------------------------------------------------------------
# Public API
# --------------------------------------------------------------------------
def denoise_mesh(mesh: trimesh.Trimesh, radius: float = 0.05, crease_angle_deg: float = 30.0,
                 iterations: int = 2) -> trimesh.Trimesh:
    """Feature-preserving denoising: move every vertex onto its local plane.

    Method in the module docstring.  Left where they are: vertices with
    fewer than 3 usable faces (weight >= 0.001) within ``radius``
    (isolated triangles, a ``radius`` below the point spacing), vertices
    whose neighbourhood is not a plane to within the noise even on half the
    radius (parts smaller than a few spacings), crease vertices without
    fitted neighbours, and vertices of zero-area faces only (their normal:
    the reference normal, or the input's vertex normal).  The noise level
    is estimated from this mesh alone; :func:`denoise_meshes` shares it
    between the objects of a scene.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        the mesh [m] (not modified)
    radius : float, optional
        neighbourhood radius ``R`` [m], > 0; Gaussian
        weights of ``sigma = R / 2``.  Use 2.5-3.5 point
        spacings of the scan (default 5 cm: 1-2 cm scans)
    crease_angle_deg : float, optional
        faces whose reference normals differ by more than
        this are on different planes [deg], in (0, 90]
    iterations : int, optional
        number of passes (>= 1), each recomputing normals

    Returns
    -------
    trimesh.Trimesh
        a new mesh (``process=False``): the same
        faces in the same order, denoised vertices,
        ``vertex_normals`` = fitted plane normals (unit),
        copies of ``face_attributes``, ``vertex_attributes``
        and ``metadata``

    Raises
    ------
    InputValueError
        ``mesh`` is not a ``trimesh.Trimesh``, has no faces or NaN/Inf
        vertices, or a ``radius`` that is not finite and > 0, a
        ``crease_angle_deg`` outside (0, 90] or ``iterations`` that is not
        an integer >= 1.
    """
    r, angle, n_iter = _check(mesh, radius, crease_angle_deg, iterations)
    return _denoise([mesh], r, angle, n_iter)[0]


def _denoise(meshes, radius, angle, n_iter):
    """Denoise checked meshes together (one noise estimate for all of them)."""
    import trimesh

    # reference normals are good to ~1 deg: a crease of exactly the crease
    # angle (the 30 deg between the facets of a 12-sided pole) must not be
    # split by chance, so the tests use 90 % of it
    cos_crease = float(np.cos(np.radians(_CREASE_MARGIN * angle)))
    cos_half = float(np.cos(np.radians(_CREASE_MARGIN * angle / 2.0)))
    faces = [np.asarray(m.faces, dtype=np.int64) for m in meshes]
    origins = [np.asarray(m.vertices, dtype=np.float64).mean(axis=0) for m in meshes]
    xs = [np.asarray(m.vertices, dtype=np.float64) - o       # centred: well-conditioned moments
          for m, o in zip(meshes, origins)]
    normals, has_area = [None] * len(meshes), [None] * len(meshes)
    for _ in range(n_iter):
        states = [_prepare(x, f, radius, cos_crease, cos_half) for x, f in zip(xs, faces)]
        # noise: per mesh (it depends on the incidence of the scan), at most 4x
        # the pooled rms (an object made only of small facets has no plane to
        # measure it on)
        lam0 = np.concatenate([st["lam0"] for st in states if st is not None] + [np.zeros(0)])
        pooled = float(np.median(lam0)) if lam0.size else 0.0
        for k, st in enumerate(states):
            if st is None:                        # no face of non-zero area
                normals[k], has_area[k] = np.zeros_like(xs[k]), np.zeros(len(xs[k]), dtype=bool)
                continue
            own = float(np.median(st["lam0"])) if st["lam0"].size else pooled
            xs[k], normals[k], has_area[k] = _finish(st, min(own, _NOISE_SPREAD * pooled))
        del states
    out = []
    for m, x, o, f, nrm, ha in zip(meshes, xs, origins, faces, normals, has_area):
        if not ha.all():
            nrm[~ha] = np.asarray(m.vertex_normals, dtype=np.float64)[~ha]
        res = trimesh.Trimesh(
            vertices=x + o, faces=f.copy(), process=False,
            face_attributes={k: np.array(v, copy=True) for k, v in m.face_attributes.items()},
            vertex_attributes={k: np.array(v, copy=True) for k, v in m.vertex_attributes.items()},
            metadata=copy.deepcopy(m.metadata))
        res.vertex_normals = nrm
        out.append(res)
    return out


def auto_radius(meshes, spacings: float = 3.0) -> float:
    """``spacings`` x the median unique edge length of ``meshes`` (a mesh or a
    ``dict`` of them) [m]: the scan's point spacing measured on the mesh,
    so that a neighbourhood holds a few dozen samples."""
    import trimesh

    items = list(meshes.values()) if isinstance(meshes, dict) else [meshes]
    lengths = [np.asarray(m.edges_unique_length) for m in items
               if isinstance(m, trimesh.Trimesh) and len(m.faces)]
    if not lengths:
        raise InputValueError("auto_radius: no mesh with faces")
    return float(spacings * np.median(np.concatenate(lengths)))


def denoise_meshes(meshes: dict, **kwargs) -> dict:
    """:func:`denoise_mesh` of every mesh of a ``dict`` name -> ``trimesh.Trimesh``.

    Each mesh is fitted on its own samples (no neighbours from other
    objects).  The noise level is estimated per mesh but capped at 4x the
    rms pooled over all of them, so that an object made only of small
    facets (a pole, a bollard), which has no plane to measure it on, is
    judged against the scene's noise.

    Parameters
    ----------
    meshes : dict
        name -> ``trimesh.Trimesh`` [m] (e.g. the result of
        :func:`sionna_mmir.benchmark_scenes.lidarize`)
    **kwargs
        ``radius`` [m] (``None``: :func:`auto_radius`, 3 median edge
        lengths), ``crease_angle_deg`` [deg], ``iterations``
        (see :func:`denoise_mesh`), the same for every mesh

    Returns
    -------
    dict
        name -> denoised ``trimesh.Trimesh``, same keys in
        the same order (``{}`` for ``{}``)

    Raises
    ------
    InputValueError
        ``meshes`` is not a ``dict``, an unknown keyword, or any error of
        :func:`denoise_mesh` (the message names the object).
    """
    if not isinstance(meshes, dict):
        raise InputValueError(f"denoise_meshes: meshes must be a dict name -> trimesh.Trimesh, "
                              f"got {type(meshes).__name__}")
    unknown = set(kwargs) - {"radius", "crease_angle_deg", "iterations"}
    if unknown:
        raise InputValueError(f"denoise_meshes: unknown keyword argument(s) {sorted(unknown)}")
    params = {"radius": 0.05, "crease_angle_deg": 30.0, "iterations": 2, **kwargs}
    if not meshes:
        return {}
    if params["radius"] is None:
        params["radius"] = auto_radius(meshes)
    for name, mesh in meshes.items():
        try:
            r, angle, n_iter = _check(mesh, **params)
        except InputValueError as err:
            raise InputValueError(f"denoise_meshes: object {name!r}: {err}") from None
    return dict(zip(meshes, _denoise(list(meshes.values()), r, angle, n_iter)))

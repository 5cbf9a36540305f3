"""Sub-facet sets (:class:`~.accumulate.Scatterers`) of single bounces and image chains.

``single_bounce``: every face (in front of the array when the element
patterns are directional) is split into sub-facets (:mod:`.facets`); a
sub-facet counts when the segment from its centroid to the array centre is
free (:class:`~.mesh.Occlusion`, one ray per sub-facet).

``chain_bounce``: the lit region of an image chain (:mod:`sionna_mmir.independent.images`) is
split the same way with the chain's image source; the folded path of each
visibility cell (the mirror points found by crossing the unfolded line with
each mirror plane) is ray cast segment by segment, and the co-polar Fresnel
coefficient and coherent roughness factor of every mirror bounce multiply
the weight.  Ray-cast end points are moved :data:`SURFACE_OFFSET` off their
surface, to the side the path is on.
"""
from __future__ import annotations

import numpy as np

from . import facets, polygons
from .accumulate import ArrayGeometry, Scatterers
from .images import compose, image_sources, mirror_map
from .materials import copol_reflection
from .patterns import pattern_exponents
from .rough import coherent_factor

#: Offset of ray-cast end points off their surface [m].
SURFACE_OFFSET = 1e-4


def _aperture(array: ArrayGeometry) -> float:
    return float(np.linalg.norm(array.tx - array.centre, axis=1).max()
                 + np.linalg.norm(array.rx - array.centre, axis=1).max())


def _offset(points, normals, towards):
    """``points`` moved :data:`SURFACE_OFFSET` along ``normals`` to the side of ``towards``."""
    side = np.sign(np.einsum("sk,sk->s", towards - points, normals))
    return points + SURFACE_OFFSET * side[:, None] * normals


def single_bounce(scene, occl, array, k, freq, opts, diffuse, rng) -> Scatterers:
    """Visible sub-facets of every face, lit and seen from the array (module docstring).

    Parameters
    ----------
    scene : SceneMesh
        The scene.
    occl : Occlusion
        Visibility.
    array : ArrayGeometry
        Elements and centre.
    k, freq : float
        Wavenumber [rad/m] and frequency [Hz].
    opts : dict
        Split options (:func:`~.facets.split`).
    diffuse : bool
        Add the incoherent term.
    rng : numpy.random.Generator
        Its random phases.

    Returns
    -------
    Scatterers
        Depth 1, identity image map.
    """
    c = array.centre
    tri = scene.triangles
    keep = np.arange(len(tri))
    if pattern_exponents(array.tx_pattern) is not None or \
            pattern_exponents(array.rx_pattern) is not None:
        ahead = (tri - c) @ array.rotation[:, 0]                 # radar-frame x [F, 3]
        keep = keep[ahead.max(axis=1) > 0]
    sub, parent, _, _ = facets.split(tri[keep], c, c, k, _aperture(array), opts)
    face = keep[parent]
    x = sub.mean(axis=1)
    vis = ~occl.blocked(_offset(x, scene.normals[face], c), np.broadcast_to(c, x.shape))
    w_coh, w_diff = facets.weights(scene, sub[vis], face[vis], c, c, k, freq, diffuse, rng)
    return Scatterers(sub[vis], w_coh, w_diff, depth=1)


def _crossing(a, b, n, d):
    """Points where segments ``a -> b`` ``[S, 3]`` cross the plane ``n . y = d``."""
    v = b - a
    t = (d - a @ n) / (v @ n)
    return a + t[:, None] * v


def _reflection_points(x, seq, srcs, pieces):
    """Folded path ``[p_0, .., p_{n-2}, x]`` of a chain ending at points ``x [S, 3]``."""
    pts = [x]
    for m in range(len(seq) - 2, -1, -1):
        pc = pieces[seq[m]]
        pts.insert(0, _crossing(np.broadcast_to(srcs[m + 1], x.shape), pts[0], pc.normal, pc.offset))
    return pts


def chain_bounce(chain, pieces, scene, occl, array, k, freq, opts) -> Scatterers:
    """Sub-facets of a chain's lit region, with the mirror bounces' factors.

    Parameters
    ----------
    chain : Chain
        From :func:`~.images.chains`.
    pieces : list of Piece
        The scene's planar pieces.
    scene, occl, array, k, freq, opts
        As :func:`single_bounce`.

    Returns
    -------
    Scatterers
        Depth ``len(chain.pieces)``, Tx-side image map of the mirrors.
    """
    c = array.centre
    seq = chain.pieces
    srcs = image_sources(pieces, seq[:-1], c)                  # s_0 .. s_{n-1}
    tris, owners = [], []
    for poly, faces in chain.regions:
        t = polygons.fan(poly)
        tris.append(t)
        owners.append(np.tile(faces, (len(t), 1)))
    tris, owners = np.concatenate(tris), np.concatenate(owners)
    area = 0.5 * np.linalg.norm(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]), axis=1)
    tris, owners = tris[area > polygons.MIN_POLY_AREA], owners[area > polygons.MIN_POLY_AREA]
    sub, parent, cells, cell = facets.split(tris, srcs[-1], c, k, _aperture(array), opts,
                                            opts["chain_aperture_phase"], opts["visibility_cell"])
    vis_pts = _reflection_points(cells.mean(axis=1), seq, srcs, pieces)
    ends = [_offset(p, np.broadcast_to(pieces[q].normal, p.shape), np.broadcast_to(srcs[m], p.shape))
            for m, (p, q) in enumerate(zip(vis_pts, seq))]
    cc = np.broadcast_to(c, ends[0].shape)
    vis = np.ones(len(cells), dtype=bool)
    for a, b in zip([cc] + ends, ends + [cc]):
        vis &= ~occl.blocked(np.ascontiguousarray(a), np.ascontiguousarray(b))
    ok = vis[cell]
    sub, owner = sub[ok], owners[parent[ok]]                   # owner: [S, n] faces
    w, _ = facets.weights(scene, sub, owner[:, -1], srcs[-1], c, k, freq)
    pts = _reflection_points(sub.mean(axis=1), seq, srcs, pieces)
    for m, p in enumerate(pts[:-1]):
        u = p - srcs[m]
        cos = np.abs(u @ pieces[seq[m]].normal) / np.linalg.norm(u, axis=1)
        par = scene.parameters(owner[:, m], p)
        w = w * copol_reflection(cos, par, freq) * coherent_factor(k, par[:, 2], cos, cos)
    lin, off = np.eye(3), np.zeros(3)
    for q in seq[:-1]:
        lin, off = compose(mirror_map(pieces[q]), (lin, off))
    return Scatterers(sub, w, None, lin, off, depth=len(seq))



"""Tests for :mod:`sionna_mmir.scene.edges`: boundary / crease detection, the
LiDAR-noise edge suppression filter and nearest-edge queries vs brute force."""
from __future__ import annotations

import numpy as np
import pytest

from sionna_mmir.errors import InputValueError
from sionna_mmir.scene.edges import (BOUNDARY, CREASE, EdgeIndex, find_diffracting_edges,
                                     point_segment_distance)


def square():
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=float)
    return v, np.array([[0, 1, 2], [0, 2, 3]])


def cube(flip_some=False):
    v = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], dtype=float)
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    f = []
    for a, b, c, d in quads:
        f += [[a, b, c], [a, c, d]]
    f = np.array(f)
    if flip_some:
        f[::3] = f[::3, ::-1]
    return v, f


def grid(n, jitter=0.0, seed=0):
    """n x n quads on [0,1]^2 (2 n^2 triangles); z jitter of ``jitter`` metres."""
    xs = np.linspace(0, 1, n + 1)
    X, Y = np.meshgrid(xs, xs, indexing="ij")
    rng = np.random.default_rng(seed)
    Z = jitter * rng.standard_normal(X.shape)
    v = np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=1)
    i = np.arange(n)[:, None] * (n + 1) + np.arange(n)[None, :]
    a, b, c, d = i, i + (n + 1), i + (n + 2), i + 1
    f = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3),
                        np.stack([a, c, d], -1).reshape(-1, 3)])
    return v, f


def test_01_square_has_four_boundary_edges():
    es = find_diffracting_edges(*square())
    assert len(es) == 4 and np.all(es.kind == BOUNDARY)
    np.testing.assert_allclose(np.sort(es.length), [1, 1, 1, 1])
    assert np.all(es.faces[:, 1] == -1) and np.all(es.a0 == es.a1)
    # apex is the third vertex of the adjacent face
    for k in range(len(es)):
        face = square()[1][es.faces[k, 0]]
        assert set(face) == {es.v0[k], es.v1[k], es.a0[k]}


@pytest.mark.parametrize("flip", [False, True])
def test_02_cube_has_twelve_creases(flip):
    es = find_diffracting_edges(*cube(flip))
    assert len(es) == 12 and np.all(es.kind == CREASE)
    np.testing.assert_allclose(es.dihedral, 90.0, atol=1e-9)
    np.testing.assert_allclose(es.length, 1.0)
    # face diagonals (coplanar, 0 deg) are suppressed; with a 95 deg threshold all go
    assert len(find_diffracting_edges(*cube(flip), crease_angle_deg=95.0)) == 0


def test_03_noisy_plane_keeps_only_outer_boundary():
    n = 24
    v, f = grid(n, jitter=0.002)                 # cell 4.2 mm: normals tilt by a few deg
    # check the premise: the noise really tilts the interior faces by several degrees
    cr = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    tilt = np.degrees(np.arccos(np.abs(cr[:, 2]) / np.linalg.norm(cr, axis=1)))
    assert 1.0 < np.median(tilt) < 15.0
    assert len(find_diffracting_edges(v, f, crease_angle_deg=0.5)) > 4 * n  # noise creases
    es = find_diffracting_edges(v, f)
    assert len(es) == 4 * n and np.all(es.kind == BOUNDARY)
    mid = es.midpoint
    on_border = np.isclose(mid[:, 0], 0) | np.isclose(mid[:, 0], 1) | \
        np.isclose(mid[:, 1], 0) | np.isclose(mid[:, 1], 1)
    assert np.all(on_border)
    # min_length filter
    assert len(find_diffracting_edges(v, f, min_length=0.1)) == 0


def test_04_non_manifold_and_degenerate():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [2, 0, 0]], float)
    f = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4], [0, 1, 5]])   # last: degenerate (collinear)
    es = find_diffracting_edges(v, f)
    shared = (es.v0 == 0) & (es.v1 == 1)
    assert shared.sum() == 1 and es.kind[shared][0] == CREASE     # 3 faces: non-manifold
    assert np.all(es.kind[~shared] == BOUNDARY) and len(es) == 7


def test_05_bad_input():
    v, f = square()
    bad = v.copy()
    bad[1, 0] = np.nan
    with pytest.raises(InputValueError):
        find_diffracting_edges(bad, f)
    with pytest.raises(InputValueError):
        find_diffracting_edges(v, f + 10)
    with pytest.raises(InputValueError):
        find_diffracting_edges(v[:, :2], f)
    with pytest.raises(InputValueError):
        EdgeIndex(find_diffracting_edges(v, f)).query(np.full((1, 3), np.nan), 0.1)


def test_06_query_matches_brute_force():
    rng = np.random.default_rng(3)
    v, f = grid(8, jitter=0.0)
    # random crumpled sheet: many edges of various lengths via a low threshold
    v[:, 2] = 0.2 * rng.standard_normal(len(v))
    es = find_diffracting_edges(v, f, crease_angle_deg=20.0)
    assert len(es) > 50
    pts = rng.uniform(-0.2, 1.2, size=(400, 3))
    pts[:, 2] *= 0.3
    radius, k = 0.15, 5
    idx, valid, dist = EdgeIndex(es).query(pts, radius, max_edges=k, return_distance=True)
    d_all = point_segment_distance(pts[:, None, :], es.p0[None], es.p1[None])     # [N, E]
    for i in range(len(pts)):
        inside = np.nonzero(d_all[i] <= radius)[0]
        ref = inside[np.argsort(d_all[i, inside], kind="stable")][:k]
        got = idx[i, valid[i]]
        assert len(got) == len(ref)
        np.testing.assert_allclose(d_all[i, got], np.sort(d_all[i, inside])[:k], atol=1e-12)
        np.testing.assert_allclose(dist[i, valid[i]], d_all[i, got], atol=1e-12)
        assert np.all(idx[i, ~valid[i]] == 0)
    assert valid.any() and (~valid).any()


def test_07_empty_edge_set_query():
    v, f = cube()
    es = find_diffracting_edges(v, f, crease_angle_deg=120.0)
    assert len(es) == 0
    idx, valid = EdgeIndex(es).query(np.zeros((3, 3)), 1.0, max_edges=2)
    assert idx.shape == (3, 2) and not valid.any()


def split_vertices(v, f):
    """The same surface with no vertex shared between faces (flat shading)."""
    return v[f.reshape(-1)], np.arange(3 * len(f)).reshape(-1, 3)


def test_09_split_vertices_weld_to_the_true_edges():
    """A flat-shaded mesh (faces sharing no vertex) has its seams as boundary
    edges by vertex id; welded by position it has only the real ones."""
    n = 6
    v, f = grid(n)
    vs, fs = split_vertices(v, f)
    assert len(find_diffracting_edges(vs, fs)) == 3 * len(f)          # every side a "boundary"
    es = find_diffracting_edges(vs, fs, weld_tol=1e-6)
    ref = find_diffracting_edges(v, f)
    assert len(es) == len(ref) == 4 * n and np.all(es.kind == BOUNDARY)
    key = lambda e: sorted(map(tuple, np.round(np.sort(np.stack([e.p0, e.p1], 1), 1), 9)
                               .reshape(len(e), -1)))
    assert key(es) == key(ref)
    np.testing.assert_allclose(es.p0, vs[es.v0]) and np.testing.assert_allclose(es.apex0, vs[es.a0])
    cube_es = find_diffracting_edges(*split_vertices(*cube()), weld_tol=1e-6)
    assert len(cube_es) == 12 and np.all(cube_es.kind == CREASE)
    with pytest.raises(InputValueError, match="weld_tol"):
        find_diffracting_edges(v, f, weld_tol=-1.0)


def test_10_query_of_mixed_lengths_in_chunks_matches_brute_force(monkeypatch):
    """Edges from 2 mm to 2 m (the index cuts the long ones into pieces) and
    a query split into chunks give the brute-force answer."""
    import sionna_mmir.scene.edges as edges_mod

    rng = np.random.default_rng(5)
    v, f = grid(10)
    v[:, 2] = 0.05 * rng.standard_normal(len(v))
    v = np.concatenate([v, [[0, 0, 1.0], [2.0, 0, 1.0], [2.0, 0.002, 1.0]]])
    f = np.concatenate([f, [[len(v) - 3, len(v) - 2, len(v) - 1]]])     # a 2 m sliver
    es = find_diffracting_edges(v, f, crease_angle_deg=10.0)
    assert es.length.max() / np.median(es.length) > 10
    pts = rng.uniform(-0.2, 2.2, size=(300, 3))
    pts[:, 1] *= 0.5
    along = np.column_stack([np.linspace(0.1, 1.9, 20), np.full(20, 0.06), np.ones(20)])
    pts = np.concatenate([pts, along])              # near the sliver, far from its midpoint
    radius, k = 0.12, 3
    monkeypatch.setattr(edges_mod, "QUERY_CHUNK", 64)
    idx, valid, dist = EdgeIndex(es).query(pts, radius, max_edges=k, return_distance=True)
    d_all = point_segment_distance(pts[:, None, :], es.p0[None], es.p1[None])
    for i in range(len(pts)):
        ref = np.sort(d_all[i][d_all[i] <= radius])[:k]
        np.testing.assert_allclose(dist[i, valid[i]], ref, atol=1e-12)
        np.testing.assert_allclose(d_all[i, idx[i, valid[i]]], ref, atol=1e-12)
    assert valid[-20:, 0].all() and (~valid).any()

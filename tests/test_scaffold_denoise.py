"""Tests for :mod:`sionna_mmir.scaffold.denoise`: the feature-preserving mesh denoiser.

Every check is against an independent truth: the exact plane(s) the noisy
test meshes were sampled from, the clean geometry that
:func:`sionna_mmir.benchmark_scenes.lidarize` records with its meshes, or the input
mesh itself.
"""
from __future__ import annotations

import copy

import numpy as np
import pytest
import trimesh
from scipy.spatial import Delaunay

from sionna_mmir.errors import InputValueError
from sionna_mmir.scaffold import denoise_mesh, denoise_meshes

NOISE = 1e-3        # position noise along the normal [m]
SPACING = 0.01      # point spacing of the synthetic meshes [m]


def _frame(normal):
    """Orthonormal (u, v, n) with n along ``normal``."""
    n = np.asarray(normal, dtype=float)
    n = n / np.linalg.norm(n)
    u = np.cross(n, [1.0, 0.0, 0.0])
    u /= np.linalg.norm(u)
    return u, np.cross(n, u), n


def _jittered_grid(rng, n=100, spacing=SPACING):
    """Points of an n x n grid on [0, n spacing]^2, jittered by +/- 0.35 spacing."""
    iu, iv = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    p = np.column_stack([iu.ravel(), iv.ravel()]) + 0.5 + rng.uniform(-0.35, 0.35, (n * n, 2))
    return p * spacing


def _triangulate(p2):
    """Delaunay triangles of 2-D points, without the slivers along the hull."""
    t = Delaunay(p2).simplices
    a, b, c = p2[t[:, 0]], p2[t[:, 1]], p2[t[:, 2]]
    edges = np.stack([np.linalg.norm(b - a, axis=1), np.linalg.norm(c - b, axis=1),
                      np.linalg.norm(a - c, axis=1)], axis=1).max(axis=1)
    area2 = np.abs((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1])
                   - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]))
    return t[(edges < 2.5 * SPACING) & (area2 > 0.04 * edges ** 2)]


def noisy_plane(seed=0, noise=NOISE):
    """1 m x 1 m tilted plane, 1 cm jittered grid: (mesh, true normal, point on the plane)."""
    rng = np.random.default_rng(seed)
    p2 = _jittered_grid(rng)
    faces = _triangulate(p2)
    u, v, n = _frame([0.3, -0.5, 0.81])
    origin = np.array([1.0, 2.0, 0.5])
    verts = origin + p2[:, :1] * u + p2[:, 1:] * v + rng.normal(0.0, noise, len(p2))[:, None] * n
    mesh = trimesh.Trimesh(verts, faces, process=False)
    if np.median(mesh.face_normals @ n) < 0:
        mesh = trimesh.Trimesh(verts, faces[:, ::-1], process=False)
    return mesh, n, origin


def noisy_corner(seed=1, noise=NOISE):
    """L-shaped room corner: floor and wall (1 m x 1 m each, 1 cm jittered grids)
    sharing the points of their common edge, as one mesh, rotated.

    Returns (mesh, side (Nv,) 0 floor / 1 wall / -1 on the crease, distance from
    the crease (Nv,) [m], plane normals (2, 3)); both planes contain the origin.
    """
    rng = np.random.default_rng(seed)
    ys = (np.arange(100) + 0.5) * SPACING
    crease2 = np.column_stack([np.zeros(100), ys])          # (distance from crease, y)
    pts, side, dist, faces = [np.column_stack([np.zeros(100), ys, np.zeros(100)])], \
        [np.full(100, -1)], [np.zeros(100)], []
    start = 100
    for s in (0, 1):
        p2 = _jittered_grid(rng)
        p2 = p2[p2[:, 0] > 0.4 * SPACING]
        t = _triangulate(np.vstack([crease2, p2]))
        ids = np.concatenate([np.arange(100), start + np.arange(len(p2))])
        faces.append(ids[t])
        zero = np.zeros(len(p2))
        # floor: x = distance, z = 0; wall: x = 0, z = distance
        pts.append(np.column_stack([p2[:, 0], p2[:, 1], zero]) if s == 0
                   else np.column_stack([zero, p2[:, 1], p2[:, 0]]))
        side.append(np.full(len(p2), s))
        dist.append(p2[:, 0])
        start += len(p2)
    verts, side, dist = np.vstack(pts), np.concatenate(side), np.concatenate(dist)
    faces = np.vstack(faces)
    normals = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])      # facing the room
    for s in (0, 1):
        verts[side == s] += rng.normal(0.0, noise, (side == s).sum())[:, None] * normals[s]
    on = side == -1
    verts[on] += rng.normal(0.0, noise, (on.sum(), 2)) @ normals
    # wind every face towards the room
    tri = verts[faces]
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    face_side = side[faces].max(axis=1)
    flip = np.einsum("ij,ij->i", fn, normals[face_side]) < 0
    faces[flip] = faces[flip][:, ::-1]
    u, v, n = _frame([0.2, 0.1, 1.0])
    rot = np.stack([u, v, n], axis=1)                          # columns: new axes
    return (trimesh.Trimesh(verts @ rot.T, faces, process=False), side, dist, normals @ rot.T)


def _rms(a):
    return float(np.sqrt(np.mean(np.square(a))))


def _angles_deg(normals, reference):
    cos = np.clip(np.asarray(normals) @ np.asarray(reference), -1.0, 1.0)
    return np.degrees(np.arccos(cos))


# --------------------------------------------------------------------------
# Accuracy
# --------------------------------------------------------------------------
def test_01_noisy_plane():
    mesh, n, origin = noisy_plane()
    out = denoise_mesh(mesh)                     # default radius 5 cm: 5 spacings
    before = _rms((np.asarray(mesh.vertices) - origin) @ n)
    after = _rms((np.asarray(out.vertices) - origin) @ n)
    assert before == pytest.approx(NOISE, rel=0.05)
    assert after <= before / 5.0, (before, after)
    ang = _angles_deg(out.vertex_normals, n)
    assert np.median(ang) <= 0.5, np.median(ang)
    # the face normals follow (input: ~9 deg median tilt)
    assert np.median(_angles_deg(out.face_normals, n)) <= 0.5


def test_02_crease_is_not_rounded():
    mesh, side, dist, normals = noisy_corner()
    out = denoise_mesh(mesh)
    v0, v1 = np.asarray(mesh.vertices), np.asarray(out.vertices)
    for s in (0, 1):
        near = (side == s) & (dist < 0.02)
        assert near.sum() > 100
        off0, off1 = v0[near] @ normals[s], v1[near] @ normals[s]
        # not pulled into a rounded corner: no systematic offset, within noise
        assert _rms(off1) <= _rms(off0), (s, _rms(off0), _rms(off1))
        assert np.abs(off1).max() < 2 * NOISE, (s, np.abs(off1).max())
        assert abs(np.mean(off1)) < 0.2 * NOISE, (s, np.mean(off1))
        ang = _angles_deg(out.vertex_normals[side == s], normals[s])
        assert np.median(ang) <= 1.0, (s, np.median(ang))
    # vertices on the crease stay on (or get closer to) the crease line
    on = side == -1
    line0 = np.linalg.norm(v0[on] @ normals.T, axis=1)
    line1 = np.linalg.norm(v1[on] @ normals.T, axis=1)
    assert _rms(line1) <= _rms(line0), (_rms(line0), _rms(line1))


@pytest.fixture(scope="module")
def lidar_hallway():
    from sionna_mmir.benchmark_scenes import build_scene, lidarize_scene

    spec = build_scene("hallway", seed=0)
    return lidarize_scene(spec, seed=0, max_triangles=50_000)


def test_03_lidarized_hallway(lidar_hallway):
    from sionna_mmir.benchmark_scenes import mesh_statistics

    spacing = next(iter(lidar_hallway.values())).metadata["lidar"]["point_spacing"]
    out = denoise_meshes(lidar_hallway, radius=3.0 * spacing)
    assert list(out) == list(lidar_hallway)
    s0, s1 = mesh_statistics(lidar_hallway), mesh_statistics(out)
    # clean geometry recorded by lidarize is the truth
    assert s1["offset_rms_m"] <= s0["offset_rms_m"] / 2.0, (s0["offset_rms_m"], s1["offset_rms_m"])
    assert s1["normal_dev_median_deg"] < s0["normal_dev_median_deg"] / 2.0, \
        (s0["normal_dev_median_deg"], s1["normal_dev_median_deg"])
    assert s1["normal_dev_p90_deg"] < s0["normal_dev_p90_deg"]
    assert s1["offset_max_m"] <= s0["offset_max_m"]
    # topology untouched
    for key in ("n_triangles", "n_vertices", "n_boundary_edges"):
        assert s1[key] == s0[key]


# --------------------------------------------------------------------------
# Structure
# --------------------------------------------------------------------------
def _mesh_with_attributes():
    mesh, _, _ = noisy_plane(seed=3)
    # a duplicate of vertex 0 (used by face 0; process=True would merge it)
    # and an unreferenced vertex
    verts = np.vstack([mesh.vertices, mesh.vertices[:1], [[5.0, 5.0, 5.0]]])
    faces = np.asarray(mesh.faces).copy()
    faces[0, 0] = len(verts) - 2                                            # uses the duplicate
    rng = np.random.default_rng(4)
    return trimesh.Trimesh(
        verts, faces, process=False,
        vertex_attributes={"clean_position": rng.normal(size=(len(verts), 3)),
                           "label": np.arange(len(verts))},
        face_attributes={"clean_normal": rng.normal(size=(len(faces), 3)),
                         "material": np.arange(len(faces)) % 7},
        metadata={"lidar": {"point_spacing": 0.01, "seed": 3}, "source": "test"})


def test_04_structure_preserved_input_untouched():
    mesh = _mesh_with_attributes()
    verts0 = np.array(mesh.vertices, copy=True)
    faces0 = np.array(mesh.faces, copy=True)
    vattr0 = {k: np.array(v, copy=True) for k, v in mesh.vertex_attributes.items()}
    fattr0 = {k: np.array(v, copy=True) for k, v in mesh.face_attributes.items()}
    meta0 = copy.deepcopy(mesh.metadata)

    out = denoise_mesh(mesh)
    assert isinstance(out, trimesh.Trimesh) and out is not mesh
    assert len(out.vertices) == len(verts0) and len(out.faces) == len(faces0)
    np.testing.assert_array_equal(out.faces, faces0)                  # same order
    assert set(out.vertex_attributes) == set(vattr0) and set(out.face_attributes) == set(fattr0)
    for k, v in vattr0.items():
        np.testing.assert_array_equal(out.vertex_attributes[k], v)
        assert not np.shares_memory(out.vertex_attributes[k], mesh.vertex_attributes[k])
    for k, v in fattr0.items():
        np.testing.assert_array_equal(out.face_attributes[k], v)
        assert not np.shares_memory(out.face_attributes[k], mesh.face_attributes[k])
    assert out.metadata == meta0
    out.metadata["lidar"]["seed"] = -1                                 # a deep copy
    assert mesh.metadata == meta0
    # the input is not modified
    np.testing.assert_array_equal(mesh.vertices, verts0)
    np.testing.assert_array_equal(mesh.faces, faces0)
    # vertices moved, unit normals that stick, unused vertex untouched
    assert np.abs(np.asarray(out.vertices) - verts0).max() > 0
    nrm = np.asarray(out.vertex_normals)
    assert nrm.shape == verts0.shape
    np.testing.assert_allclose(np.linalg.norm(nrm[:-1], axis=1), 1.0, atol=1e-9)
    np.testing.assert_array_equal(out.vertices[-1], verts0[-1])


def test_05_noise_free_plane_is_left_in_place():
    mesh, n, origin = noisy_plane(seed=5, noise=0.0)
    out = denoise_mesh(mesh)
    assert np.abs(np.asarray(out.vertices) - mesh.vertices).max() < 1e-9
    assert np.median(_angles_deg(out.vertex_normals, n)) < 1e-6


def test_06_denoise_meshes_dict():
    mesh, n, origin = noisy_plane(seed=6)
    corner = noisy_corner(seed=7)[0]
    out = denoise_meshes({"b": mesh, "a": corner}, radius=0.05, iterations=1)
    assert list(out) == ["b", "a"]
    assert all(isinstance(m, trimesh.Trimesh) for m in out.values())
    assert _rms((np.asarray(out["b"].vertices) - origin) @ n) < 0.5 * NOISE
    assert denoise_meshes({}) == {}
    with pytest.raises(InputValueError, match="meshes"):
        denoise_meshes([mesh])
    with pytest.raises(InputValueError, match="'bad'.*no faces"):
        denoise_meshes({"good": mesh, "bad": trimesh.Trimesh()})
    with pytest.raises(InputValueError, match="radius"):
        denoise_meshes({"good": mesh}, radius=-1.0)
    with pytest.raises(InputValueError, match="sigma"):
        denoise_meshes({"good": mesh}, sigma=1.0)


# --------------------------------------------------------------------------
# Bad inputs
# --------------------------------------------------------------------------
@pytest.fixture(scope="module")
def small_mesh():
    return trimesh.Trimesh(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0.0]]),
                           np.array([[0, 1, 2], [1, 3, 2]]), process=False)


@pytest.mark.parametrize("bad", [np.zeros((3, 3)), "mesh.ply", None])
def test_07_not_a_trimesh(bad):
    with pytest.raises(InputValueError, match="mesh must be a trimesh.Trimesh"):
        denoise_mesh(bad)


def test_08_mesh_without_faces():
    with pytest.raises(InputValueError, match="no faces"):
        denoise_mesh(trimesh.Trimesh())
    with pytest.raises(InputValueError, match="no faces"):
        denoise_mesh(trimesh.Trimesh(np.zeros((3, 3)), np.zeros((0, 3), dtype=int), process=False))


@pytest.mark.parametrize("value", [np.nan, np.inf])
def test_09_non_finite_vertex(small_mesh, value):
    verts = np.array(small_mesh.vertices, copy=True)
    verts[2, 1] = value
    with pytest.raises(InputValueError, match="NaN/Inf vertices"):
        denoise_mesh(trimesh.Trimesh(verts, small_mesh.faces, process=False))


@pytest.mark.parametrize("radius", [0.0, -0.05, np.nan, np.inf, "5 cm"])
def test_10_bad_radius(small_mesh, radius):
    with pytest.raises(InputValueError, match="radius"):
        denoise_mesh(small_mesh, radius=radius)


@pytest.mark.parametrize("angle", [0.0, 120.0, -10.0, np.nan])
def test_11_bad_crease_angle(small_mesh, angle):
    with pytest.raises(InputValueError, match="crease_angle_deg"):
        denoise_mesh(small_mesh, crease_angle_deg=angle)


@pytest.mark.parametrize("iterations", [0, -1, 1.5, True, "2"])
def test_12_bad_iterations(small_mesh, iterations):
    with pytest.raises(InputValueError, match="iterations"):
        denoise_mesh(small_mesh, iterations=iterations)


def test_13_limits_accepted(small_mesh):
    out = denoise_mesh(small_mesh, radius=1e-3, crease_angle_deg=90, iterations=1)
    np.testing.assert_array_equal(out.vertices, small_mesh.vertices)  # nothing within 1 mm


def test_14_auto_radius_is_three_point_spacings():
    """``radius=None``: 3 median edge lengths; on a jittered 1 cm grid the
    Delaunay edges have a median near the spacing, so the radius is ~3 cm,
    and the plane is still denoised >= 3x."""
    from sionna_mmir.scaffold.denoise import auto_radius

    mesh, n, origin = noisy_plane(seed=3)
    r = auto_radius({"plane": mesh})
    assert 2.5 * SPACING <= r <= 3.6 * SPACING, r
    out = denoise_meshes({"plane": mesh}, radius=None)["plane"]
    before = _rms((np.asarray(mesh.vertices) - origin) @ n)
    after = _rms((np.asarray(out.vertices) - origin) @ n)
    assert after <= before / 3.0, (before, after)
    with pytest.raises(InputValueError, match="auto_radius: no mesh with faces"):
        auto_radius({})

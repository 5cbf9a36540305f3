"""sionna_mmir.scaffold.snap_planes: region growing + total-least-squares planes, vertex snapping."""
from __future__ import annotations

import numpy as np
import pytest
import trimesh

from sionna_mmir.errors import InputValueError
from sionna_mmir.scaffold import snap_planes

HALF = np.array([1.0, 0.5, 0.4])           # half extents of the test box [m]


def _noisy(mesh, sigma, seed=0):
    rng = np.random.default_rng(seed)
    v = np.asarray(mesh.vertices) + rng.normal(0.0, sigma, (len(mesh.vertices), 3))
    return trimesh.Trimesh(v, np.asarray(mesh.faces), process=False)


def _box(subdiv=5):
    box = trimesh.creation.box(extents=2 * HALF)
    for _ in range(subdiv):
        box = box.subdivide()
    return box


def _plane_distances(v):
    """Distance of each vertex to each of the box's six face planes [V, 3] (by axis)."""
    return np.abs(np.abs(v) - HALF)


def test_01_noisy_box_lands_on_its_faces_edges_and_corners():
    """0.5 mm noise on a subdivided 2 x 1 x 0.8 m box: afterwards every
    vertex is every vertex within 0.2 mm of it (noise 1 mm)s analytic face plane (rms < 0.03 mm), the
    vertices of the box's edges within 0.1 mm of both planes, the six planes
    found have the analytic face areas (1 %)."""
    box = _box()
    noisy = _noisy(box, 0.5e-3)
    d_true = _plane_distances(np.asarray(box.vertices))
    on = d_true < 1e-9                                    # which planes each vertex lies on
    before = _plane_distances(np.asarray(noisy.vertices))[on]
    out = snap_planes(noisy)
    after = _plane_distances(np.asarray(out.vertices))[on]
    assert np.sqrt(np.mean(before ** 2)) > 4e-4
    # plane-fit error: ~ sigma sqrt(3 / N) = 2.7e-5 m for ~1000 vertices a face
    assert np.sqrt(np.mean(after ** 2)) < 6e-5 and after.max() < 2e-4
    edge = on.sum(axis=1) >= 2
    assert edge.sum() > 100
    assert _plane_distances(np.asarray(out.vertices))[edge][on[edge]].max() < 2e-4
    areas = sorted(out.metadata["planes"]["area_m2"])
    want = sorted(4 * np.array([HALF[1] * HALF[2], HALF[1] * HALF[2], HALF[0] * HALF[2],
                                HALF[0] * HALF[2], HALF[0] * HALF[1], HALF[0] * HALF[1]]))
    assert out.metadata["planes"]["count"] == 6
    np.testing.assert_allclose(areas, want, rtol=0.01)


def test_02_tilted_plane_normal_and_offset():
    """A 3 x 2 m grid tilted by 20 deg about x then 35 about z, 1 mm noise:
    the snapped vertices lie on one plane whose normal is within 0.02 deg of
    the true one (TLS over ~4000 points: sigma / (L sqrt(N)) ~ 3e-4 deg) and
    every vertex within 0.2 mm of it (noise 1 mm)."""
    g = trimesh.creation.box(extents=(3.0, 2.0, 1e-3))
    top = g.vertices[:, 2] > 0
    faces = g.faces[np.all(top[g.faces], axis=1)]
    plate = trimesh.Trimesh(g.vertices, faces, process=True)
    for _ in range(6):
        plate = plate.subdivide()
    v = np.asarray(plate.vertices) - [0, 0, 5e-4]
    ax, az = np.radians(20.0), np.radians(35.0)
    rx = np.array([[1, 0, 0], [0, np.cos(ax), -np.sin(ax)], [0, np.sin(ax), np.cos(ax)]])
    rz = np.array([[np.cos(az), -np.sin(az), 0], [np.sin(az), np.cos(az), 0], [0, 0, 1]])
    R = rz @ rx
    n_true = R @ [0.0, 0.0, 1.0]
    clean = trimesh.Trimesh(v @ R.T + [0.3, -0.2, 1.0], plate.faces, process=False)
    d_true = float(n_true @ [0.3, -0.2, 1.0])
    out = snap_planes(_noisy(clean, 1e-3, seed=3), distance=5e-3)
    w = np.asarray(out.vertices)
    assert out.metadata["planes"]["count"] == 1
    _, _, vt = np.linalg.svd(w - w.mean(axis=0))
    ang = np.degrees(np.arccos(min(1.0, abs(vt[-1] @ n_true))))
    assert ang < 0.02
    assert np.abs(w @ n_true - d_true).max() < 2e-4


def test_03_exact_planes_are_not_moved_and_curved_surfaces_are_left_alone():
    """Noise-free box: identity (1e-12).  A noisy 0.5 m sphere holds no
    plane of 0.05 m^2 (strips of sag <= 2 mm are ~ 0.006 m^2): no vertex moves."""
    box = _box(3)
    out = snap_planes(box)
    np.testing.assert_allclose(out.vertices, box.vertices, atol=1e-12)
    sphere = _noisy(trimesh.creation.icosphere(subdivisions=4, radius=0.5), 0.5e-3)
    out = snap_planes(sphere)
    assert out.metadata["planes"]["count"] == 0
    np.testing.assert_array_equal(out.vertices, sphere.vertices)


def test_04_min_area_and_small_parts():
    """A 10 cm noisy cube is below the default 0.05 m^2 per face and is left
    alone; with ``min_area=0`` its faces are snapped."""
    cube = trimesh.creation.box(extents=(0.1, 0.1, 0.1))
    for _ in range(3):
        cube = cube.subdivide()
    noisy = _noisy(cube, 0.1e-3)
    np.testing.assert_array_equal(snap_planes(noisy).vertices, noisy.vertices)
    out = snap_planes(noisy, min_area=0.0)
    assert out.metadata["planes"]["count"] == 6
    err = np.min(np.abs(np.abs(np.asarray(out.vertices)) - 0.05), axis=1)
    assert err.max() < 1e-4


def test_05_topology_metadata_and_dicts():
    noisy = _noisy(_box(2), 0.5e-3)
    noisy.metadata["name"] = "box"
    out = snap_planes({"b": noisy, "a": noisy})
    assert list(out) == ["b", "a"]
    for m in out.values():
        np.testing.assert_array_equal(m.faces, noisy.faces)
        assert len(m.vertices) == len(noisy.vertices)
        assert m.metadata["name"] == "box" and m.metadata["planes"]["count"] == 6
    assert "planes" not in noisy.metadata                   # input untouched


@pytest.mark.parametrize("kwargs, match", [
    (dict(angle_deg=0.0), "angle_deg"),
    (dict(angle_deg=60.0), "angle_deg"),
    (dict(angle_deg=float("nan")), "angle_deg"),
    (dict(distance=0.0), "distance"),
    (dict(distance=-1e-3), "distance"),
    (dict(distance="2mm"), "distance"),
    (dict(min_area=-1.0), "min_area"),
    (dict(min_area=True), "min_area"),
])
def test_06_bad_parameters(kwargs, match):
    with pytest.raises(InputValueError, match=match):
        snap_planes(_box(1), **kwargs)


def test_07_bad_meshes():
    with pytest.raises(InputValueError, match="empty dict"):
        snap_planes({})
    with pytest.raises(InputValueError, match="expected trimesh"):
        snap_planes({"x": np.zeros((3, 3))})
    with pytest.raises(InputValueError, match="no faces"):
        snap_planes(trimesh.Trimesh(np.zeros((3, 3)), np.zeros((0, 3), int), process=False))
    bad = _box(1)
    v = np.asarray(bad.vertices).copy()
    v[4, 1] = np.nan
    with pytest.raises(InputValueError, match="NaN"):
        snap_planes({"wall": trimesh.Trimesh(v, bad.faces, process=False)})

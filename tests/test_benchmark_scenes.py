"""Tests of sionna_mmir.benchmark_scenes: catalog, ground-truth materials, LiDAR meshes.

The LiDAR tests scan a closed 2 m x 2 m x 2 m room (faces wound inward) with
a 0.4 m cube on its floor, from two sensor positions, at 2.5 cm spacing.
"""
from __future__ import annotations

import numpy as np
import pytest
import trimesh

import sionna_mmir  # noqa: F401  (configures the backend first)
from sionna_mmir.errors import InputValueError
from sionna_mmir.radio_materials import available_materials, default_vertex_parameters
from sionna_mmir.benchmark_scenes import (
    SCENES,
    WAVELENGTH_77GHZ,
    area_weighted_mean,
    build_scene,
    lidarize,
    lidarize_scene,
    material_patches,
    mesh_statistics,
    rotation_matrix,
    true_materials,
    true_object_materials,
    region_names,
    true_region_materials,
    true_vertex_materials,
)

NAMES = ("hallway", "lab", "classroom", "street", "parking_lot", "building_corner")
SMOOTH_OBJECTS = {"pole", "lamp_pole", "downpipe", "bollards"}  # faceted cylinders
SPACING = 0.025
SIGMA = 0.005
SENSORS = np.array([[0.0, 0.0, 0.2], [-0.5, 0.4, 0.5]])


def _room():
    box = trimesh.creation.box(extents=[2.0, 2.0, 2.0])
    room = trimesh.Trimesh(box.vertices, box.faces[:, ::-1], process=False)  # faces inward
    cube = trimesh.creation.box(extents=[0.4, 0.4, 0.4])
    cube.apply_translation([0.5, -0.3, -0.8])  # standing on the floor z = -1
    return {"room": room, "cube": cube}


@pytest.fixture(scope="module")
def scenes():
    return {name: build_scene(name, seed=0) for name in NAMES}


@pytest.fixture(scope="module")
def room_scan():
    objects = _room()
    out = lidarize(objects, SENSORS, seed=3, point_spacing=SPACING, range_noise_std=SIGMA,
                   hole_fraction=0.01, max_triangles=None)
    return objects, out


# ---------------------------------------------------------------- catalog
def test_01_registry_builds_every_scene(scenes):
    assert set(SCENES) == set(NAMES)
    for name, spec in scenes.items():
        assert spec.name == name and spec.description
        assert len(spec.objects) >= 5
        assert set(spec.objects) == set(spec.materials)
        assert 50 < spec.n_triangles < 2000, (name, spec.n_triangles)
        assert np.shape(spec.radar_position) == (3,) and np.shape(spec.radar_orientation) == (3,)
        assert 0.8 <= spec.radar_position[2] <= 1.2
        assert spec.lidar_positions.ndim == 2 and spec.lidar_positions.shape[1] == 3
        for obj, mesh in spec.objects.items():
            assert isinstance(mesh, trimesh.Trimesh) and len(mesh.faces) > 0, (name, obj)
            assert np.isfinite(mesh.vertices).all()
            assert mesh.area_faces.min() > 1e-8, (name, obj)


def test_02_deterministic_for_a_seed():
    for name in NAMES:
        a, b = build_scene(name, seed=4), build_scene(name, seed=4)
        assert list(a.objects) == list(b.objects) and a.materials == b.materials
        for obj in a.objects:
            np.testing.assert_array_equal(a.objects[obj].vertices, b.objects[obj].vertices)
            np.testing.assert_array_equal(a.objects[obj].faces, b.objects[obj].faces)
        c = build_scene(name, seed=5)
        moved = any(obj not in c.objects or a.objects[obj].vertices.shape != c.objects[obj].vertices.shape
                    or not np.allclose(a.objects[obj].vertices, c.objects[obj].vertices)
                    for obj in a.objects)
        assert moved, f"{name}: seed does not change the layout"


def test_03_geometry_in_field_of_view_and_range():
    for name in NAMES:
        for seed in range(3):
            spec = build_scene(name, seed=seed)
            assert spec.field_of_view_violations() == [], (name, seed)
            # independent check in the radar frame
            rot = rotation_matrix(*spec.radar_orientation)
            for mesh in spec.objects.values():
                q = (mesh.vertices - spec.radar_position) @ rot
                assert q[:, 0].min() >= 1.0 - 1e-6
                assert np.linalg.norm(q, axis=1).max() <= 12.0 + 1e-6
                assert np.degrees(np.arctan2(np.abs(q[:, 1]), q[:, 0])).max() <= 60.0 + 1e-6


def test_04_materials_valid_at_77ghz(scenes):
    valid = set(available_materials(77e9))
    for name, spec in scenes.items():
        assert set(spec.materials.values()) <= valid, name
        assert "metal" in spec.materials.values()
        assert "glass" in spec.materials.values()


def test_05_winding_faces_the_radar_side_and_creases_unshared(scenes):
    for name, spec in scenes.items():
        for ground in ("floor", "road", "ground"):
            if ground in spec.objects:
                assert np.allclose(spec.objects[ground].face_normals, [0, 0, 1]), name
        if "ceiling" in spec.objects:
            assert np.allclose(spec.objects["ceiling"].face_normals, [0, 0, -1])
        # walls and facades (their main face) face the radar
        for obj in spec.objects:
            if obj.startswith(("wall", "facade")):
                m = spec.objects[obj]
                to_radar = spec.radar_position - m.triangles_center
                facing = np.einsum("ij,ij->i", m.face_normals, to_radar) > 0
                assert np.average(facing, weights=m.area_faces) > 0.9, (name, obj)
        # closed boxes (e.g. car bodies) face outward: positive signed volume
        for obj in spec.objects:
            if obj.endswith("_body"):
                assert spec.objects[obj].volume > 0, (name, obj)
        # vertex normals = face normals on flat parts
        for obj, m in spec.objects.items():
            if obj in SMOOTH_OBJECTS:
                continue
            vn = m.vertex_normals[m.faces]
            cos = np.einsum("fkj,fj->fk", vn, m.face_normals)
            assert cos.min() > 0.9999, (name, obj)


def test_06_refined_keeps_geometry(scenes):
    spec = scenes["hallway"]
    ref = spec.refined(max_edge=0.5)
    for obj, m in ref.items():
        assert m.area == pytest.approx(spec.objects[obj].area, rel=1e-9)
        assert m.edges_unique_length.max() <= 0.5 + 1e-9
    with pytest.raises(InputValueError):
        spec.refined(max_edge=0.0)


def test_07_build_scene_bad_input():
    with pytest.raises(InputValueError, match="unknown scene"):
        build_scene("office")
    with pytest.raises(InputValueError):
        build_scene("lab", seed=-1)


# ---------------------------------------------------------- true materials
def test_08_true_materials_in_bounds_varying_deterministic(scenes):
    for name, spec in scenes.items():
        ref = spec.refined(max_edge=0.5)
        truth = true_materials(spec, seed=1, objects=ref)
        again = true_materials(spec, seed=1, objects=ref)
        other = true_materials(spec, seed=2, objects=ref)
        for obj, p in truth.items():
            assert p.shape == (len(ref[obj].vertices), 6)
            assert np.isfinite(p).all()
            assert (p[:, 0] >= 1).all() and (p[:, 1] >= 0).all() and (p[:, 2] >= 0).all()
            assert (p[:, 3] > 0).all() and (p[:, 4] >= 0).all() and (p[:, 4] <= 1).all()
            assert (p[:, 5] > 0).all()
            np.testing.assert_array_equal(p, again[obj])
            if len(p) > 20:
                assert (np.std(p, axis=0)[[1, 2, 3, 5]] > 0).all(), (name, obj)
        big = max(spec.objects, key=lambda k: spec.objects[k].area)
        assert np.std(truth[big][:, 0]) > 0.02 * np.mean(truth[big][:, 0]), name
        assert not np.allclose(truth[big], other[big])
        # the variation is substantial but centred on the nominal values
        nominal = default_vertex_parameters(spec.materials[big], 77e9)
        ratio = truth[big][:, 0] / nominal[0]
        assert 0.6 < np.median(ratio) < 1.4 and ratio.max() > 1.05


def test_09_patches_of_other_materials(scenes):
    for name, spec in scenes.items():
        patches = {obj: material_patches(spec, obj, seed=0) for obj in spec.objects}
        assert sum(len(p) for p in patches.values()) >= 1, name
        for obj, plist in patches.items():
            for pt in plist:
                assert pt.material in available_materials(77e9) and pt.material != spec.materials[obj]
                p = true_vertex_materials(spec, obj, pt.center[None], seed=0)[0]
                nominal = default_vertex_parameters(pt.material, 77e9)
                # at the patch centre: the patch material (up to the smooth variation
                # (x0.6..1.65) and blobs (up to x3)); hosts differ by orders of magnitude
                assert abs(np.log(p[1] / nominal[1])) < 1.7, (name, obj, pt.material)


def test_10_true_materials_bad_input(scenes):
    spec = scenes["lab"]
    with pytest.raises(InputValueError):
        true_vertex_materials(spec, "no_such_object", np.zeros((2, 3)))
    with pytest.raises(InputValueError):
        true_vertex_materials(spec, "floor", np.array([[0.0, np.nan, 0.0]]))
    with pytest.raises(InputValueError):
        true_vertex_materials(spec, "floor", np.zeros((2, 2)))


# ------------------------------------------------------------------ LiDAR
def _box_distance(points, lo, hi):
    """Distance of points to the nearest face plane of an axis-aligned box."""
    return np.min(np.abs(np.concatenate([points - lo, points - hi], axis=1)), axis=1)


def _two_part_plate(left_side=1.0, right_side=3.0):
    """Two unshared flat rectangles 1 m tall, ``left_side`` and ``right_side`` m wide."""
    parts = []
    for x0, w in ((0.0, left_side), (left_side, right_side)):
        v = np.array([[x0, 0, 0], [x0 + w, 0, 0], [x0 + w, 1, 0], [x0, 1, 0]], float)
        parts.append((v, np.array([[0, 1, 2], [0, 2, 3]])))
    v = np.vstack([parts[0][0], parts[1][0]])
    f = np.vstack([parts[0][1], parts[1][1] + 4])
    return trimesh.Trimesh(v, f, process=False)


def test_10b_per_object_reduction_is_the_area_weighted_mean(scenes):
    host = default_vertex_parameters("concrete", 77e9)
    patch = default_vertex_parameters("metal", 77e9)
    # uniform object: its value, on a plate of unequal faces
    plate = _two_part_plate()
    np.testing.assert_allclose(area_weighted_mean(plate, np.tile(host, (8, 1))), host,
                               rtol=1e-12)
    # 1 m^2 of metal beside 3 m^2 of concrete: weights 1/4 and 3/4, linear for
    # eps_real and tau, geometric for eps_imag, sigma_h, l_c, d
    p = np.vstack([np.tile(patch, (4, 1)), np.tile(host, (4, 1))])
    got = area_weighted_mean(plate, p)
    lin = [0, 4]
    np.testing.assert_allclose(got[lin], 0.25 * patch[lin] + 0.75 * host[lin], rtol=1e-12)
    geo = [1, 2, 3, 5]
    patch_g = np.maximum(patch[geo], 1e-30)
    np.testing.assert_allclose(got[geo], np.exp(0.25 * np.log(patch_g) + 0.75 * np.log(host[geo])),
                               rtol=1e-10)
    assert not np.allclose(got, 0.5 * (patch + host))   # not the per-vertex mean
    with pytest.raises(InputValueError):
        area_weighted_mean(plate, np.tile(host, (7, 1)))
    # on a catalog scene: one (6,) per object, in the range of its vertex values
    spec = scenes["hallway"]
    red = true_object_materials(spec, max_edge=0.25)
    assert set(red) == set(spec.objects)
    verts = true_materials(spec, objects=spec.refined(0.25))
    for name, v in red.items():
        assert v.shape == (6,)
        assert np.all(v >= verts[name].min(0) - 1e-12) and np.all(v <= verts[name].max(0) + 1e-12)


def test_10c_region_reduction_cuts_objects_at_their_patches(scenes):
    spec = scenes["hallway"]
    regions = true_region_materials(spec, max_edge=0.25)
    whole = true_object_materials(spec, max_edge=0.25)
    for name, mesh in spec.objects.items():
        parts = {k: r for k, r in regions.items() if k == name or k.startswith(name + "__")}
        # the regions partition the object's surface, with its orientation
        assert sum(r[0].area for r in parts.values()) == pytest.approx(mesh.area, rel=1e-9)
        if len(parts) == 1:   # no patch: the per-object mean
            np.testing.assert_allclose(parts[name][2], whole[name], rtol=1e-12)
        # every face of a region is named that region by the point rule
        for key, (piece, _, _) in parts.items():
            assert set(region_names(spec, name, piece.triangles_center)) == {key}
    patches = {k: r for k, r in regions.items() if "__patch" in k}
    assert patches, "the largest object carries at least one patch"
    for key, (mesh, cls, p) in patches.items():
        name, j = key.split("__patch")
        patch = material_patches(spec, name)[int(j)]
        assert cls == patch.material
        # the region is the patch's half-weight box: each smoothstep factor >= 1/2
        d = np.asarray(mesh.vertices) - patch.center
        for axis, half in ((patch.u, patch.half_u), (patch.v, patch.half_v),
                           (patch.n, patch.half_n)):
            assert np.abs(d @ axis).max() <= half + patch.edge / 2 + 1e-9
        host_normals = spec.objects[name].face_normals
        assert np.all(np.max(mesh.face_normals @ host_normals.T, axis=1) > 0.999)
        # it carries the patch's material: eps'' (spanning orders of magnitude)
        # sits nearer the patch's class than the host's, in log
        lp = np.log(default_vertex_parameters(patch.material, 77e9)[1])
        lh = np.log(default_vertex_parameters(spec.materials[name], 77e9)[1])
        assert abs(np.log(p[1]) - lp) < abs(np.log(p[1]) - lh)


def test_11_lidar_box_room_statistics(room_scan):
    objects, out = room_scan
    assert set(out) == {"room", "cube"}
    room = out["room"]
    st = mesh_statistics(room)
    vis_area = room.metadata["lidar"]["visible_area_m2"]
    assert 18.0 < vis_area < 24.0  # 24 m^2 minus the cube's footprint and shadow
    expected = 2 * vis_area / SPACING ** 2
    assert 0.6 * expected < st["n_triangles"] < 2.0 * expected, (st["n_triangles"], expected)
    assert 0.7 * SPACING < st["median_edge_m"] < 1.4 * SPACING
    assert st["frac_subwavelength"] > 0.001                     # dense patches
    assert room.edges_unique_length.min() < WAVELENGTH_77GHZ
    assert 0.2 < st["normal_dev_median_deg"] < 20.0
    assert st["n_boundary_edges"] > 50                          # holes exist
    assert 0.002 < st["hole_area_fraction"] < 0.1
    # noisy vertices stay near the clean surface (plane distances, not attributes)
    d_room = _box_distance(room.vertices, -1.0, 1.0)
    assert d_room.max() < 4 * SIGMA
    assert d_room.std() > 1e-4                                  # but they are noisy
    cube = out["cube"]
    c_lo, c_hi = np.array([0.3, -0.5, -1.0]), np.array([0.7, -0.1, -0.6])
    assert _box_distance(cube.vertices, c_lo, c_hi).max() < 4 * SIGMA
    # winding follows the clean surface: room normals point inward
    assert np.einsum("ij,ij->i", room.face_normals, room.face_attributes["clean_normal"]).mean() > 0.9
    # pooled statistics over the dict
    assert mesh_statistics(out)["n_triangles"] == st["n_triangles"] + len(cube.faces)


def test_12_lidar_occlusion_shadow(room_scan):
    _, out = room_scan
    room = out["room"]
    cp = room.vertex_attributes["clean_position"]
    on_floor = np.abs(cp[:, 2] + 1.0) < 1e-9
    under_cube = on_floor & (cp[:, 0] > 0.32) & (cp[:, 0] < 0.68) & (cp[:, 1] > -0.48) & (cp[:, 1] < -0.12)
    assert on_floor.sum() > 1000 and under_cube.sum() == 0


def test_13_lidar_deterministic_and_budget():
    objects = _room()
    kw = dict(point_spacing=0.05, hole_fraction=0.02, max_triangles=None)
    a = lidarize(objects, SENSORS, seed=7, **kw)
    b = lidarize(objects, SENSORS, seed=7, **kw)
    c = lidarize(objects, SENSORS, seed=8, **kw)
    for k in a:
        np.testing.assert_array_equal(a[k].vertices, b[k].vertices)
        np.testing.assert_array_equal(a[k].faces, b[k].faces)
    assert not np.array_equal(a["room"].vertices[:100], c["room"].vertices[:100])
    small = lidarize(objects, SENSORS, seed=7, point_spacing=0.01, max_triangles=8000)
    n = mesh_statistics(small)["n_triangles"]
    assert 4000 < n < 8800
    assert small["room"].metadata["lidar"]["point_spacing"] > 0.01


def test_14_lidar_bad_input():
    objects = _room()
    with pytest.raises(InputValueError, match="non-empty"):
        lidarize({}, SENSORS)
    with pytest.raises(InputValueError, match="NaN"):
        lidarize(objects, [[0.0, np.nan, 0.0]])
    with pytest.raises(InputValueError):
        lidarize(objects, np.zeros((2, 2)))
    with pytest.raises(InputValueError):
        lidarize({"x": "not a mesh"}, SENSORS)
    with pytest.raises(InputValueError):
        lidarize(objects, SENSORS, point_spacing=0.0)
    with pytest.raises(InputValueError):
        lidarize(objects, SENSORS, hole_fraction=0.9)
    with pytest.raises(InputValueError, match="visible"):
        lidarize(objects, [[5.0, 5.0, 5.0]])  # outside the room: sees only back faces
    with pytest.raises(InputValueError):
        mesh_statistics({})


def test_15_lidar_of_a_catalog_scene(scenes):
    spec = scenes["building_corner"]
    out = lidarize_scene(spec, seed=0, max_triangles=20_000)
    st = mesh_statistics(out)
    assert 10_000 < st["n_triangles"] < 22_000
    assert {"ground", "facade_a", "facade_b", "door", "windows"} <= set(out)
    assert set(out) <= set(spec.objects)
    assert st["offset_max_m"] < 4 * 0.005
    for name, mesh in out.items():
        np.testing.assert_allclose(np.linalg.norm(mesh.face_attributes["clean_normal"], axis=1), 1.0)

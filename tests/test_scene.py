"""Tests of sionna_mmir.scene: mesh validation, RadarScene, attributes, AD.

Geometry: a 2 m x 2 m plane at z = 0 (two triangles) and a 0.5 m box centred
at (3, 0, 1), written to PLY files with trimesh.
"""
from __future__ import annotations

import numpy as np
import pytest
import trimesh

import sionna_mmir

sionna_mmir.init_backend()

import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402
import sionna.rt  # noqa: E402

from sionna_mmir.errors import ConfigError, InputValueError  # noqa: E402
from sionna_mmir.radio_materials import default_vertex_parameters  # noqa: E402
from sionna_mmir.scene import load_scene, read_mesh  # noqa: E402

PLANE_V = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], dtype=float)
PLANE_F = np.array([[0, 1, 2], [0, 2, 3]])
ORIGIN = np.array([0.2, 0.3, 2.0])
DIRECTION = np.array([0.1, -0.2, -1.0]) / np.linalg.norm([0.1, -0.2, -1.0])


@pytest.fixture()
def ply_files(tmp_path):
    plane = trimesh.Trimesh(vertices=PLANE_V, faces=PLANE_F, process=False)
    box = trimesh.creation.box(extents=[0.5, 0.5, 0.5])
    box.apply_translation([3.0, 0.0, 1.0])
    paths = {"plane": tmp_path / "plane.ply", "box": tmp_path / "box.ply"}
    plane.export(paths["plane"])
    box.export(paths["box"])
    return {k: str(v) for k, v in paths.items()}


@pytest.fixture()
def scene(ply_files):
    return load_scene(ply_files, materials={"box": "metal"})


def _ray():
    return mi.Ray3f(mi.Point3f(*ORIGIN.tolist()), mi.Vector3f(*DIRECTION.tolist()))


def _hit_and_barycentrics(vertices):
    """Closed-form hit of the fixed ray with the plane mesh (NumPy, float64)."""
    for face in PLANE_F:
        p0, p1, p2 = vertices[face]
        # Solve o + t d = p0 + u (p1 - p0) + v (p2 - p0)
        a = np.column_stack([-DIRECTION, p1 - p0, p2 - p0])
        t, u, v = np.linalg.solve(a, ORIGIN - p0)
        if u >= 0 and v >= 0 and u + v <= 1:
            return t, face, np.array([1 - u - v, u, v])
    raise AssertionError("ray misses the plane")


def test_01_scene_is_sionna_scene(scene):
    assert isinstance(scene, sionna.rt.Scene)
    assert set(scene.objects) == {"plane", "box"}
    assert float(scene.frequency[0]) == pytest.approx(77e9)
    keys = set(scene.params())
    assert {"plane.vertex_positions", "plane.vertex_normals", "plane.vertex_materials",
            "box.vertex_materials", "radar.position", "radar.orientation"} <= keys


def test_02_tensor_shapes_and_initial_values(scene):
    obj = scene.mesh_objects["box"]
    nv = obj.vertex_positions.shape[0]
    assert obj.vertex_positions.shape == (nv, 3)
    assert obj.vertex_normals.shape == (nv, 3)
    assert obj.vertex_materials.shape == (nv, 6)
    expected = default_vertex_parameters("metal", 77e9, allow_out_of_band=True)
    np.testing.assert_allclose(obj.vertex_materials.numpy(), np.tile(expected, (nv, 1)), rtol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(obj.vertex_normals.numpy(), axis=1), 1.0, atol=1e-5)
    assert scene.position.shape == (3,) and scene.orientation.shape == (3,)


def test_03_frequency_change_does_not_break(scene):
    scene.frequency = 28e9
    scene.frequency = 77e9
    with pytest.raises(ConfigError):
        scene.frequency = -1.0


def test_04_ray_hits_plane_at_closed_form_distance(scene):
    t_ref, _, _ = _hit_and_barycentrics(PLANE_V)
    si = scene.mi_scene.ray_intersect(_ray())
    assert bool(si.is_valid()[0])
    assert float(si.t[0]) == pytest.approx(t_ref, rel=1e-5)
    assert float(t_ref) == pytest.approx(2.0 / abs(DIRECTION[2]))


def test_05_interpolated_material_is_barycentric(scene):
    obj = scene.mesh_objects["plane"]
    mats = np.arange(24, dtype=float).reshape(4, 6) * 0.5 + 1.0
    obj.vertex_materials = mi.TensorXf(mi.Float(mats.ravel().astype(np.float32)), (4, 6))
    scene.sync()
    _, face, w = _hit_and_barycentrics(PLANE_V)
    si = scene.mi_scene.ray_intersect(_ray())
    rm = scene.get("plane").radio_material
    assert rm is obj.radio_material and rm.vertex_parameters is obj.vertex_materials
    got = np.array([float(v[0]) for v in rm.parameters_at(si.p, si.prim_index)])
    expected = w @ mats[face]
    np.testing.assert_allclose(got, expected, rtol=1e-5)


def test_06_material_gradient_equals_barycentric_weights(scene):
    obj = scene.mesh_objects["plane"]
    dr.enable_grad(obj.vertex_materials)
    scene.sync()
    si = scene.mi_scene.ray_intersect(_ray())
    value = obj.radio_material.parameters_at(si.p, si.prim_index)
    dr.backward(value[1])  # eps_imag
    grad = dr.grad(obj.vertex_materials).numpy()
    _, face, w = _hit_and_barycentrics(PLANE_V)
    expected = np.zeros((4, 6))
    expected[face, 1] = w
    np.testing.assert_allclose(grad, expected, atol=1e-6)


def test_07_moving_vertices_moves_hit(scene):
    obj = scene.mesh_objects["plane"]
    moved = PLANE_V.copy()
    moved[:, 2] += 0.5
    obj.vertex_positions = mi.TensorXf(mi.Float(moved.ravel().astype(np.float32)), (4, 3))
    scene.sync()
    t_ref, _, _ = _hit_and_barycentrics(moved)
    si = scene.mi_scene.ray_intersect(_ray())
    assert float(si.t[0]) == pytest.approx(t_ref, rel=1e-5)
    assert float(t_ref) == pytest.approx(1.5 / abs(DIRECTION[2]))


def _distance(scene, positions):
    scene.mesh_objects["plane"].vertex_positions = mi.TensorXf(
        mi.Float(positions.ravel().astype(np.float32)), positions.shape)
    scene.sync()
    return float(scene.mi_scene.ray_intersect(_ray()).t[0])


def test_08_distance_gradient_wrt_vertex_z_ad_vs_fd(scene):
    obj = scene.mesh_objects["plane"]
    dr.enable_grad(obj.vertex_positions)
    scene.sync()
    si = scene.mi_scene.ray_intersect(_ray(), ray_flags=mi.RayFlags.All, coherent=False)
    dr.backward(si.t)
    grad_z = dr.grad(obj.vertex_positions).numpy()[:, 2]
    _, face, w = _hit_and_barycentrics(PLANE_V)
    closed = np.zeros(4)
    closed[face] = -w / abs(DIRECTION[2])  # dt/dz_i for a z = 0 plane
    np.testing.assert_allclose(grad_z, closed, atol=1e-5)
    h = 1e-2
    for i in face:
        plus, minus = PLANE_V.copy(), PLANE_V.copy()
        plus[i, 2] += h
        minus[i, 2] -= h
        fd = (_distance(scene, plus) - _distance(scene, minus)) / (2 * h)
        assert abs(grad_z[i] - fd) <= 0.02 * abs(fd), (i, grad_z[i], fd)


def _write(path, text):
    path.write_text(text)
    return str(path)


def test_09_empty_mesh_raises_naming_file(tmp_path):
    path = _write(tmp_path / "empty.ply", "ply\nformat ascii 1.0\nelement vertex 3\n"
                  "property float x\nproperty float y\nproperty float z\n"
                  "element face 0\nproperty list uchar int vertex_indices\nend_header\n"
                  "0 0 0\n1 0 0\n0 1 0\n")
    with pytest.raises(InputValueError, match="empty.ply.*no faces"):
        load_scene(path)


def test_10_nan_vertices_raise_naming_file(tmp_path):
    path = tmp_path / "nan.ply"
    v = PLANE_V.copy()
    v[2, 0] = np.nan
    trimesh.Trimesh(vertices=v, faces=PLANE_F, process=False).export(path)
    with pytest.raises(InputValueError, match="nan.ply.*NaN"):
        load_scene(str(path))


def test_11_degenerate_triangles_raise_or_drop(tmp_path):
    v = np.vstack([PLANE_V, [[2, 0, 0], [3, 0, 0], [4, 0, 0]]])
    f = np.vstack([PLANE_F, [[4, 5, 6]]])
    path = tmp_path / "degen.ply"
    trimesh.Trimesh(vertices=v, faces=f, process=False).export(path)
    with pytest.raises(InputValueError, match=r"degen.ply: 1 degenerate.*\[2\]"):
        load_scene(str(path))
    data = read_mesh(str(path), drop_degenerate=True)
    assert data.faces.shape == (2, 3)
    sc = load_scene(str(path), drop_degenerate=True)
    assert sc.mesh_objects["mesh"].faces.shape == (2, 3)


def test_12_out_of_range_faces_raise_naming_file(tmp_path):
    path = _write(tmp_path / "oob.ply", "ply\nformat ascii 1.0\nelement vertex 3\n"
                  "property float x\nproperty float y\nproperty float z\n"
                  "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
                  "0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n")
    with pytest.raises(InputValueError, match="oob.ply.*out of range"):
        load_scene(path)
    with pytest.raises(InputValueError, match="<trimesh>.*out of range"):
        read_mesh(trimesh.Trimesh(vertices=PLANE_V, faces=[[0, 1, 9]], process=False))


def test_13_normal_attribute_gradient_ad_vs_fd(scene):
    """The solver's shading normal at a hit: AD w.r.t. vertex normals vs central differences."""
    obj = scene.mesh_objects["plane"]
    base = obj.vertex_normals.numpy().copy()

    from sionna_mmir.paths.geometry import SceneGeometry

    def value(normals, grad=False):
        obj.vertex_normals = mi.TensorXf(mi.Float(normals.ravel().astype(np.float32)), normals.shape)
        if grad:
            dr.enable_grad(obj.vertex_normals)
        scene.sync()
        geo = SceneGeometry(scene)
        valid, o, face, u, v = geo.trace(_ray().o, _ray().d)
        return geo.interaction(valid, o, face, u, v).n      # unit shading normal (AD)

    n = value(base, grad=True)
    dr.backward(n.x)
    ad = dr.grad(obj.vertex_normals).numpy()[:, 0]
    h = 1e-2
    for v in range(4):
        p, m = base.copy(), base.copy()
        p[v, 0] += h
        m[v, 0] -= h
        fd = (float(value(p).x[0]) - float(value(m).x[0])) / (2 * h)
        assert abs(ad[v] - fd) <= 0.02 * max(abs(fd), 1e-3), (v, ad[v], fd)
    value(base)


def test_14_given_vertex_normals_are_the_shading_normals(tmp_path):
    """A mesh's own normals (Trimesh ``vertex_normals=`` or a PLY's nx ny nz)
    are used, normalised; without them trimesh's face-averaged normals
    (here the plane's +z)."""
    tilted = np.tile([0.0, 0.6, 0.8], (len(PLANE_V), 1)) * 2.0        # length 2
    given = trimesh.Trimesh(vertices=PLANE_V, faces=PLANE_F, vertex_normals=tilted, process=False)
    plain = trimesh.Trimesh(vertices=PLANE_V, faces=PLANE_F, process=False)
    path = tmp_path / "tilted.ply"
    given.export(path)
    for mesh, expected in ((given, [0.0, 0.6, 0.8]), (str(path), [0.0, 0.6, 0.8]),
                           (plain, [0.0, 0.0, 1.0])):
        n = np.array(load_scene({"plate": mesh}).mesh_objects["plate"].vertex_normals)
        assert np.allclose(n, expected, atol=1e-6), (mesh, n)


@pytest.mark.parametrize("bad", ["nan", "zero"])
def test_15_bad_given_normals_raise_naming_the_mesh(bad):
    n = np.tile([0.0, 0.0, 1.0], (len(PLANE_V), 1))
    n[1] = np.nan if bad == "nan" else 0.0
    mesh = trimesh.Trimesh(vertices=PLANE_V, faces=PLANE_F, vertex_normals=n, process=False)
    with pytest.raises(InputValueError, match="plate.*vertex normals are NaN/Inf or zero"):
        load_scene({"plate": mesh})


def test_16_cached_normals_of_an_unused_vertex_do_not_raise():
    """Normals trimesh computed and cached (someone read ``vertex_normals``)
    count as given; an unreferenced vertex (zero normal) is not an error."""
    v = np.vstack([PLANE_V, [[5.0, 5.0, 5.0]]])
    mesh = trimesh.Trimesh(vertices=v, faces=PLANE_F, process=False)
    _ = mesh.vertex_normals                              # populates trimesh's cache
    n = np.array(load_scene({"plate": mesh}).mesh_objects["plate"].vertex_normals)
    assert np.allclose(n[:4], [0.0, 0.0, 1.0], atol=1e-6)

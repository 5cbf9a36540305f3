"""Tests of sionna_mmir.paths.sms: specular manifold sampling and IFT gradients.

Geometry (built with trimesh, no files):

* plate: 1 m x 1 m at z = 0 split into 1 cm right triangles (20 000 faces),
  all vertex normals +z, so shading and geometric normals agree;
* sphere: icosphere of radius 0.5 m (5 subdivisions, ~1.7 cm edges) with
  trimesh's smooth vertex normals.

Endpoints are ~1 m away, so every triangle is much smaller than the distances
and the image method on the seed triangle alone cannot find the reflection.
"""
from __future__ import annotations

import time

import numpy as np
import pytest
import trimesh
from scipy.optimize import brentq

import sionna_mmir

sionna_mmir.init_backend()

import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402

from sionna_mmir.errors import InputValueError  # noqa: E402
from sionna_mmir.paths import sms  # noqa: E402
from sionna_mmir.paths.sms import NO_OBJECT, solve_specular, specular_point_ad  # noqa: E402
from sionna_mmir.scene import load_scene  # noqa: E402

CELL = 0.01
HALF = 0.5
SPHERE_R = 0.5


def _plate(x0=-HALF, x1=HALF, y0=-HALF, y1=HALF, cell=CELL) -> trimesh.Trimesh:
    nx, ny = int(round((x1 - x0) / cell)), int(round((y1 - y0) / cell))
    xs, ys = np.linspace(x0, x1, nx + 1), np.linspace(y0, y1, ny + 1)
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    verts = np.c_[gx.ravel(), gy.ravel(), np.zeros(gx.size)]
    i, j = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    v00 = (i * (ny + 1) + j).ravel()
    v10, v11, v01 = v00 + ny + 1, v00 + ny + 2, v00 + 1
    faces = np.concatenate([np.c_[v00, v10, v11], np.c_[v00, v11, v01]])
    return trimesh.Trimesh(verts, faces, process=False)


@pytest.fixture(scope="module")
def plate_scene():
    return load_scene({"plate": _plate()})


@pytest.fixture(scope="module")
def sphere_scene():
    return load_scene({"sphere": trimesh.creation.icosphere(subdivisions=5, radius=SPHERE_R)})


def _p(v) -> mi.Point3f:
    v = np.atleast_2d(np.asarray(v, dtype=np.float32))
    return mi.Point3f(mi.Float(v[:, 0]), mi.Float(v[:, 1]), mi.Float(v[:, 2]))


def _np(p) -> np.ndarray:
    return np.stack([np.asarray(p.x), np.asarray(p.y), np.asarray(p.z)], axis=-1).astype(np.float64)


def _mirror_point(a, b):
    """Specular point on the plane z = 0 (image method, float64)."""
    am = np.array([a[0], a[1], -a[2]])
    t = am[2] / (am[2] - b[2])
    return am + (b - am) * t


def _plate_endpoints():
    """a, b whose mirror point is the centroid of a plate triangle (well inside it)."""
    x = np.array([0.113, -0.077, 0.0])
    cell = np.floor(x[:2] / CELL) * CELL
    x[:2] = cell + CELL * np.array([2.0, 1.0]) / 3.0  # centroid of the lower-right triangle
    a = np.array([-0.3, 0.1, 1.0])
    d = x - a * np.array([1, 1, -1])
    b = x + 0.7 * d / np.linalg.norm(d)
    return a, b, x


def _sphere_specular(a, b, r=SPHERE_R):
    """Specular point of the true sphere (centre 0) by 1-D root finding (float64)."""
    e1 = a / np.linalg.norm(a)
    e2 = b - e1 * (b @ e1)
    e2 /= np.linalg.norm(e2)
    phi_b = np.arctan2(b @ e2, b @ e1)

    def g(phi):
        x = r * (np.cos(phi) * e1 + np.sin(phi) * e2)
        wa, wb = (a - x) / np.linalg.norm(a - x), (b - x) / np.linalg.norm(b - x)
        tang = -np.sin(phi) * e1 + np.cos(phi) * e2
        return (wa + wb) @ tang

    phi = brentq(g, 0.0, phi_b, xtol=1e-14)
    return r * (np.cos(phi) * e1 + np.sin(phi) * e2)


def _reflection_angle(scene, sol, a, b, name):
    """Angle between h and the interpolated shading normal, recomputed in float64."""
    obj = scene.mesh_objects[name]
    pos, nor = obj.vertex_positions.numpy().astype(np.float64), obj.vertex_normals.numpy()
    face = obj.faces[np.asarray(sol.prim_index)]
    u, v = np.asarray(sol.bary.x, dtype=np.float64), np.asarray(sol.bary.y, dtype=np.float64)
    w = np.stack([1 - u - v, u, v], axis=-1)[..., None]
    x = (w * pos[face]).sum(axis=1)
    n = (w * nor[face]).sum(axis=1)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    wa = (a - x) / np.linalg.norm(a - x, axis=1, keepdims=True)
    wb = (b - x) / np.linalg.norm(b - x, axis=1, keepdims=True)
    h = wa + wb
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    return np.arccos(np.clip((h * n).sum(axis=1), -1, 1)), x


def _barycentric_in_face(p, tri):
    e1, e2 = tri[1] - tri[0], tri[2] - tri[0]
    m = np.array([[e1 @ e1, e1 @ e2], [e1 @ e2, e2 @ e2]])
    u, v = np.linalg.solve(m, [(p - tri[0]) @ e1, (p - tri[0]) @ e2])
    return u, v


def test_01_plate_solution_is_mirror_point_and_walk_crosses_triangles(plate_scene):
    a, b, x_ref = _plate_endpoints()
    np.testing.assert_allclose(_mirror_point(a, b), x_ref, atol=1e-12)
    seed = x_ref + np.array([0.05, 0.03, 0.0])
    t0 = time.perf_counter()
    sol = solve_specular(plate_scene, a, b, seed)
    elapsed = time.perf_counter() - t0
    assert bool(sol.valid[0])
    np.testing.assert_allclose(_np(sol.position)[0], x_ref, atol=1e-4)
    assert float(sol.error[0]) < 1e-5
    assert int(sol.iterations[0]) <= 10
    # The seed's triangle: its image-method point (same plane) lies outside it.
    ray = mi.Ray3f(_p(a), mi.Vector3f(_p(seed - a)) / float(np.linalg.norm(seed - a)))
    pi = plate_scene.mi_scene.ray_intersect_preliminary(ray)
    seed_prim = int(pi.prim_index[0])
    obj = plate_scene.mesh_objects["plate"]
    tri = obj.vertex_positions.numpy()[obj.faces[seed_prim]].astype(np.float64)
    u, v = _barycentric_in_face(x_ref, tri)
    assert min(u, v, 1 - u - v) < -1.0, (u, v)  # many triangles away
    assert int(sol.prim_index[0]) != seed_prim
    u, v = float(sol.bary.x[0]), float(sol.bary.y[0])
    assert min(u, v, 1 - u - v) > 0.2  # landed well inside the right triangle
    assert elapsed < 5.0
    # The AD re-evaluation reproduces the solution (one more Newton step).
    x_ad, n_ad = specular_point_ad(plate_scene, sol, _p(a), _p(b))
    np.testing.assert_allclose(_np(x_ad)[0], _np(sol.position)[0], atol=1e-6)
    np.testing.assert_allclose(_np(n_ad)[0], [0.0, 0.0, 1.0], atol=1e-6)


def test_02_sphere_reflection_law_and_true_sphere_point(sphere_scene):
    a = np.array([1.5, 0.3, 0.4])
    b = np.array([0.8, -1.2, 0.5])
    x_true = _sphere_specular(a, b)
    seeds = x_true + np.array([[0.0, 0.0, 0.0], [0.04, 0.03, -0.03], [-0.05, 0.02, 0.04],
                               [0.02, -0.06, 0.0]])
    sol = solve_specular(sphere_scene, np.tile(a, (4, 1)), np.tile(b, (4, 1)), seeds)
    assert np.asarray(sol.valid).all()
    angle, x64 = _reflection_angle(sphere_scene, sol, a, b, "sphere")
    assert angle.max() < 1e-4, angle
    x = _np(sol.position)
    np.testing.assert_allclose(x, x64, atol=1e-6)
    # Tessellation error: ~1.7 cm edges on R = 0.5 m (sagitta ~7e-5 m, plus
    # the interpolated normals' deviation from radial; measured ~9e-5 m).
    err = np.linalg.norm(x - x_true, axis=1)
    assert err.max() < 3e-4, err
    # All seeds reach the same point (same triangle).
    assert np.ptp(x, axis=0).max() < 1e-5
    n = _np(sol.normal)
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-5)


def test_03_convergence_from_distant_seeds_vectorised(plate_scene):
    a, b, x_ref = _plate_endpoints()
    rng = np.random.default_rng(3)
    ang = rng.uniform(0, 2 * np.pi, 16)
    rad = rng.uniform(0.03, 0.15, 16)
    seeds = x_ref + np.c_[rad * np.cos(ang), rad * np.sin(ang), np.zeros(16)]
    sol = solve_specular(plate_scene, a, b, seeds)  # a, b of size 1 broadcast
    assert np.asarray(sol.valid).all()
    np.testing.assert_allclose(_np(sol.position), np.tile(x_ref, (16, 1)), atol=1e-4)
    assert np.asarray(sol.iterations).max() <= 15
    # Seeds off the surface (above and below) project onto it and converge too.
    off = np.array([x_ref + [0.05, 0.0, 0.02], x_ref + [-0.04, 0.04, -0.03]])
    sol = solve_specular(plate_scene, a, b, off)
    assert np.asarray(sol.valid).all()
    np.testing.assert_allclose(_np(sol.position), np.tile(x_ref, (2, 1)), atol=1e-4)
    # A tight step limit still converges, in more (shorter) steps.
    far = x_ref + np.array([[0.15, 0.0, 0.0]])
    free = solve_specular(plate_scene, a, b, far)
    slow = solve_specular(plate_scene, a, b, far, step_limit=0.01)
    assert bool(free.valid[0]) and bool(slow.valid[0])
    np.testing.assert_allclose(_np(slow.position)[0], x_ref, atol=1e-4)
    assert int(slow.iterations[0]) >= 15 > int(free.iterations[0])


def test_04_invalid_when_occluded_behind_or_off_the_plate():
    a, b, x_ref = _plate_endpoints()
    blocker = trimesh.creation.box(extents=[0.04, 0.04, 0.04])
    mid = 0.5 * (a + x_ref)
    blocker.apply_translation(mid)
    scene = load_scene({"plate": _plate(), "blocker": blocker})
    seed = x_ref + np.array([0.04, -0.03, 0.0])
    sol = solve_specular(scene, a, b, seed)
    assert float(sol.error[0]) < 1e-5  # converged on the plate...
    np.testing.assert_allclose(_np(sol.position)[0], x_ref, atol=1e-4)
    assert not bool(sol.valid[0])  # ...but the path to a is blocked
    # Same query without the blocker is valid.
    free = load_scene({"plate": _plate()})
    assert bool(solve_specular(free, a, b, seed).valid[0])
    # b behind the plate, and a reflection point beyond the plate's edge.
    b_behind = b * np.array([1, 1, -1])
    a2, b2 = np.array([0.3, 0.0, 0.3]), np.array([1.5, 0.0, 0.3])  # mirror point x = 0.9
    sol = solve_specular(free, np.stack([a, a2]), np.stack([b_behind, b2]),
                         np.stack([x_ref, [0.45, 0.0, 0.0]]))
    assert not np.asarray(sol.valid).any()
    # Invalid lanes: zeros from specular_point_ad, and no NaN in the gradients.
    obj = free.mesh_objects["plate"]
    dr.enable_grad(obj.vertex_positions)
    x, n = specular_point_ad(free, sol, _p(np.stack([a, a2])), _p(np.stack([b_behind, b2])))
    assert not _np(x).any() and not _np(n).any()
    dr.backward(dr.sum(x.x + x.y + x.z + n.z))
    assert np.isfinite(dr.grad(obj.vertex_positions).numpy()).all()
    dr.disable_grad(obj.vertex_positions)


def test_05_shape_pointer_mapping_and_walk_across_objects():
    left, right = _plate(-HALF, 0.0), _plate(0.0, HALF)
    scene = load_scene({"left": left, "right": right})
    assert sms.object_names(scene) == ["left", "right"]
    a, b, x_ref = _plate_endpoints()  # x_ref has x > 0: on "right"
    seed = np.array([-0.05, x_ref[1], 0.0])  # on "left"
    sol = solve_specular(scene, a, b, seed)
    assert bool(sol.valid[0])
    np.testing.assert_allclose(_np(sol.position)[0], x_ref, atol=1e-4)
    assert int(sol.object_id[0]) == 1
    assert bool((sol.shape == mi.ShapePtr(scene.mesh("right")))[0])
    ids = dr.reinterpret_array(mi.UInt32, sol.shape)
    assert int(ids[0]) == int(dr.reinterpret_array(mi.UInt32, mi.ShapePtr(scene.mesh("right")))[0])
    # A query that misses everything: no object, null shape.
    sol = solve_specular(scene, [5.0, 5.0, 1.0], [5.1, 5.0, 1.0], [5.0, 5.0, 3.0])
    assert not bool(sol.valid[0])
    assert int(sol.object_id[0]) == NO_OBJECT
    assert int(dr.reinterpret_array(mi.UInt32, sol.shape)[0]) == 0
    # The AD re-evaluation gathers from the right object's tensors.
    sol = solve_specular(scene, a, b, seed)
    x, _ = specular_point_ad(scene, sol, _p(a), _p(b))
    np.testing.assert_allclose(_np(x)[0], x_ref, atol=1e-4)


def test_06_analytic_jacobian_matches_finite_differences(sphere_scene):
    a = np.array([1.5, 0.3, 0.4])
    b = np.array([0.8, -1.2, 0.5])
    sol = solve_specular(sphere_scene, a, b, _sphere_specular(a, b))
    tables = sms._Tables(sphere_scene, detach=True)
    ps, ns = tables.triangle(sol.object_id, sol.prim_index)
    u0, v0 = float(sol.bary.x[0]) - 0.2, float(sol.bary.y[0]) + 0.1  # off the solution
    args = (_p(a), _p(b))
    _, _, _, _, jac, _, _ = sms._constraint(ps, ns, mi.Float(u0), mi.Float(v0), *args, True)
    scale = max(abs(float(jac[i][k][0])) for i in range(2) for k in range(2))
    h = 0.05  # barycentric units (C is smooth; float32 needs a large step)
    for k, (du, dv) in enumerate(((h, 0.0), (0.0, h))):
        cp = sms._constraint(ps, ns, mi.Float(u0 + du), mi.Float(v0 + dv), *args, False)[3]
        cm = sms._constraint(ps, ns, mi.Float(u0 - du), mi.Float(v0 - dv), *args, False)[3]
        for i in range(2):
            fd = (float(cp[i][0]) - float(cm[i][0])) / (2 * h)
            an = float(jac[i][k][0])
            assert abs(an - fd) <= 2e-3 * scale, (i, k, an, fd, scale)


# ---------------------------------------------------------------- gradients
def _set(scene, name, key, values):
    setattr(scene.mesh_objects[name], key,
            mi.TensorXf(mi.Float(values.ravel().astype(np.float32)), values.shape))
    scene.sync()


def _x_of(scene, a, b, seed):
    """Re-solved reflection point (plus one Newton polish step), float64."""
    sol = solve_specular(scene, a, b, seed, tol=1e-6)
    assert bool(sol.valid[0])
    x, _ = specular_point_ad(scene, sol, _p(a), _p(b))
    return _np(x)[0], int(sol.prim_index[0])


def _forward_grad(scene, name, key, index, a, b, sol):
    """d x / d (tensor[index]) by forward-mode AD through specular_point_ad."""
    obj = scene.mesh_objects[name]
    tensor = getattr(obj, key)
    dr.enable_grad(tensor)
    seed_grad = np.zeros(tensor.shape, dtype=np.float32)
    seed_grad[index] = 1.0
    dr.set_grad(tensor, mi.TensorXf(mi.Float(seed_grad.ravel()), tensor.shape))
    x, _ = specular_point_ad(scene, sol, _p(a), _p(b))
    dr.forward_to(x)
    g = _np(dr.grad(x))[0]
    dr.disable_grad(tensor)
    return g


def _fd_tensor(scene, name, key, index, a, b, seed, h):
    base = getattr(scene.mesh_objects[name], key).numpy().copy()
    out, prims = [], []
    for sign in (1, -1):
        vals = base.copy()
        vals[index] += sign * h
        _set(scene, name, key, vals)
        x, prim = _x_of(scene, a, b, seed)
        out.append(x)
        prims.append(prim)
    _set(scene, name, key, base)
    return (out[0] - out[1]) / (2 * h), prims


def _assert_close_vec(ad, fd, rel=0.01):
    assert np.linalg.norm(ad - fd) <= rel * np.linalg.norm(fd) + 1e-6, (ad, fd)


@pytest.mark.parametrize("case", ["plate", "sphere"])
def test_07_gradient_wrt_vertex_position_and_normal_ad_vs_fd(case, plate_scene, sphere_scene):
    if case == "plate":
        scene, name = plate_scene, "plate"
        a, b, x_ref = _plate_endpoints()
    else:
        scene, name = sphere_scene, "sphere"
        a, b = np.array([1.5, 0.3, 0.4]), np.array([0.8, -1.2, 0.5])
        x_ref = _sphere_specular(a, b)
    sol = solve_specular(scene, a, b, x_ref, tol=1e-6)
    assert bool(sol.valid[0])
    prim = int(sol.prim_index[0])
    face = scene.mesh_objects[name].faces[prim]
    w = np.array([1 - float(sol.bary.x[0]) - float(sol.bary.y[0]),
                  float(sol.bary.x[0]), float(sol.bary.y[0])])
    vert = int(face[int(np.argmax(w))])
    seed = _np(sol.position)[0]
    # Vertex position, z component (along the normal for the plate).
    ad = _forward_grad(scene, name, "vertex_positions", (vert, 2), a, b, sol)
    fd, prims = _fd_tensor(scene, name, "vertex_positions", (vert, 2), a, b, seed, 1e-3)
    assert prims == [prim, prim]
    _assert_close_vec(ad, fd)
    assert np.linalg.norm(fd) > 0.1
    # Vertex normal, x component.
    ad = _forward_grad(scene, name, "vertex_normals", (vert, 0), a, b, sol)
    fd, prims = _fd_tensor(scene, name, "vertex_normals", (vert, 0), a, b, seed, 1e-3)
    assert prims == [prim, prim]
    _assert_close_vec(ad, fd)
    assert np.linalg.norm(fd) > 0.05


@pytest.mark.parametrize("case", ["plate", "sphere"])
def test_08_gradient_wrt_endpoint_a_and_path_length(case, plate_scene, sphere_scene):
    if case == "plate":
        scene = plate_scene
        a, b, x_ref = _plate_endpoints()
    else:
        scene = sphere_scene
        a, b = np.array([1.5, 0.3, 0.4]), np.array([0.8, -1.2, 0.5])
        x_ref = _sphere_specular(a, b)
    sol = solve_specular(scene, a, b, x_ref, tol=1e-6)
    seed = _np(sol.position)[0]
    h = 1e-3
    for k in range(3):
        ad = []
        for want_length in (False, True):  # forward_to(x, length) would clear x's grad
            ap = _p(a)
            dr.enable_grad(ap)
            dr.set_grad(ap, mi.Vector3f(*[1.0 if i == k else 0.0 for i in range(3)]))
            x, _ = specular_point_ad(scene, sol, ap, _p(b))
            out = dr.norm(ap - x) + dr.norm(x - _p(b)) if want_length else x
            dr.forward_to(out)
            ad.append(dr.grad(out))
        ad_x, ad_len = _np(ad[0])[0], float(ad[1][0])
        xs, lens = [], []
        for sign in (1, -1):
            a2 = a.copy()
            a2[k] += sign * h
            x2, _ = _x_of(scene, a2, b, seed)
            xs.append(x2)
            lens.append(np.linalg.norm(a2 - x2) + np.linalg.norm(x2 - b))
        fd_x = (xs[0] - xs[1]) / (2 * h)
        fd_len = (lens[0] - lens[1]) / (2 * h)
        _assert_close_vec(ad_x, fd_x)
        assert abs(ad_len - fd_len) <= 0.02 * abs(fd_len) + 1e-3, (k, ad_len, fd_len)
        if case == "plate":
            # Shading normal = geometric normal: L is stationary in x, so
            # dL/da is the unit direction from x to a.
            direction = (a - seed) / np.linalg.norm(a - seed)
            assert abs(ad_len - direction[k]) < 1e-4, (k, ad_len, direction[k])


def test_09_bad_inputs_raise():
    scene = load_scene({"plate": _plate(cell=0.1)})
    a, b, x_ref = _plate_endpoints()
    with pytest.raises(InputValueError, match="a: contains NaN"):
        solve_specular(scene, [np.nan, 0.0, 1.0], b, x_ref)
    with pytest.raises(InputValueError, match="b: contains NaN"):
        solve_specular(scene, _p(a), mi.Point3f(0.0, float("inf"), 1.0), x_ref)
    with pytest.raises(InputValueError, match="seed"):
        solve_specular(scene, a, b, np.zeros((2, 2)))
    with pytest.raises(InputValueError, match="sizes"):
        solve_specular(scene, np.tile(a, (2, 1)), np.tile(b, (3, 1)), x_ref)
    with pytest.raises(InputValueError, match="tol"):
        solve_specular(scene, a, b, x_ref, tol=0.0)

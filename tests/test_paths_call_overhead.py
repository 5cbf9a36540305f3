"""Per-call work of ``RadarPathSolver`` that is cached or evaluated once (``paths.geometry``).

``SceneGeometry.validate`` skips tensors that passed and are unchanged (same
Dr.Jit variable), and the face / shape tables are built once per scene.  Every
way of changing a tensor must still be checked again, and the cached tables
must give the same paths as fresh ones.
"""
from __future__ import annotations

import numpy as np
import pytest

import sionna_mmir  # noqa: F401
from sionna_mmir.errors import InputValueError
from sionna_mmir.radar import RadarConfig
from sionna_mmir.scene import load_scene

from helpers import square_plate

from sionna_mmir.paths import RadarPathSolver  # noqa: E402
from sionna_mmir.paths.geometry import SceneGeometry  # noqa: E402

import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402


def _scene():
    return load_scene({"p": square_plate([2, 0, 0], 0.5, subdiv=1)}, radar=RadarConfig.dense(1, 1))


def _solve(scene):
    return RadarPathSolver()(scene, num_rays=200, max_depth=1, seed=3)


def test_unchanged_tensors_are_checked_once_and_changes_are_checked_again():
    scene = _scene()
    obj = scene.mesh_objects["p"]
    _solve(scene)
    passed = obj._validated
    assert set(passed) == {"vertex_positions", "vertex_normals", "vertex_materials"}
    tokens = dict(passed)
    _solve(scene)                                       # nothing changed: same records
    assert all(obj._validated[k] is tokens[k] for k in tokens)

    # in place through Dr.Jit indexing: a new variable, checked again
    good = np.array(obj.vertex_materials)
    obj.vertex_materials[1, 2] = -1e-3
    with pytest.raises(InputValueError, match="sigma_h < 0"):
        _solve(scene)
    obj.vertex_materials = mi.TensorXf(good)
    _solve(scene)

    # in place through dr.scatter on the tensor's array
    dr.scatter(obj.vertex_materials.array, mi.Float(float("nan")), mi.UInt32(0))
    with pytest.raises(InputValueError, match="NaN"):
        _solve(scene)
    obj.vertex_materials = mi.TensorXf(good)
    _solve(scene)

    # normals: a zero normal set in place is caught
    nrm = np.array(obj.vertex_normals)
    for c in range(3):
        obj.vertex_normals[0, c] = 0.0
    with pytest.raises(InputValueError, match="zero-length"):
        _solve(scene)
    obj.vertex_normals = mi.TensorXf(nrm)

    # positions: a new tensor with Inf
    pos = np.array(obj.vertex_positions)
    bad = pos.copy()
    bad[1, 0] = np.inf
    obj.vertex_positions = mi.TensorXf(bad)
    with pytest.raises(InputValueError, match="vertex_positions"):
        _solve(scene)
    obj.vertex_positions = mi.TensorXf(pos)
    _solve(scene)


def test_gradient_enabled_tensors_still_validated_after_change():
    scene = _scene()
    obj = scene.mesh_objects["p"]
    dr.enable_grad(obj.vertex_materials)
    _solve(scene)
    m = obj.vertex_materials * 1.0
    m[0, 0] = 0.5                                       # eps_real < 1, on an AD expression
    obj.vertex_materials = m
    with pytest.raises(InputValueError, match="eps_real < 1"):
        _solve(scene)


def test_cached_tables_match_fresh_ones_and_follow_new_scenes():
    scene = _scene()
    g1, g2 = SceneGeometry(scene), SceneGeometry(scene)
    assert g1.faces is g2.faces and g1._shape_table is g2._shape_table
    faces = np.asarray(scene.mesh_objects["p"].faces, dtype=np.uint32).ravel()
    assert np.array_equal(np.asarray(g1.faces), faces)
    assert g1.num_faces == len(scene.mesh_objects["p"].faces)
    a = _solve(scene)
    b = _solve(scene)
    assert np.array_equal(a.numpy()[0], b.numpy()[0])
    # another scene never reuses this scene's tables
    other = load_scene({"q": square_plate([3, 0, 0], 0.5, subdiv=2)}, radar=RadarConfig.dense(1, 1))
    g3 = SceneGeometry(other)
    assert g3.faces is not g1.faces and g3.num_faces == len(other.mesh_objects["q"].faces)


def test_replayed_samples_are_frozen_at_every_depth():
    """``samples=`` replays the recorded hits of *every* depth and the frozen
    values (visibility included): moving a vertex and rebuilding Mitsuba's
    acceleration structure (``scene.sync()``) must not change what is replayed,
    and central differences of the replayed estimator converge to AD.

    (Lazy Dr.Jit expressions for the hits of depths 2 and 3 would re-run the
    ray tracing against the *current* scene on replay.)
    """
    import trimesh

    floor = trimesh.Trimesh(np.array([[0.5, -1, -0.4], [3, -1, -0.4], [3, 1, -0.4], [0.5, 1, -0.4]]),
                            [[0, 2, 1], [0, 3, 2]], process=False).subdivide().subdivide()
    radar = RadarConfig.awr1843()
    scene = load_scene({"wall": square_plate([1.6, 0.0, 0.0], 0.8, yaw_deg=8.0, subdiv=2),
                        "floor": floor}, radar=radar)
    metal = np.array([1.0, 1e6, 1e-5, 1e-2, 0.9, 0.01], np.float32)
    mat = np.array([4.0, 0.05, 3e-4, 5e-3, 0.5, 8e-3], np.float32)
    for name, m in (("wall", mat), ("floor", metal)):
        obj = scene.mesh_objects[name]
        obj.vertex_materials = mi.TensorXf(np.tile(m, (obj.vertex_positions.shape[0], 1)))
    scene.sync()
    opts = dict(num_rays=8000, max_depth=3, seed=5)
    solver = RadarPathSolver()
    samples = solver(scene, **opts).samples
    assert len(samples[0]) == 3                          # one recorded trace per depth

    def power():
        return solver(scene, samples=list(samples), **opts).power()

    obj = scene.mesh_objects["floor"]
    base = np.array(obj.vertex_positions, dtype=np.float64)
    fv = int(np.argmin(np.linalg.norm(base - [1.75, 0.0, -0.4], axis=1)))
    t = mi.TensorXf(base.astype(np.float32))
    dr.enable_grad(t)
    obj.vertex_positions = t
    y = power()
    dr.backward(y)
    ad = float(np.asarray(dr.grad(t))[fv, 2])
    step = 1e-4

    def at(dz, sync):
        b = base.copy()
        b[fv, 2] += dz
        obj.vertex_positions = mi.TensorXf(b.astype(np.float32))
        if sync:
            scene.sync()
        return float(np.asarray(power())[0])

    moved = [at(s * step, sync=True) for s in (1, -1)]
    unsynced = [at(s * step, sync=False) for s in (1, -1)]
    obj.vertex_positions = mi.TensorXf(base.astype(np.float32))
    scene.sync()
    assert np.isfinite(moved).all() and moved == unsynced   # the BVH plays no part in a replay
    fd = (moved[0] - moved[1]) / (2 * step)
    assert np.isfinite(ad) and ad != 0
    assert abs(ad - fd) <= 0.02 * abs(fd), (ad, fd)

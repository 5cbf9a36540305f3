"""sionna_mmir.scaffold.prepare_scaffold: denoise -> snap planes -> shading, in one call."""
from __future__ import annotations

import numpy as np
import pytest
import trimesh

from sionna_mmir.errors import InputValueError
from sionna_mmir.scaffold import prepare_scaffold, snap_planes

HALF = np.array([1.0, 0.5, 0.4])


def _scan(sigma=0.8e-3, seed=0):
    box = trimesh.creation.box(extents=2 * HALF)
    for _ in range(5):
        box = box.subdivide()
    rng = np.random.default_rng(seed)
    return trimesh.Trimesh(np.asarray(box.vertices) + rng.normal(0, sigma, box.vertices.shape),
                           box.faces, process=False)


def _rms_to_box(mesh):
    v = np.asarray(mesh.vertices)
    return float(np.sqrt(np.mean(np.min(np.abs(np.abs(v) - HALF), axis=1) ** 2)))


def test_01_each_step_brings_a_noisy_box_closer_to_its_faces():
    """0.8 mm noise: the MLS denoiser reduces the rms distance to the analytic
    faces, snapping the planes reduces it by another 3x at least; flat shading
    then gives every corner its face's axis normal."""
    scan = {"box": _scan()}
    raw = _rms_to_box(scan["box"])
    den = prepare_scaffold(scan, planes=False, shading="shared")["box"]
    snapped = prepare_scaffold(scan, shading="shared")["box"]
    assert _rms_to_box(den) < 0.7 * raw
    assert _rms_to_box(snapped) < 0.3 * _rms_to_box(den)
    flat = prepare_scaffold(scan, shading="flat")["box"]
    n = np.asarray(flat.vertex_normals)
    np.testing.assert_allclose(np.sort(np.abs(n), axis=1)[:, 2], 1.0, atol=1e-3)
    auto = prepare_scaffold(scan)["box"]                   # a box is not curved: flat
    assert auto.metadata["shading"].startswith("flat")


def test_02_curved_objects_are_not_snapped():
    """A 0.3 m noisy column (64 sides, 1 m): snap_planes on its own cuts the
    denoised side into planar strips (moves of > 1 mm sideways);
    prepare_scaffold sees a curved object and leaves it as denoised, and
    still snaps the box beside it."""
    rng = np.random.default_rng(1)
    cyl = trimesh.creation.cylinder(radius=0.3, height=1.0, sections=64)
    cyl = cyl.subdivide().subdivide()
    cyl = trimesh.Trimesh(np.asarray(cyl.vertices) + rng.normal(0, 0.5e-3, cyl.vertices.shape),
                          cyl.faces, process=False)
    scan = {"column": cyl, "box": _scan()}
    on = prepare_scaffold(scan, shading="shared")
    off = prepare_scaffold(scan, planes=False, shading="shared")
    np.testing.assert_array_equal(on["column"].vertices, off["column"].vertices)
    alone = snap_planes(off["column"])
    assert alone.metadata["planes"]["count"] > 0
    assert np.abs(np.asarray(alone.vertices) - np.asarray(off["column"].vertices))[:, :2].max() > 1e-3
    assert _rms_to_box(on["box"]) < 0.3 * _rms_to_box(off["box"])


def test_03_nothing_to_do_returns_the_meshes():
    scan = {"box": _scan()}
    out = prepare_scaffold(scan, denoise=False, planes=False, shading="shared")
    assert out["box"] is scan["box"]


@pytest.mark.parametrize("meshes, kwargs, match", [
    ({}, {}, "non-empty dict"),
    ([1], {}, "non-empty dict"),
    (None, dict(shading="smooth"), "shading must be one of"),
])
def test_04_bad_inputs(meshes, kwargs, match):
    with pytest.raises(InputValueError, match=match):
        prepare_scaffold(meshes, **kwargs)

"""sionna_mmir.scene.flat_shaded: per-face vertices and normals."""
from __future__ import annotations

import numpy as np
import pytest
import trimesh

from sionna_mmir.errors import InputValueError
from sionna_mmir.scene import flat_shaded, read_mesh


def test_01_box_normals_are_the_face_normals():
    """A unit box (shared vertices, averaged normals at its corners): after
    flat shading every vertex normal is its face's axis-aligned normal."""
    box = trimesh.creation.box(extents=(1.0, 2.0, 3.0))
    avg = np.asarray(box.vertex_normals)
    assert np.abs(avg).max() < 0.99                     # corners lean: |n| spread over axes
    flat = flat_shaded(box)
    assert len(flat.vertices) == 3 * len(box.faces) and len(flat.faces) == len(box.faces)
    n = np.asarray(flat.vertex_normals)
    # each normal is +-e_x, +-e_y or +-e_z and points away from the centre
    np.testing.assert_allclose(np.sort(np.abs(n), axis=1), np.tile([0, 0, 1.0], (len(n), 1)),
                               atol=1e-12)
    assert (np.sum(n * np.asarray(flat.vertices), axis=1) > 0).all()
    # same triangles, same winding
    np.testing.assert_allclose(np.asarray(flat.triangles), np.asarray(box.triangles))


def test_02_load_path_uses_the_flat_normals(tmp_path):
    flat = flat_shaded(trimesh.creation.box(extents=(1.0, 1.0, 1.0)))
    data = read_mesh(flat)
    np.testing.assert_allclose(data.normals, np.asarray(flat.vertex_normals), atol=1e-6)


def test_03_dict_and_degenerate_faces():
    good = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 0]],
                           [[0, 1, 2], [0, 1, 3]], process=False)      # second face: zero area
    out = flat_shaded({"a": good})
    assert list(out) == ["a"] and len(out["a"].faces) == 1
    np.testing.assert_allclose(out["a"].vertex_normals, [[0, 0, 1]] * 3, atol=1e-12)


def test_04_bad_inputs():
    with pytest.raises(InputValueError, match="expected trimesh"):
        flat_shaded({"x": np.zeros((3, 3))})
    with pytest.raises(InputValueError, match="empty dict"):
        flat_shaded({})
    with pytest.raises(InputValueError, match="no faces"):
        flat_shaded(trimesh.Trimesh(np.zeros((3, 3)), np.zeros((0, 3), int), process=False))
    with pytest.raises(InputValueError, match="NaN"):
        flat_shaded(trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [np.nan, 1, 0]], [[0, 1, 2]],
                                    process=False))
    with pytest.raises(InputValueError, match="degenerate"):
        flat_shaded(trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [2, 0, 0]], [[0, 1, 2]],
                                    process=False))

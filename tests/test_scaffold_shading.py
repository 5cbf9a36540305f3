"""sionna_mmir.scaffold.flat_shaded / crease_shaded: per-face or crease-split vertices and normals."""
from __future__ import annotations

import numpy as np
import pytest
import trimesh

from sionna_mmir.errors import InputValueError
from sionna_mmir.scaffold import auto_shaded, crease_shaded, flat_shaded
from sionna_mmir.scene import read_mesh
from sionna_mmir.scaffold.shading import curved_fraction


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


def _capped_prism(n_sides=24, radius=0.1, height=1.0):
    """A regular prism with a top cap, side vertices shared and their normals radial
    (the smooth shading of a pole); the cap's rim shares the side's top vertices."""
    ang = 2 * np.pi * np.arange(n_sides) / n_sides
    ring = np.column_stack([radius * np.cos(ang), radius * np.sin(ang)])
    v = np.vstack([np.column_stack([ring, np.zeros(n_sides)]),
                   np.column_stack([ring, np.full(n_sides, height)]), [[0, 0, height]]])
    k, k1 = np.arange(n_sides), (np.arange(n_sides) + 1) % n_sides
    sides = np.vstack([np.column_stack([k, k1, n_sides + k1]),
                       np.column_stack([k, n_sides + k1, n_sides + k])])
    cap = np.column_stack([n_sides + k, n_sides + k1, np.full(n_sides, 2 * n_sides)])
    normals = np.vstack([np.column_stack([np.cos(ang), np.sin(ang), np.zeros(n_sides)])] * 2
                        + [[[0, 0, 1.0]]])
    return trimesh.Trimesh(v, np.vstack([sides, cap]), vertex_normals=normals, process=False)


def test_05_crease_shading_of_a_box_is_flat():
    """Every corner of a box sits on a 90 deg crease: crease shading at 30 deg
    splits them all and gives the face normals, like flat shading."""
    box = trimesh.creation.box(extents=(1.0, 2.0, 3.0))
    out = crease_shaded(box, 30.0)
    assert len(out.vertices) == 3 * len(box.faces)
    np.testing.assert_allclose(np.asarray(out.triangles), np.asarray(box.triangles))
    n = np.asarray(out.vertex_normals)[np.asarray(out.faces)]         # (F, 3 corners, 3)
    np.testing.assert_allclose(n, np.repeat(np.asarray(box.face_normals)[:, None], 3, axis=1),
                               atol=1e-12)


def test_06_crease_shading_keeps_a_pole_smooth_and_splits_its_rim():
    """A 24-sided capped prism with radial vertex normals (15 deg between
    facets, 90 deg at the rim): the side keeps its shared vertices and radial
    normals (7.5 deg from each facet's normal), the cap gets its own vertices
    with the normal +z; the triangles are unchanged."""
    pole = _capped_prism()
    out = crease_shaded({"pole": pole}, 30.0)["pole"]
    np.testing.assert_allclose(np.asarray(out.triangles), np.asarray(pole.triangles))
    F_side = 48
    faces, v, n = np.asarray(out.faces), np.asarray(out.vertices), np.asarray(out.vertex_normals)
    side_v = np.unique(faces[:F_side])
    assert len(side_v) == 48                          # 2 rings, shared as in the input
    radial = v[side_v, :2] / np.linalg.norm(v[side_v, :2], axis=1, keepdims=True)
    np.testing.assert_allclose(n[side_v, :2], radial, atol=1e-12)
    cap_v = np.unique(faces[F_side:])
    assert not set(cap_v) & set(side_v)               # the rim is split
    np.testing.assert_allclose(n[cap_v], np.tile([0, 0, 1.0], (len(cap_v), 1)), atol=1e-12)
    # a threshold below the 7.5 deg lean flattens the side as well
    tight = crease_shaded(pole, 5.0)
    # (48 side faces x 3 corners, 24 cap faces x 2 rim corners, the shared cap centre)
    assert len(tight.vertices) == 48 * 3 + 24 * 2 + 1
    np.testing.assert_allclose(np.asarray(tight.vertex_normals)[np.asarray(tight.faces)][:F_side],
                               np.repeat(np.asarray(pole.face_normals)[:F_side, None], 3, axis=1),
                               atol=1e-12)


def test_07_crease_shading_bad_inputs():
    box = trimesh.creation.box()
    for bad in (0.0, 180.0, -5.0, float("nan")):
        with pytest.raises(InputValueError, match="angle_deg"):
            crease_shaded(box, bad)
    for bad in (-1.0, 180.0, float("nan")):
        with pytest.raises(InputValueError, match="planar_deg"):
            crease_shaded(box, 30.0, bad)
    with pytest.raises(InputValueError, match="empty dict"):
        crease_shaded({})
    with pytest.raises(InputValueError, match="expected trimesh"):
        crease_shaded({"x": "box"})
    with pytest.raises(InputValueError, match="no faces"):
        crease_shaded(trimesh.Trimesh(np.zeros((3, 3)), np.zeros((0, 3), int), process=False))


def test_08_curved_fraction_of_a_pole_and_a_box():
    """The capped 24-sided prism: its side faces are curved (vertex normals 15 deg
    apart, 7.5 deg from the face), its cap is not (rim normals at 90 deg): the
    fraction is the side's share of the area, from the polygon's geometry.  A
    box has none; a planar threshold above 15 deg calls the side planar."""
    r, h, n = 0.1, 1.0, 24
    side = n * 2 * r * np.sin(np.pi / n) * h
    cap = n * 0.5 * r * r * np.sin(2 * np.pi / n)
    pole = _capped_prism(n, r, h)
    assert curved_fraction(pole, 20.0, 2.0) == pytest.approx(side / (side + cap), rel=1e-9)
    assert curved_fraction(pole, 20.0, 16.0) == 0.0
    assert curved_fraction(pole, 5.0, 2.0) == 0.0          # 7.5 deg lean: a crease at 5 deg
    assert curved_fraction(trimesh.creation.box(), 20.0, 2.0) == 0.0


def test_09_auto_shading_per_object():
    """A pole (curved) keeps its smooth side and gets a split rim; a box is
    flat-shaded; the choice is recorded in the metadata."""
    out = auto_shaded({"pole": _capped_prism(), "box": trimesh.creation.box()})
    assert list(out) == ["pole", "box"]
    assert out["pole"].metadata["shading"].startswith("crease")
    assert out["box"].metadata["shading"].startswith("flat")
    assert len(np.unique(np.asarray(out["pole"].faces)[:48])) == 48
    assert len(out["box"].vertices) == 36
    for bad, match in (({}, "non-empty dict"), (trimesh.creation.box(), "non-empty dict")):
        with pytest.raises(InputValueError, match=match):
            auto_shaded(bad)
    with pytest.raises(InputValueError, match="min_curved"):
        auto_shaded({"box": trimesh.creation.box()}, min_curved=1.5)
    with pytest.raises(InputValueError, match="no faces"):
        auto_shaded({"e": trimesh.Trimesh(np.zeros((3, 3)), np.zeros((0, 3), int), process=False)})

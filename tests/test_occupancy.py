"""3-D occupancy: metrics, RAE cube, point cloud, gating, PLY, pipeline, CLI, bad input."""
import json
import math
import os

import numpy as np
import pytest

from helpers import point_target_delays
from sionna_mmir.errors import ConfigError, InputValueError
from sionna_mmir.fmcw.synthesize import synthesize_adc
from sionna_mmir.occupancy import (beam_mask, extract_point_cloud, occupancy, occupancy_metrics,
                                   radar_to_scene, read_ply, reference_points, scene_to_radar,
                                   write_ply)
from sionna_mmir.processing.rae import RAECube, check_elevation_aperture, elevation_bins, rae_cube
from sionna_mmir.processing.range_fft import range_bins_m
from sionna_mmir.radar.config import RadarConfig


def _plate(path, centre, size=1.0, subdiv=2):
    """Square plate of side ``size`` [m] facing -x (the radar), PLY at ``path``."""
    import trimesh

    c = np.asarray(centre, float)
    h = size / 2
    v = c + np.array([[0, -h, -h], [0, h, -h], [0, h, h], [0, -h, h]])
    m = trimesh.Trimesh(v, [[0, 2, 1], [0, 3, 2]], process=False)
    for _ in range(subdiv):
        m = m.subdivide()
    m.export(str(path))
    return str(path)


def _target_adc(radar, xyz):
    tau = point_target_delays(radar, xyz)
    return synthesize_adc(radar, np.ones_like(tau, dtype=complex), tau)


def _flat_cube(radar, n_angle=31, power=1.0):
    """Synthetic cube: every visible voxel has the same power."""
    ranges = range_bins_m(radar)
    ang = elevation_bins(radar, n_angle)
    cube = RAECube(np.full((ranges.size, n_angle, n_angle), power, np.float32), ranges, ang, ang,
                   np.zeros(3))
    cube.power[:, ~cube.visible] = 0.0
    return cube


def test_01_metrics_against_hand_computed_sets():
    pred = np.array([[0, 0, 0.3], [0, 0, -0.2], [1, 0, 0.4], [5, 0, 0]], float)
    ref = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0], [10, 0, 0]], float)
    m = occupancy_metrics(pred, ref, tau=0.5)
    d_p = [0.3, 0.2, 0.4, 2.0]                               # predicted -> nearest reference
    d_q = [0.2, 0.4, math.sqrt(1.16), 2.0, 5.0]              # reference -> nearest predicted
    assert m["precision"] == pytest.approx(3 / 4)
    assert m["recall"] == pytest.approx(2 / 5)
    assert m["f1"] == pytest.approx(2 * 0.75 * 0.4 / 1.15)
    assert m["accuracy"] == pytest.approx(5 / 9)
    assert m["rmse"] == pytest.approx(math.sqrt((sum(d * d for d in d_p)
                                                 + sum(d * d for d in d_q)) / 9))
    chamfer = 0.5 * (np.mean(d_p) + np.mean(d_q))
    assert m["chamfer"] == pytest.approx(chamfer)
    assert m["r_cd"] == pytest.approx(chamfer / 10.0)         # reference bounding-box diagonal
    assert m["r_cd"] == pytest.approx(occupancy_metrics(pred, ref, scale=10.0)["r_cd"])
    assert (m["n_predicted"], m["n_reference"]) == (4, 5)
    same = occupancy_metrics(ref, ref)
    assert same["f1"] == 1.0 and same["rmse"] == 0.0 and same["chamfer"] == 0.0


def test_02_rae_cube_peaks_at_the_point_target():
    radar = RadarConfig.dense(8, 8)
    rng, az, el = 5.0, math.radians(20.0), math.radians(-15.0)
    u = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
    cube = rae_cube(_target_adc(radar, rng * u), radar)
    assert cube.shape == (256, 127, 127) and cube.power.dtype == np.float32
    np.testing.assert_allclose(cube.origin_m, 0.0, atol=1e-12)
    i, j, k = np.unravel_index(int(np.argmax(cube.power)), cube.shape)
    assert abs(cube.ranges_m[i] - rng) <= radar.range_resolution
    step = np.diff(np.sin(cube.azimuths_rad)).mean()
    assert abs(np.sin(cube.azimuths_rad[j]) - u[1]) <= step                 # u_y = cos el sin az
    assert abs(np.sin(cube.elevations_rad[k]) - u[2]) <= step               # u_z = sin el
    d = cube.directions()[j, k]
    assert math.degrees(math.atan2(d[1], d[0])) == pytest.approx(20.0, abs=1.0)
    assert math.degrees(math.asin(d[2])) == pytest.approx(-15.0, abs=1.0)


def test_03_point_cloud_in_the_scene_frame_with_a_pose():
    pos, ori = np.array([2.0, -1.0, 1.5]), np.radians([30.0, -10.0, 5.0])
    radar = RadarConfig.dense(8, 8, position=pos, orientation=ori)
    local = 4.0 * np.array([math.cos(0.2) * math.cos(-0.3), math.cos(0.2) * math.sin(-0.3),
                            math.sin(0.2)])
    target = radar_to_scene(local, pos, ori)[0]
    np.testing.assert_allclose(scene_to_radar(target, pos, ori)[0], local, atol=1e-12)
    cube = rae_cube(_target_adc(radar, local), radar)
    cloud = extract_point_cloud(cube, pos, ori)
    assert 0 < len(cloud) <= 0.002 * cube.power.size
    assert cloud.intensity.max() == pytest.approx(1.0) and cloud.intensity.min() >= 0.0
    best = cloud.points[np.argmax(cloud.intensity)]
    assert np.linalg.norm(best - target) < 0.15
    assert np.linalg.norm(cloud.points.mean(axis=0) - target) < 0.3     # main lobe about it
    top = extract_point_cloud(cube, pos, ori, percentile=99.99)
    assert len(top) < len(cloud) and np.linalg.norm(top.points - target, axis=1).max() < 0.7


def test_04_gating_keeps_only_visible_in_beam_points(tmp_path):
    radar = RadarConfig.dense(8, 8)
    cube = _flat_cube(radar)
    meshes = {"front": _plate(tmp_path / "front.ply", [5, 0, 0]),
              "hidden": _plate(tmp_path / "hidden.ply", [7, 0, 0], size=0.6),
              "high": _plate(tmp_path / "high.ply", [3, 0, 3 * math.tan(math.radians(55))]),
              "far": _plate(tmp_path / "far.ply", [20, 3, 0])}
    ref = reference_points(meshes, cube, np.zeros(3), np.zeros(3), points_per_m2=2000)
    c = ref.counts
    assert c["sampled"] > c["line_of_sight"] > c["beam"] > c["grid"] == c["intensity"] > 0
    p = ref.points
    assert np.all(np.abs(p[:, 0] - 5.0) < 1e-9)          # only the front plate survives
    assert c["grid"] == pytest.approx(2000, rel=0.1)
    d = np.array([[1, 0, 0], [math.cos(math.radians(37)), 0, math.sin(math.radians(37))],
                  [math.cos(math.radians(39)), 0, math.sin(math.radians(39))],
                  [math.cos(math.radians(72)), math.sin(math.radians(72)), 0],
                  [math.cos(math.radians(73)), math.sin(math.radians(73)), 0]])
    assert beam_mask(d).tolist() == [True, True, False, True, False]
    cube.power[:, :, : cube.shape[2] // 2 + 1] = 1e-9      # below the gate at and under el 0
    low = reference_points(meshes, cube, np.zeros(3), np.zeros(3), points_per_m2=2000)
    assert 0 < low.counts["intensity"] < c["intensity"] and np.all(low.points[:, 2] > 0)


def test_05_ply_round_trip(tmp_path):
    rng = np.random.default_rng(1)
    pts, inten = rng.normal(size=(50, 3)) * 10, rng.random(50)
    for binary in (True, False):
        path = tmp_path / f"c{int(binary)}.ply"
        write_ply(path, pts, inten, binary=binary, comment="test\ncloud")
        p2, i2 = read_ply(str(path))
        np.testing.assert_allclose(p2, pts, rtol=0 if binary else 1e-8, atol=1e-12 if binary
                                   else 1e-7)
        np.testing.assert_allclose(i2, inten, rtol=1e-6)
    with pytest.raises(InputValueError, match="empty point cloud"):
        write_ply(tmp_path / "e.ply", np.zeros((0, 3)))
    assert not (tmp_path / "e.ply").exists()
    data = (tmp_path / "c1.ply").read_bytes()
    (tmp_path / "t.ply").write_bytes(data[:-10])
    with pytest.raises(InputValueError, match="truncated"):
        read_ply(str(tmp_path / "t.ply"))
    (tmp_path / "x.ply").write_text("hello\n")
    with pytest.raises(InputValueError, match="not a PLY"):
        read_ply(str(tmp_path / "x.ply"))


def test_06_library_rejects_bad_input(tmp_path):
    radar = RadarConfig.dense(8, 8)
    empty = _flat_cube(radar, power=0.0)
    with pytest.raises(InputValueError, match="empty point cloud"):
        extract_point_cloud(empty, np.zeros(3), np.zeros(3))
    with pytest.raises(InputValueError, match="empty point cloud"):
        occupancy_metrics(np.zeros((0, 3)), np.ones((3, 3)))
    line = RadarConfig.dense(1, 8)
    with pytest.raises(ConfigError, match="no elevation aperture"):
        rae_cube(np.zeros(line.adc_shape, np.complex64), line)
    with pytest.raises(ConfigError, match="no elevation aperture"):
        check_elevation_aperture(RadarConfig.mmwcas())
    wall = _plate(tmp_path / "wall.ply", [4, 0, 0])
    with pytest.raises(ConfigError, match="no elevation aperture"):
        occupancy({"wall": wall}, line, wall)
    behind = _plate(tmp_path / "behind.ply", [-4, 0, 0])
    with pytest.raises(InputValueError, match="do not overlap"):
        reference_points(behind, _flat_cube(radar), np.zeros(3), np.zeros(3))
    with pytest.raises(InputValueError, match="behind.ply: mesh and radar frames do not overlap"):
        occupancy({"wall": wall}, radar, behind)
    (tmp_path / "bad.ply").write_text("not a mesh")
    with pytest.raises(InputValueError, match="bad.ply"):
        occupancy({"wall": wall}, radar, str(tmp_path / "bad.ply"))


def test_07_occupancy_of_a_posed_scene(tmp_path):
    wall = _plate(tmp_path / "wall.ply", [5, 1, 1], size=2.0, subdiv=3)
    pose = (np.array([1.0, 0.5, 0.2]), np.radians([10.0, -5.0, 0.0]))
    res = occupancy({"wall": wall}, RadarConfig.dense(16, 16), wall, pose,
                    materials={"wall": "metal"})
    assert res.cube.shape == (256, 127, 127)
    assert res.radar.position.tolist() == [1.0, 0.5, 0.2]
    m = res.metrics
    assert m["precision"] > 0.8 and m["recall"] > 0.5 and m["n_reference"] > 100
    assert np.median(np.abs(res.cloud.points[:, 0] - 5.0)) < 0.3      # on the wall, scene frame
    assert set(res.timings) >= {"render_s", "rae_s", "frame_s"}


def test_08_cli_writes_point_cloud_metrics_and_picture(tmp_path, capsys):
    from sionna_mmir.cli.main import main

    with pytest.raises(SystemExit):
        main(["occupancy", "--help"])
    assert "default: 100x100" in capsys.readouterr().out
    wall = _plate(tmp_path / "wall.ply", [4, 0, 1], size=2.0)
    out = tmp_path / "occ"
    assert main(["occupancy", wall, "--material", "wall=metal", "--array", "12x12",
                 "--position", "0,0,1", "--orientation", "5,0,0", "--out", str(out)]) == 0
    assert sorted(os.listdir(out)) == ["metrics.json", "occupancy.png", "points.ply"]
    pts, inten = read_ply(str(out / "points.ply"))
    info = json.loads((out / "metrics.json").read_text())
    assert len(pts) == info["metrics"]["n_predicted"] > 0 and np.all(inten <= 1)
    assert info["settings"]["render"]["max_depth"] == 1
    assert main(["occupancy", wall, "--array", "12x12", "--out", str(out)]) == 2
    assert "exists" in capsys.readouterr().err


@pytest.mark.parametrize("case", ["empty", "one_d", "frames", "unreadable"])
def test_09_cli_bad_input_exits_2_and_writes_nothing(tmp_path, capsys, case):
    from sionna_mmir.cli.main import EXIT_BAD_INPUT, main

    wall = _plate(tmp_path / "wall.ply", [4, 0, 0])
    behind = _plate(tmp_path / "behind.ply", [-4, 0, 0])
    (tmp_path / "bad.ply").write_text("not a mesh")
    args, words = {"empty": ([behind, "--truth", wall], ["behind.ply", "empty point cloud"]),
                   "one_d": ([wall, "--array", "1x12"], ["--array 1x12", "no elevation"]),
                   "frames": ([wall, "--truth", behind], ["behind.ply", "do not overlap"]),
                   "unreadable": ([str(tmp_path / "bad.ply")], ["bad.ply", "cannot read"])}[case]
    out = tmp_path / "occ"
    extra = [] if case == "one_d" else ["--array", "12x12"]
    code = main(["occupancy", *args, *extra, "--out", str(out)])
    err = capsys.readouterr().err
    assert code == EXIT_BAD_INPUT and err.splitlines()[-1].startswith("error: "), err
    assert all(w in err for w in words), err
    assert not out.exists() and not (tmp_path / "occ.partial").exists()


def test_10_fitted_scene_reloads_materials_and_normals(tmp_path):
    from sionna_mmir.fit import Adam, load_fitted_scene, reparam
    from sionna_mmir.fit.fitter import save_checkpoint

    wall = _plate(tmp_path / "wall.ply", [4, 0, 0])
    nv = 25
    mats = np.tile([3.0, 0.2, 1e-4, 5e-3, 0.5, 0.1], (nv, 1))
    normals = np.tile([-1.0, 0.0, 0.0], (nv, 1))
    z = {"wall.materials": reparam.to_latent(mats), "wall.normals": normals,
         "beam.tx.q_az": np.full(12, 2.0)}
    ck = tmp_path / "fit" / "fit_mmir.h5"
    os.makedirs(ck.parent)
    save_checkpoint(str(ck), z, Adam(), [1.0], "{}")
    scene = load_fitted_scene({"wall": wall}, tmp_path / "fit")
    obj = scene.mesh_objects["wall"]
    np.testing.assert_allclose(np.array(obj.vertex_materials), mats, rtol=1e-5)
    np.testing.assert_allclose(np.array(obj.vertex_normals), normals, atol=1e-7)
    other = _plate(tmp_path / "other.ply", [4, 0, 0], subdiv=1)
    with pytest.raises(InputValueError, match="vertices"):
        load_fitted_scene({"wall": other}, ck)
    with pytest.raises(InputValueError, match="object 'wall'"):
        load_fitted_scene({"door": wall}, ck)
    from sionna_mmir.cli.main import main

    out = tmp_path / "occ"
    assert main(["occupancy", wall, "--fitted", str(tmp_path / "fit"), "--array", "8x8",
                 "--out", str(out)]) == 0
    assert (out / "points.ply").exists()

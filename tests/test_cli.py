"""The ``sionna-mmir`` command line: help, happy paths, bad input -> exit 2, no partial output."""
import os
import subprocess
import sys

import numpy as np
import pytest

from sionna_mmir import Capture, RadarConfig
from sionna_mmir.cli.main import EXIT_BAD_INPUT, main

SUBCOMMANDS = ["demo", "info", "convert", "ra", "synth", "render", "fit", "compare", "bench",
               "dataset"]


def _run(*args):
    return subprocess.run([sys.executable, "-m", "sionna_mmir.cli.main", *args],
                          capture_output=True, text=True, timeout=300)


@pytest.mark.parametrize("cmd", SUBCOMMANDS)
def test_01_help(cmd, capsys):
    with pytest.raises(SystemExit) as e:
        main([cmd, "--help"])
    assert e.value.code == 0
    assert "usage: sionna-mmir " + cmd in capsys.readouterr().out


def test_02_synth_then_info_and_ra(tmp_path, capsys):
    out = tmp_path / "t.h5"
    assert main(["synth", "--radar", "mmwcas", "--chirps", "1", "--target", "8.0,10",
                 "--out", str(out)]) == 0
    assert main(["info", str(out)]) == 0
    text = capsys.readouterr().out
    line = [l for l in text.splitlines() if l.startswith("strongest")][0]
    r, az = float(line.split()[1]), float(line.split()[3])
    radar = RadarConfig.mmwcas()
    # the angle FFT looks from the azimuth row's phase centre ((tx + rx) / 2)
    centre = 0.5 * (radar.tx_positions[3:, None, :] + radar.rx_positions[None]).reshape(-1, 3).mean(0)
    x = 8.0 * np.array([np.cos(np.radians(10)), np.sin(np.radians(10)), 0.0])
    seen = np.degrees(np.arctan2(x[1] - centre[1], x[0] - centre[0]))
    assert abs(r - np.linalg.norm(x - centre)) <= radar.range_resolution
    assert abs(az - seen) < 0.5
    png = tmp_path / "ra.png"
    assert main(["ra", str(out), "--out", str(png)]) == 0
    assert png.stat().st_size > 1000


def test_03_missing_file_exits_2(tmp_path):
    res = _run("info", str(tmp_path / "nope.mat"))
    assert res.returncode == EXIT_BAD_INPUT
    assert "nope.mat" in res.stderr and "Traceback" not in res.stderr


def test_04_truncated_bin_exits_2_no_output(tmp_path, measured_dir):
    src = measured_dir / "awr1843_dca1000" / "moving_target_500frames.bin"
    if not src.exists():
        pytest.skip(f"{src} absent")
    bad = tmp_path / "cut.bin"
    bad.write_bytes(src.read_bytes()[:10001])
    out = tmp_path / "out.h5"
    res = _run("convert", str(bad), "--out", str(out))
    assert res.returncode == EXIT_BAD_INPUT
    assert "cut.bin" in res.stderr
    assert not out.exists()
    assert [p.name for p in tmp_path.iterdir()] == ["cut.bin"]


def test_05_nan_capture_rejected(tmp_path):
    radar = RadarConfig.awr1843()
    cap = Capture(np.ones(radar.adc_shape, np.complex64), radar)
    path = tmp_path / "c.h5"
    cap.save(path)
    import h5py

    with h5py.File(path, "r+") as f:
        f["adc"][0, 0, 0, 0, 3] = np.nan
    res = _run("convert", str(path), "--out", str(tmp_path / "o.h5"))
    assert res.returncode == EXIT_BAD_INPUT
    assert "NaN" in res.stderr
    assert not (tmp_path / "o.h5").exists()


def test_06_bad_target_and_existing_output(tmp_path):
    res = _run("synth", "--target", "abc", "--out", str(tmp_path / "x.h5"))
    assert res.returncode == EXIT_BAD_INPUT and "--target" in res.stderr
    assert not (tmp_path / "x.h5").exists()
    existing = tmp_path / "keep.h5"
    existing.write_text("old")
    res = _run("synth", "--target", "2,0", "--out", str(existing))
    assert res.returncode == EXIT_BAD_INPUT and "exists" in res.stderr
    assert existing.read_text() == "old"


def test_07_mat_without_calibresult(tmp_path):
    import scipy.io as sio

    bad = tmp_path / "bad.mat"
    sio.savemat(bad, {"something": np.zeros(3)})
    res = _run("info", str(bad))
    assert res.returncode == EXIT_BAD_INPUT
    assert "bad.mat" in res.stderr and "calibResult" in res.stderr


def test_08_demo_runs_on_embedded_capture(tmp_path, monkeypatch):
    """Without measured data the demo says so and runs on its synthetic capture."""
    monkeypatch.setenv("SIONNA_MMIR_MEASURED", str(tmp_path / "absent"))
    monkeypatch.chdir(tmp_path)
    from sionna_mmir.captures import measured
    from sionna_mmir.compare import demo

    monkeypatch.setattr(measured, "find_measured_dir", lambda: None)
    summary = demo.run_demo(out=tmp_path / "rep", fit_iterations=1, fit_rays=2000,
                            sionna_samples=20_000, progress=False)
    assert summary["note"] and "synthetic" in summary["note"]
    assert set(summary["fit"]) == {"mmIR", "Sionna RT"}
    assert "Sionna RT" in (tmp_path / "rep" / "table2.md").read_text()
    assert abs(summary["corner_range_m"] - 4.74) < 0.06
    assert summary["metrics"]["ra_correlation"] > 0.9
    for f in ("ra_panels.png", "report.md", "summary.json", "model.h5"):
        assert (tmp_path / "rep" / f).stat().st_size > 0
    with pytest.raises(FileExistsError):
        demo.run_demo(out=tmp_path / "rep", fit_iterations=0)
    assert not [p for p in os.listdir(tmp_path) if p.startswith(".demo-")]


def _wall_ply(path, x=3.0):
    import trimesh

    v = np.array([[x, -.5, -.5], [x, .5, -.5], [x, .5, .5], [x, -.5, .5]])
    trimesh.Trimesh(v, [[0, 2, 1], [0, 3, 2]], process=False).subdivide().export(str(path))
    return str(path)


def test_09_render_writes_capture_with_target_at_its_range(tmp_path):
    from sionna_mmir.processing.imaging import range_azimuth

    wall = _wall_ply(tmp_path / "wall.ply")
    out = tmp_path / "r.h5"
    assert main(["render", wall, "--material", "wall=metal", "--radar", "awr1843",
                 "--rays", "6000", "--chirps", "2", "--out", str(out)]) == 0
    cap = Capture.load(str(out))
    assert cap.frames.shape == (1, 3, 4, 2, 128)
    ra, ranges, _ = range_azimuth(cap.frames[0], cap.radar)
    r_i = np.unravel_index(np.argmax(ra), ra.shape)[0]
    assert abs(ranges[r_i] - 3.0) < 2 * cap.radar.range_resolution


def test_10_render_bad_inputs_exit_2_without_output(tmp_path, capsys):
    behind = _wall_ply(tmp_path / "behind.ply", x=-3.0)
    wall = _wall_ply(tmp_path / "wall.ply")
    nan = tmp_path / "nan.obj"
    nan.write_text("v 0 0 0\nv 1 0 0\nv 0 nan 0\nf 1 2 3\n")
    cases = [([behind], "hits"), ([wall, "--material", "wall=unobtainium"], "unobtainium"),
             ([wall, "--material", "wall=marble"], "marble"), ([str(nan)], "NaN"),
             ([str(tmp_path / "missing.ply")], "does not exist"),
             ([wall, "--position", "0,0"], "three")]
    for args, word in cases:
        out = tmp_path / "o.h5"
        code = main(["render", *args, "--radar", "awr1843", "--rays", "500", "--out", str(out)])
        err = capsys.readouterr().err
        assert code == EXIT_BAD_INPUT and word in err, (args, err)
        assert not out.exists()


def _target_capture(tmp_path):
    wall = _wall_ply(tmp_path / "wall.ply")
    tgt = tmp_path / "tgt.h5"
    assert main(["render", wall, "--material", "wall=metal", "--radar", "awr1843",
                 "--rays", "3000", "--out", str(tgt)]) == 0
    return wall, str(tgt)


def test_11_fit_and_compare_write_reports_and_resume(tmp_path):
    import json

    wall, tgt = _target_capture(tmp_path)
    out = tmp_path / "fit"
    common = [tgt, wall, "--iterations", "2", "--rays", "1500"]
    assert main(["fit", *common, "--out", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert len(summary["mmIR"]["loss"]) == 2
    for f in ("report.md", "ra_panels.png", "loss.png", "table2.csv", "fit_mmir.h5",
              "scene_mmir.ply"):
        assert (out / f).exists(), f
    # resume: the finished checkpoint is picked up, no iteration is redone
    assert main(["fit", *common, "--out", str(out), "--resume"]) == 0
    again = json.loads((out / "summary.json").read_text())
    np.testing.assert_allclose(again["mmIR"]["loss"], summary["mmIR"]["loss"], rtol=1e-6)
    cmp_out = tmp_path / "cmp"
    assert main(["compare", *common, "--sionna-samples", "2000", "--scaffold", "lidar",
                 "--sampling", "facets", "--out", str(cmp_out)]) == 0
    table = (cmp_out / "table2.md").read_text()
    assert "mmIR" in table and "Sionna RT" in table


def test_12_fit_bad_inputs_exit_2_without_output(tmp_path, capsys):
    wall, tgt = _target_capture(tmp_path)
    behind = _wall_ply(tmp_path / "behind.ply", x=-3.0)
    nan = tmp_path / "nan.h5"
    cap = Capture.load(tgt)
    frames = cap.frames.copy()
    frames[0, 0, 0, 0, 0] = np.nan
    with pytest.raises(Exception):
        Capture(frames, cap.radar, {}, "x").save(str(nan))
    junk = tmp_path / "junk.bin"
    junk.write_bytes(b"\x00" * 7)
    empty = tmp_path / "empty.ply"
    empty.write_text("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\n"
                     "property float y\nproperty float z\nelement face 0\n"
                     "property list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n")
    cases = [([tgt, str(behind)], "do not overlap"), ([str(tmp_path / "no.h5"), wall], "no.h5"),
             ([str(junk), wall], "junk.bin"), ([tgt, str(tmp_path / "no.ply")], "does not exist"),
             ([tgt, wall, "--iterations", "0"], "iterations"),
             ([tgt, str(empty), "--scaffold", "lidar"], "no faces"),
             ([tgt, str(empty), "--shading", "flat"], "no faces"),
             ([tgt, str(empty), "--scaffold", "lidar", "--shading", "shared"], "no faces"),
             ([tgt, str(empty), "--shading", "auto"], "no faces"),
             ([tgt, wall, "--min-rel-power", "-1"], "min_rel_power"),
             ([tgt, wall, "--normals-smoothing", "nan"], "normals_smoothing"),
             ([tgt, wall, "--materials-smoothing", "-3"], "materials_smoothing"),
             ([tgt, wall, "--learn", "pose,colour"], "--learn")]
    for args, word in cases:
        out = tmp_path / "o"
        code = main(["fit", *args, "--rays", "500", "--out", str(out)])
        err = capsys.readouterr().err
        assert code == EXIT_BAD_INPUT and word in err, (args, err)
        assert not out.exists() and not (tmp_path / "o.partial").exists()


def test_13_bench_reports_both_timings_and_rejects_bad_options(tmp_path, capsys):
    import json

    out = tmp_path / "b.json"
    assert main(["bench", "--rays", "300", "--repeat", "1", "--max-triangles", "3000",
                 "--sionna-depth", "1", "--out", str(out)]) == 0
    res = json.loads(out.read_text())
    assert res["mmir_s_per_it"] > 0 and res["sionna_s_per_it"] > 0
    assert abs(res["ratio_mmir_over_sionna"] - res["mmir_s_per_it"] / res["sionna_s_per_it"]) < 1e-9
    assert main(["bench", "--scene", "moon"]) == EXIT_BAD_INPUT
    assert "unknown scene" in capsys.readouterr().err
    assert main(["bench", "--sionna-depth", "0"]) == EXIT_BAD_INPUT
    assert "--sionna-depth must be >= 1" in capsys.readouterr().err
    assert main(["bench", "--sionna-samples", "0"]) == EXIT_BAD_INPUT
    assert "--sionna-samples must be >= 1" in capsys.readouterr().err
    assert main(["bench", "--min-rel-power", "1.5", "--max-triangles", "3000"]) == EXIT_BAD_INPUT
    assert "min_rel_power" in capsys.readouterr().err
    assert main(["bench", "--learn", "materials,colour"]) == EXIT_BAD_INPUT
    assert "cannot learn ['colour']" in capsys.readouterr().err
    with pytest.raises(SystemExit) as e:                     # argparse: an unknown choice
        main(["bench", "--shading", "round"])
    assert e.value.code == EXIT_BAD_INPUT and "invalid choice" in capsys.readouterr().err
    assert res["learn"] == ["materials", "beam"]


def test_14_fit_learns_the_radar_pose_with_the_boundary_term(tmp_path):
    import json

    wall, tgt = _target_capture(tmp_path)
    out = tmp_path / "pose"
    assert main(["fit", tgt, wall, "--iterations", "2", "--rays", "1500", "--learn", "pose",
                 "--boundary", "--out", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert len(summary["mmIR"]["loss"]) == 2

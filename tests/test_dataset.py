"""``sionna-mmir dataset``: frames written, bit-identical re-render from the
manifest, interrupt + resume, Ray and the fallback without it, bad specs."""
import json
import math
import os

import numpy as np
import pytest

from sionna_mmir.cli.main import EXIT_BAD_INPUT, main
from sionna_mmir.dataset import (load_spec, read_manifest, read_shard, render_frame,
                                 run_dataset)
from sionna_mmir.dataset import render as render_mod
from sionna_mmir.dataset import runner
from sionna_mmir.errors import ConfigError
from sionna_mmir.radar.config import rotation_matrix

pytest.importorskip("sionna.rt")


def _plate_ply(folder):
    import trimesh

    plate = trimesh.Trimesh([[3, -1, 0], [3, 1, 0], [3, 1, 2], [3, -1, 2]],
                            [[0, 1, 2], [0, 2, 3]], process=False)
    path = os.path.join(folder, "plate.ply")
    plate.export(path)
    return "plate.ply"


def _spec(tmp_path, frames=7, per_shard=3, **changes):
    spec = {"scenes": ["sionna:floor_wall",
                       {"name": "plate", "meshes": {"plate": _plate_ply(tmp_path)},
                        "materials": {"plate": "metal"}}],
            "radars": [{"preset": "awr1843", "chirps": 2}],
            "poses": {"type": "line", "start": [-2.0, 0.0, 1.0], "direction": [1, 0, 0],
                      "speed": 1.5, "frames": frames, "frame_period": 0.05},
            "solver": {"num_rays": 1500, "max_depth": 2}, "seed": 11,
            "frames_per_shard": per_shard}
    spec.update(changes)
    path = tmp_path / "spec.json"
    path.write_text(json.dumps(spec))
    return str(path)


def _all_frames(out):
    frames = {}
    for s in read_manifest(out)["shards"]:
        frames.update(read_shard(os.path.join(out, s["file"])))
    return frames


def test_01_writes_all_frames_with_manifest(tmp_path):
    out = str(tmp_path / "ds")
    stats = run_dataset(_spec(tmp_path), out, workers=1, progress=False)
    assert stats["frames"] == 14 and stats["shards"] == 5 and stats["mode"] == "local"
    man = read_manifest(out)
    assert man["complete"] and man["num_frames"] == 14 and man["package_version"]
    assert [e["seed"] for e in man["frames"]] == list(range(11, 25))
    assert [s["file"] for s in man["shards"]] == [f"shard_{i:05d}.h5" for i in range(5)]
    assert all(len(s["sha256"]) == 64 for s in man["shards"])
    frames = _all_frames(out)
    assert sorted(frames) == list(range(14))
    assert all(a.shape == (3, 4, 2, 128) and a.dtype == np.complex64 for a in frames.values())
    assert all(np.abs(a).max() > 0 for a in frames.values())
    e = man["frames"][8]                           # scene 2 ("plate"), pose 1
    assert e["scene"]["name"] == "plate" and e["shard"] == "shard_00002.h5"
    assert e["pose"]["position"] == pytest.approx([-2.0 + 1.5 * 0.05, 0.0, 1.0])
    assert e["pose"]["velocity"] == pytest.approx([1.5, 0.0, 0.0])
    assert e["radar"]["position"] == e["pose"]["position"]
    import h5py

    with h5py.File(os.path.join(out, "shard_00002.h5")) as f:
        g = f["frames/0000008"]
        assert json.loads(g.attrs["pose"]) == e["pose"] and g.attrs["seed"] == e["seed"]
        assert json.loads(g.attrs["radar"]) == e["radar"]


def test_02_frame_rerenders_bit_identically_from_manifest(tmp_path):
    out = str(tmp_path / "ds")
    run_dataset(_spec(tmp_path, frames=4, per_shard=4), out, workers=1, progress=False)
    frames = _all_frames(out)
    render_mod._SCENES.clear()                     # a fresh scene, as in another process
    entries = json.loads(json.dumps(read_manifest(out)["frames"]))
    for e in (entries[0], entries[5], entries[3]):
        assert np.array_equal(render_frame(e), frames[e["frame"]])
    moved = dict(entries[5], pose=dict(entries[5]["pose"], velocity=[0.0, 0.0, 0.0]))
    assert not np.array_equal(render_frame(moved), frames[5])   # the velocity is rendered


def test_03_interrupt_then_resume_skips_finished_shards(tmp_path):
    out = str(tmp_path / "ds")
    spec = _spec(tmp_path, frames=5, per_shard=4)          # 10 frames, 3 shards

    def kill_after_first(name):
        raise KeyboardInterrupt(f"killed after {name}")

    with pytest.raises(KeyboardInterrupt):
        run_dataset(spec, out, workers=1, progress=False, on_shard=kill_after_first)
    assert sorted(n for n in os.listdir(out) if n.endswith(".h5")) == ["shard_00000.h5"]
    assert not read_manifest(out)["complete"]
    first = os.stat(os.path.join(out, "shard_00000.h5")).st_mtime_ns
    # a killed writer's temp file and a shard without its completion marker
    open(os.path.join(out, ".shard_00001.h5-abc.part"), "wb").write(b"half a shard")
    import h5py

    with h5py.File(os.path.join(out, "shard_00002.h5"), "w") as f:
        f.attrs["format"] = "sionna_mmir.dataset_shard"
    written = []
    stats = run_dataset(spec, out, workers=1, progress=False, on_shard=written.append)
    assert stats["skipped"] == ["shard_00000.h5"]
    assert written == stats["rendered"] == ["shard_00001.h5", "shard_00002.h5"]
    assert os.stat(os.path.join(out, "shard_00000.h5")).st_mtime_ns == first
    assert not [n for n in os.listdir(out) if n.endswith(".part")]
    assert read_manifest(out)["complete"] and sorted(_all_frames(out)) == list(range(10))
    # a third run renders nothing; a corrupted shard is detected by its checksum
    assert run_dataset(spec, out, workers=1, progress=False)["rendered"] == []
    with h5py.File(os.path.join(out, "shard_00001.h5"), "a") as f:
        f["frames/0000004/adc"][0, 0, 0, 0] += 1.0
    assert run_dataset(spec, out, workers=1, progress=False)["rendered"] == ["shard_00001.h5"]


def test_04_fallback_without_ray(tmp_path, monkeypatch):
    ref = str(tmp_path / "ref")
    spec = _spec(tmp_path, frames=3, per_shard=2)
    run_dataset(spec, ref, workers=1, progress=False)
    monkeypatch.setattr(runner, "_import_ray", lambda: None)
    out = str(tmp_path / "noray")
    stats = run_dataset(spec, out, workers=2, progress=False)
    assert stats["mode"] == "local (ray not installed)"
    a, b = _all_frames(ref), _all_frames(out)
    assert a.keys() == b.keys() and all(np.array_equal(a[k], b[k]) for k in a)
    with pytest.raises(ConfigError, match="needs Ray"):
        run_dataset(spec, str(tmp_path / "x"), address="auto", progress=False)
    assert not os.path.exists(tmp_path / "x")


def test_05_ray_two_workers_bit_identical(tmp_path):
    pytest.importorskip("ray")
    spec = _spec(tmp_path, frames=3, per_shard=2)
    ref, out = str(tmp_path / "ref"), str(tmp_path / "ray")
    run_dataset(spec, ref, workers=1, progress=False)
    stats = run_dataset(spec, out, workers=2, progress=False)
    assert stats["mode"] == "ray" and len(stats["rendered"]) == 3
    a, b = _all_frames(ref), _all_frames(out)
    assert a.keys() == b.keys() and all(np.array_equal(a[k], b[k]) for k in a)


def test_06_trajectories(tmp_path):
    from sionna_mmir.dataset import circle_trajectory, line_trajectory

    line = line_trajectory([0, 0, 1], [1, 1, 0], speed=2.0, frames=3, frame_period=0.5)
    d = np.array([1, 1, 0]) / math.sqrt(2)
    assert np.allclose(line[2]["position"], [0, 0, 1] + 2.0 * d)
    assert np.allclose(line[1]["velocity"], 2.0 * d)
    assert np.allclose(rotation_matrix(line[0]["orientation"]) @ [1, 0, 0], d)
    circ = circle_trajectory([1, 2, 0.5], radius=3.0, speed=1.5, frames=4, frame_period=0.4)
    for p in circ:
        r = np.array(p["position"]) - [1, 2, 0.5]
        assert np.isclose(np.linalg.norm(r), 3.0) and np.isclose(r[2], 0)
        assert np.isclose(np.linalg.norm(p["velocity"]), 1.5) and np.isclose(
            np.dot(p["velocity"], r), 0, atol=1e-12)
        assert np.allclose(rotation_matrix(p["orientation"]) @ [1, 0, 0], -r / 3.0)
    spec = load_spec(_spec(tmp_path, poses={"type": "list", "poses": [
        {"position": [0, 0, 1], "orientation_deg": [90, 0, 0]}, {"position": [1, 0, 1]}]}))
    assert spec.num_frames == 4
    assert np.allclose(spec.poses[0]["orientation"], [math.pi / 2, 0, 0])


def _cli(argv, capsys):
    code = main(argv)
    return code, capsys.readouterr()


def test_07_cli_writes_and_resumes(tmp_path, capsys):
    out = str(tmp_path / "ds")
    spec = _spec(tmp_path, frames=2, per_shard=2)
    code, cap = _cli(["dataset", spec, "--out", out, "--workers", "1", "--quiet"], capsys)
    assert code == 0 and "4 frames in 2 shard(s) (2 rendered, 0 already complete)" in cap.out
    code, cap = _cli(["dataset", spec, "--out", out, "--workers", "1", "--quiet"], capsys)
    assert code == 0 and "(0 rendered, 2 already complete)" in cap.out
    other = _spec(tmp_path, frames=3, per_shard=2)
    code, cap = _cli(["dataset", other, "--out", out, "--workers", "1", "--quiet"], capsys)
    assert code == EXIT_BAD_INPUT and f"error: {out}: holds a dataset of another spec" in cap.err
    code, cap = _cli(["dataset", other, "--out", out, "--workers", "1", "--quiet",
                      "--overwrite"], capsys)
    assert code == 0 and read_manifest(out)["num_frames"] == 6


@pytest.mark.parametrize("change,path_part,problem", [
    ({"scenes": ["missing.xml"]}, "missing.xml", "scene file does not exist"),
    ({"radars": ["awr9999"]}, "spec.json", "unknown radar preset 'awr9999'"),
    ({"poses": {"type": "line", "start": [0, 0, 1], "direction": [1, 0, 0], "speed": 1,
                "frames": -3}}, "spec.json", "poses.frames must be an integer >= 1"),
    ({"solver": {"num_rayz": 10}}, "spec.json", "unknown solver option 'num_rayz'"),
])
def test_08_bad_spec_exit_2_nothing_written(tmp_path, capsys, change, path_part, problem):
    out = tmp_path / "ds"
    code, cap = _cli(["dataset", _spec(tmp_path, **change), "--out", str(out)], capsys)
    assert code == EXIT_BAD_INPUT
    line = cap.err.strip().splitlines()[-1]
    assert line.startswith("error: ") and path_part in line.split(": ")[1] and problem in line
    assert not out.exists()


def test_09_locked_folder_exit_2_nothing_written(tmp_path, capsys):
    out = str(tmp_path / "ds")
    spec = _spec(tmp_path, frames=2, per_shard=2)
    with runner.dataset_lock(out):                # another running job holds the folder
        before = sorted(os.listdir(out))
        code, cap = _cli(["dataset", spec, "--out", out, "--workers", "1", "--quiet"], capsys)
        assert code == EXIT_BAD_INPUT
        assert f"error: {out}: locked by another running dataset job (pid {os.getpid()})" \
            in cap.err
        assert sorted(os.listdir(out)) == before == [".lock"]
    code, cap = _cli(["dataset", spec, "--out", out, "--workers", "1", "--quiet"], capsys)
    assert code == 0
    (tmp_path / "stuff").mkdir()
    (tmp_path / "stuff" / "notes.txt").write_text("mine")
    code, cap = _cli(["dataset", spec, "--out", str(tmp_path / "stuff"), "--quiet"], capsys)
    assert code == EXIT_BAD_INPUT and "is not a dataset folder" in cap.err
    assert os.listdir(tmp_path / "stuff") == ["notes.txt"]


def test_10_coloradar_calib_radar(tmp_path, measured_dir):
    import shutil
    import warnings

    from sionna_mmir.radar.config import RadarConfig

    calib = tmp_path / "calib"
    shutil.copytree(measured_dir / "coloradar_calib", calib)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")          # the repaired cascade waveform
        spec = load_spec(_spec(tmp_path, radars=["calib", {"coloradar": "calib",
                                                            "sensor": "single_chip",
                                                            "chirps": 2}]))
        from sionna_mmir.captures import read_coloradar_config

        cascade = read_coloradar_config(calib, "cascade")
    assert spec.radars[0]["config"] == cascade.to_dict()
    assert spec.radars[1]["config"]["num_chirps"] == 2
    with pytest.raises(ConfigError, match=r"nocalib: ColoRadar calib folder does not exist"):
        load_spec(_spec(tmp_path, radars=[{"coloradar": "nocalib"}]))

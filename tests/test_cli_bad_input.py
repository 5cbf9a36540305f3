"""Every bad input and OS fault the command line meets ends in one clear line.

Each case asserts ``error: <path>: <problem>`` on stderr, exit status 2, no
traceback, and no partial or replaced output.  Operating-system conditions
are real where that is cheap (an immutable or read-only folder, a 300-byte
file name) and simulated with ``monkeypatch`` where not (a full disk).
"""
from __future__ import annotations

import contextlib
import errno
import io
import os
import shutil
import subprocess
import sys
import threading
import time

import h5py
import numpy as np
import pytest

from sionna_mmir import Capture, RadarConfig
from sionna_mmir.cli.main import EXIT_BAD_INPUT, EXIT_INTERNAL, main

C = 299_792_458.0


def _err(capsys) -> str:
    """stderr of the last command (after any progress bar), checked to be one
    clear line and no traceback."""
    err = capsys.readouterr().err
    assert "Traceback" not in err and "internal error" not in err, err
    last = err.split("\r")[-1]
    assert last.startswith("error: ") and last.count("\n") == 1, err
    return last


def _refused(capsys, argv, *words) -> str:
    code = main([str(a) for a in argv])
    err = _err(capsys)
    assert code == EXIT_BAD_INPUT, (argv, code, err)
    for w in words:
        assert w in err, (argv, w, err)
    return err


def _capture(path, frames=1, radar=None, **meta) -> str:
    radar = radar or RadarConfig.awr1843(num_chirps=1)
    rng = np.random.default_rng(0)
    shape = (frames, *radar.adc_shape)
    adc = rng.normal(size=shape) + 1j * rng.normal(size=shape)
    Capture(adc.astype(np.complex64), radar, meta).save(path)
    return str(path)


def _wall(path, x=3.0) -> str:
    import trimesh

    v = np.array([[x, -.5, -.5], [x, .5, -.5], [x, .5, .5], [x, -.5, .5]])
    trimesh.Trimesh(v, [[0, 2, 1], [0, 3, 2]], process=False).export(str(path))
    return str(path)


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    """A one-frame and a three-frame capture and a wall mesh."""
    d = tmp_path_factory.mktemp("inputs")
    return {"cap": _capture(d / "cap.h5"), "multi": _capture(d / "multi.h5", frames=3),
            "wall": _wall(d / "wall.ply"), "dir": d}


@pytest.fixture
def readonly_dir(tmp_path):
    """A folder nothing can be created in: mode 0555, or immutable for root."""
    d = tmp_path / "ro"
    d.mkdir()
    if os.geteuid() != 0:
        d.chmod(0o555)
        undo = ["chmod", "755", str(d)]
    elif shutil.which("chattr") and subprocess.run(["chattr", "+i", str(d)],
                                                   capture_output=True).returncode == 0:
        undo = ["chattr", "-i", str(d)]
    else:
        pytest.skip("no way to make a read-only folder here")
    try:
        with pytest.raises(OSError):
            (d / "probe").write_text("x")
        yield d
    finally:
        subprocess.run(undo, check=True)


# ----------------------------------------------------------------- 1-11: read-only folder
def _readonly_cases(inputs, ro):
    cap, multi, wall = inputs["cap"], inputs["multi"], inputs["wall"]
    return {
        "convert": ["convert", cap, "--out", ro / "c.h5"],
        "synth": ["synth", "--radar", "awr1843", "--chirps", "1", "--target", "3,0",
                  "--out", ro / "s.h5"],
        "ra": ["ra", cap, "--out", ro / "r.png"],
        "render": ["render", wall, "--radar", "awr1843", "--chirps", "1", "--rays", "500",
                   "--out", ro / "x.h5"],
        "fit": ["fit", cap, wall, "--iterations", "1", "--rays", "500", "--out", ro / "fit"],
        "compare": ["compare", cap, wall, "--iterations", "1", "--rays", "500",
                    "--out", ro / "cmp"],
        "residual": ["residual", multi, "--model", "static", "--out", ro / "res"],
        "demo": ["demo", "--iterations", "0", "--out", ro / "demo"],
        "loop": ["loop", cap, wall, "--fit-iterations", "0", "--out", ro / "loop"],
        "occupancy": ["occupancy", wall, "--array", "4x4", "--out", ro / "occ"],
        "bench": ["bench", "--out", ro / "b.json"],
    }


@pytest.mark.parametrize("cmd", ["convert", "synth", "ra", "render", "fit", "compare",
                                 "residual", "demo", "loop", "occupancy", "bench"])
def test_01_readonly_output_folder_refused_before_work(cmd, inputs, readonly_dir, capsys):
    t0 = time.perf_counter()
    _refused(capsys, _readonly_cases(inputs, readonly_dir)[cmd], str(readonly_dir),
             "cannot write in this folder")
    assert time.perf_counter() - t0 < 20               # refused up front, nothing computed
    assert os.listdir(readonly_dir) == []


def test_02_readonly_folder_raised_while_writing_names_the_target(tmp_path, monkeypatch, capsys):
    """A folder that turns read-only after the checks: the write's own error."""
    import tempfile

    from sionna_mmir.utils import outputs

    monkeypatch.setattr(outputs, "check_writable", lambda path: None)

    def denied(*a, dir=None, **k):
        raise PermissionError(errno.EACCES, "Permission denied", os.path.join(dir, ".x-1.part"))

    monkeypatch.setattr(tempfile, "mkstemp", denied)
    out = tmp_path / "s.h5"
    _refused(capsys, ["synth", "--radar", "awr1843", "--chirps", "1", "--target", "3,0",
                      "--out", out], f"{out}: Permission denied")


# ----------------------------------------------------------------- 3: disk full
class _FullDisk:
    """``h5py.File`` whose first dataset write fails as on a full disk."""

    real = h5py.File

    def __init__(self, path, mode="r", **kw):
        self.f = self.real(path, mode, **kw)

    def __getattr__(self, name):
        return getattr(self.f, name)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.f.close()

    def create_dataset(self, *a, **k):
        raise OSError(errno.ENOSPC, "Can't write data (file write failed: errno = 28)")


def test_03_disk_full_leaves_nothing_and_names_the_target(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(h5py, "File", _FullDisk)
    out = tmp_path / "s.h5"
    _refused(capsys, ["synth", "--radar", "awr1843", "--chirps", "1", "--target", "3,0",
                      "--out", out], f"{out}: no space left on the device")
    assert os.listdir(tmp_path) == []
    monkeypatch.undo()

    import matplotlib.figure

    def full(self, fname, **kw):
        with open(fname, "wb") as f:
            f.write(b"\x89PNG half")
        raise OSError(errno.ENOSPC, "No space left on device", fname)

    cap = _capture(tmp_path / "c.h5")
    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", full)
    png = tmp_path / "r.png"
    _refused(capsys, ["ra", cap, "--out", png], f"{png}: no space left on the device")
    assert sorted(os.listdir(tmp_path)) == ["c.h5"]


def test_03b_disk_full_in_a_report_folder(tmp_path, inputs, monkeypatch, capsys):
    from sionna_mmir.residual import report

    def full(path, mode="r", *a, **k):
        if str(path).endswith("residual.json"):
            raise OSError(errno.ENOSPC, "No space left on device", path)
        return open(path, mode, *a, **k)

    monkeypatch.setattr(report, "open", full, raising=False)
    out = tmp_path / "rep"
    _refused(capsys, ["residual", inputs["multi"], "--model", "static", "--effects", "dc_offset",
                      "--out", out], f"{out}: no space left on the device (writing residual.json)")
    assert os.listdir(tmp_path) == []


# ----------------------------------------------------------------- 4: file name too long
def test_04_file_name_too_long(tmp_path, capsys):
    out = tmp_path / ("a" * 300 + ".h5")
    _refused(capsys, ["synth", "--radar", "awr1843", "--chirps", "1", "--target", "3,0",
                      "--out", out], "file name too long", str(out))
    rep = tmp_path / ("r" * 250)                       # fits, but not with ".partial"
    _refused(capsys, ["residual", _capture(tmp_path / "m.h5", frames=3), "--model", "static",
                      "--out", rep], "file name too long", "sibling")
    assert sorted(os.listdir(tmp_path)) == ["m.h5"]
    longest = tmp_path / ("b" * 252 + ".h5")          # 255 bytes: allowed, temp name shortened
    assert main(["synth", "--radar", "awr1843", "--chirps", "1", "--target", "3,0",
                 "--out", str(longest)]) == 0
    assert Capture.load(longest).num_frames == 1


# ----------------------------------------------------------------- 5: empty .npy
def test_05_empty_and_truncated_npy(tmp_path, capsys):
    from sionna_mmir.captures.openradar import read_openradar_npy
    from sionna_mmir.errors import CaptureFormatError

    empty = tmp_path / "empty.npy"
    empty.write_bytes(b"")
    _refused(capsys, ["info", empty], f"{empty}: file is empty")
    with pytest.raises(CaptureFormatError, match="not a readable .npy"):
        read_openradar_npy(empty)
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": "<c16", "fortran_order": False,
                                               "shape": (10 ** 8, 8, 128)})
    cut = tmp_path / "cut.npy"
    cut.write_bytes(buf.getvalue() + b"\0" * 64)
    _refused(capsys, ["info", cut], "declares (100000000, 8, 128)", "truncated")


# ----------------------------------------------------------------- 6: noise overflow
def test_06_noise_db_out_of_range(tmp_path, inputs, capsys):
    for value in ("1e6", "inf", "nan", "-1e6"):
        _refused(capsys, ["synth", "--radar", "awr1843", "--chirps", "1", "--target", "3,0",
                          f"--noise-db={value}", "--out", tmp_path / "n.h5"], "--noise-db")
    _refused(capsys, ["render", inputs["wall"], "--radar", "awr1843", "--noise-db", "1e6",
                      "--out", tmp_path / "r.h5"], "--noise-db")
    assert os.listdir(tmp_path) == []
    assert main(["synth", "--radar", "awr1843", "--chirps", "1", "--target", "3,0",
                 "--noise-db", "-20", "--out", str(tmp_path / "ok.h5")]) == 0


# ----------------------------------------------------------------- 7: output larger than RAM
def test_07_synth_larger_than_memory_refused_with_estimate(tmp_path, capsys):
    t0 = time.perf_counter()
    _refused(capsys, ["synth", "--radar", "dense", "--chirps", "1000000", "--target", "3,0",
                      "--out", tmp_path / "d.h5"], "--chirps 1000000", "18.6 TiB",
             "available on this machine")
    assert time.perf_counter() - t0 < 5
    _refused(capsys, ["render", str(tmp_path / "w.ply"), "--radar", "dense", "--chirps",
                      "1000000", "--out", tmp_path / "r.h5"], "18.6 TiB")
    assert os.listdir(tmp_path) == []


# ----------------------------------------------------------------- 8: Dr.Jit ray limit
def test_08_rays_beyond_drjit_limit_refused_before_the_scene(tmp_path, monkeypatch, capsys):
    missing = tmp_path / "absent.ply"                  # not read: the rays are checked first
    _refused(capsys, ["render", missing, "--rays", "99999999999", "--out", tmp_path / "r.h5"],
             "num_rays", "2^31")
    monkeypatch.setenv("SIONNA_MMIR_AVAILABLE_MEMORY", str(10 ** 9))
    _refused(capsys, ["render", missing, "--rays", "100000000", "--out", tmp_path / "r.h5"],
             "--rays 100000000", "available on this machine")


# ----------------------------------------------------------------- 9-11: malformed HDF5
def _variant(src, dst, edit) -> str:
    shutil.copy(src, dst)
    with h5py.File(dst, "r+") as f:
        edit(f)
    return str(dst)


def _json_attr(key, **changes):
    import json

    def edit(f):
        d = json.loads(f.attrs[key])
        d.update(changes)
        f.attrs[key] = json.dumps(d)
    return edit


def test_09_hdf5_adc_stored_as_a_group(tmp_path, inputs, capsys):
    def edit(f):
        del f["adc"]
        f.create_group("adc")
    bad = _variant(inputs["cap"], tmp_path / "g.h5", edit)
    _refused(capsys, ["convert", bad, "--out", tmp_path / "o.h5"], bad, "'adc' is a group")
    assert not (tmp_path / "o.h5").exists()


def test_10_hdf5_frame_period_not_a_number(tmp_path, inputs, capsys):
    bad = _variant(inputs["multi"], tmp_path / "fp.h5", _json_attr("metadata", frame_period="abc"))
    _refused(capsys, ["residual", bad, "--model", "static", "--out", tmp_path / "rep"],
             bad, "frame_period = 'abc'")
    assert not (tmp_path / "rep").exists()


def test_11_hdf5_radar_slope(tmp_path, inputs, capsys):
    bad = _variant(inputs["cap"], tmp_path / "s.h5", _json_attr("radar", slope=-1))
    _refused(capsys, ["info", bad], bad, "RadarConfig.slope = -1 Hz/s")
    for value in (0, float("nan")):
        with pytest.raises(ValueError, match="slope"):
            RadarConfig.awr1843().replace(slope=value)
    # a down-chirp is a chirp: range processing mirrors its bins
    down = RadarConfig.awr1843(num_chirps=1, slope=-64.598e12)
    path = _capture(tmp_path / "down.h5", radar=down)
    assert main(["info", path]) == 0
    assert "slope -64.598" in capsys.readouterr().out


# ----------------------------------------------------------------- 12: non-UTF-8 mesh name
def test_12_mesh_file_name_not_utf8(tmp_path, inputs, capsys):
    name = os.fsdecode(os.path.join(os.fsencode(str(tmp_path)), b"w\xff.ply"))
    shutil.copy(inputs["wall"], name)
    _refused(capsys, ["render", name, "--radar", "awr1843", "--out", tmp_path / "r.h5"],
             "not valid UTF-8", "rename the file")
    assert not (tmp_path / "r.h5").exists()


# ----------------------------------------------------------------- 13: fit --out a file
def test_13_fit_out_is_an_existing_file(tmp_path, inputs, capsys):
    out = tmp_path / "report"
    out.write_text("keep")
    t0 = time.perf_counter()
    _refused(capsys, ["fit", inputs["cap"], inputs["wall"], "--out", out, "--overwrite"],
             f"{out}: exists and is not a folder")
    assert time.perf_counter() - t0 < 10 and out.read_text() == "keep"
    from sionna_mmir.compare.workflow import FitRequest, run_fit
    from sionna_mmir.errors import ConfigError

    with pytest.raises(ConfigError, match="not a folder"):     # the library checks first too
        run_fit(FitRequest(capture=inputs["cap"], meshes={"wall": inputs["wall"]},
                           out=str(out), overwrite=True))
    assert out.read_text() == "keep"


# ----------------------------------------------------------------- 14-16: silently accepted
def test_14_residual_penalty_nan(tmp_path, inputs, capsys):
    for value in ("nan", "inf", "-1", "aic", ""):
        _refused(capsys, ["residual", inputs["multi"], "--model", "static", f"--penalty={value}",
                          "--out", tmp_path / "rep"], "--penalty")
    _refused(capsys, ["loop", inputs["cap"], inputs["wall"], "--penalty", "nan",
                      "--out", tmp_path / "loop"], "--penalty")
    assert os.listdir(tmp_path) == []


def test_15_negative_frames(tmp_path, inputs, capsys):
    _refused(capsys, ["ra", inputs["cap"], "--frames", "-5", "--out", tmp_path / "r.png"],
             "--frames must be >= 1")
    _refused(capsys, ["render", inputs["wall"], "--frames", "-5", "--out", tmp_path / "r.h5"],
             "--frames must be >= 1")
    _refused(capsys, ["ra", inputs["cap"], "--frame", "7", "--out", tmp_path / "r.png"],
             "frame 7 requested")
    assert os.listdir(tmp_path) == []


def test_16_speeds_not_below_light(tmp_path, inputs, capsys):
    from sionna_mmir.errors import ConfigError
    from sionna_mmir.paths.options import SolverOptions

    for v in ("3e8", "-3e8", f"{C}"):
        _refused(capsys, ["synth", "--radar", "awr1843", f"--target=3,0,0,{v}",
                          "--out", tmp_path / "s.h5"], "speed of light")
    _refused(capsys, ["render", inputs["wall"], "--velocity", "wall=2.2e8,2.2e8,0",
                      "--out", tmp_path / "r.h5"], "--velocity", "speed of light")
    with pytest.raises(ConfigError, match="speed of light"):
        SolverOptions(velocities={"wall": (0.0, 0.0, 3e8)})
    with pytest.raises(ConfigError, match="speed of light"):
        SolverOptions(radar_velocity=(3e8, 0.0, 0.0))
    assert os.listdir(tmp_path) == []


# ----------------------------------------------------------------- 17: dispatch by content
def test_17_files_read_by_content_not_extension(tmp_path, inputs, capsys):
    import scipy.io

    as_bin = tmp_path / "capture.bin"
    shutil.copy(inputs["cap"], as_bin)                # an HDF5 capture renamed .bin
    assert main(["info", str(as_bin)]) == 0
    out = capsys.readouterr().out
    assert "awr1843" in out and "frames        1" in out
    npy = tmp_path / "a.h5"                             # a .npy renamed .h5
    np.save(tmp_path / "x.npy", np.zeros((4, 128), np.complex128))
    os.replace(tmp_path / "x.npy", npy)
    assert main(["info", str(npy)]) == 0 and "openradar" in capsys.readouterr().out
    mat = tmp_path / "m.bin"                            # MATLAB v5 renamed .bin
    scipy.io.savemat(tmp_path / "m.mat", {"other": np.zeros(3)})
    os.replace(tmp_path / "m.mat", mat)
    _refused(capsys, ["info", mat], str(mat), "calibResult")
    v73 = tmp_path / "v73.mat"                          # HDF5 with a MATLAB user block
    with h5py.File(v73, "w", userblock_size=512) as f:
        f["x"] = np.zeros(3)
    with open(v73, "r+b") as f:
        f.write(b"MATLAB 7.3 MAT-file, Platform: GLNXA64")
    _refused(capsys, ["info", v73], "v7.3", "-v7")


# ----------------------------------------------------------------- 18-21: data lost
def test_18_two_saves_without_overwrite_one_wins(tmp_path, monkeypatch):
    from sionna_mmir.captures import capture as capture_mod
    from sionna_mmir.utils import atomic

    barrier = threading.Barrier(2, timeout=30)
    real = atomic.atomic_path

    @contextlib.contextmanager
    def in_step(path, **kw):                 # both writers finish writing before either commits
        with real(path, **kw) as tmp:
            yield tmp
            barrier.wait()

    monkeypatch.setattr(capture_mod, "atomic_path", in_step)
    radar = RadarConfig.awr1843(num_chirps=1)
    caps = [Capture(np.full(radar.adc_shape, v, np.complex64), radar) for v in (1, 2)]
    path, results = tmp_path / "c.h5", {}

    def save(i):
        try:
            caps[i].save(path)
            results[i] = "saved"
        except FileExistsError as e:
            results[i] = str(e)

    threads = [threading.Thread(target=save, args=(i,)) for i in (0, 1)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert sorted(results.values())[1] == "saved", results
    loser = [i for i, r in results.items() if r != "saved"][0]
    assert "not replaced" in results[loser]
    kept = Capture.load(path).frames[0, 0, 0, 0, 0].real
    assert kept == (2 - loser), (kept, loser)
    assert os.listdir(tmp_path) == ["c.h5"]


def test_19_report_folder_in_use_by_another_run(tmp_path, inputs, capsys):
    from sionna_mmir.utils.outputs import folder_lock

    out = tmp_path / "fit"
    out.mkdir()
    (out / "first.txt").write_text("the first run's report")
    with folder_lock(out):
        t0 = time.perf_counter()
        _refused(capsys, ["fit", inputs["cap"], inputs["wall"], "--out", out, "--overwrite"],
                 f"{out}: in use by another run", f"pid {os.getpid()}")
        _refused(capsys, ["loop", inputs["cap"], inputs["wall"], "--out", out, "--resume"],
                 "in use by another run")
        assert time.perf_counter() - t0 < 10
        assert (out / "first.txt").read_text() == "the first run's report"
    assert not (tmp_path / "fit.lock").exists()
    assert sorted(os.listdir(tmp_path)) == ["fit"]


def test_20_bench_out_needs_overwrite(tmp_path, capsys):
    out = tmp_path / "b.json"
    out.write_text("{}")
    t0 = time.perf_counter()
    _refused(capsys, ["bench", "--out", out], f"{out}: exists", "--overwrite")
    # with --overwrite the output check passes; the bad --repeat is what stops it
    _refused(capsys, ["bench", "--out", out, "--overwrite", "--repeat", "0"], "--repeat")
    assert time.perf_counter() - t0 < 10 and out.read_text() == "{}"
    _refused(capsys, ["bench", "--out", tmp_path], "is a folder")


def _dead_pid() -> int:
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


def test_21_stale_temporaries_removed_fresh_ones_kept(tmp_path):
    from sionna_mmir.utils.atomic import STALE_ANY_S, STALE_DEAD_S

    old, dead = time.time() - STALE_DEAD_S - 5, _dead_pid()
    files = {f".c.h5-{dead}-abcdefgh.h5.part": (old, False),           # killed writer
             f".c.h5-{dead}-recent00.h5.part": (time.time(), True),     # may still be in flight
             ".c.h5-1-alive000.h5.part": (old, True),                   # pid 1 runs
             ".c.h5-legacy00.h5.part": (time.time() - STALE_ANY_S - 5, False),
             ".c.h5-legacy11.h5.part": (old, True),
             f".d.h5-{dead}-abcdefgh.h5.part": (old, True)}             # another target
    for name, (mtime, _) in files.items():
        (tmp_path / name).write_bytes(b"x" * 100)
        os.utime(tmp_path / name, (mtime, mtime))
    radar = RadarConfig.awr1843(num_chirps=1)
    Capture(np.ones(radar.adc_shape, np.complex64), radar).save(tmp_path / "c.h5")
    left = set(os.listdir(tmp_path))
    assert left == {"c.h5"} | {n for n, (_, keep) in files.items() if keep}


@pytest.mark.parametrize("mask", [0o022, 0o027, 0o002])
def test_22_written_files_follow_the_umask(tmp_path, mask):
    radar = RadarConfig.awr1843(num_chirps=1)
    before = os.umask(mask)
    try:
        Capture(np.ones(radar.adc_shape, np.complex64), radar).save(tmp_path / "c.h5")
        assert main(["ra", str(tmp_path / "c.h5"), "--out", str(tmp_path / "r.png")]) == 0
    finally:
        os.umask(before)
    for name in ("c.h5", "r.png"):
        assert os.stat(tmp_path / name).st_mode & 0o777 == 0o666 & ~mask


# ----------------------------------------------------------------- 23-24: memory
def _refused_within(fn, exc_type, match: str, limit_mb: float) -> None:
    """``fn()`` raises ``exc_type`` matching ``match`` having allocated < ``limit_mb``."""
    import tracemalloc

    tracemalloc.start()
    try:
        with pytest.raises(exc_type, match=match):
            fn()
        peak = tracemalloc.get_traced_memory()[1] / 2 ** 20
    finally:
        tracemalloc.stop()
    assert peak < limit_mb, peak


def test_23_hdf5_declaring_more_than_it_holds(tmp_path, inputs, monkeypatch, capsys):
    from sionna_mmir.errors import CaptureFormatError, ResourceError

    def declare(f, **kw):
        a = f["adc"][()]
        del f["adc"]
        f.create_dataset("adc", shape=(100000,) + a.shape[1:], dtype=a.dtype, **kw)

    bad = _variant(inputs["cap"], tmp_path / "big.h5", declare)
    assert os.path.getsize(bad) < 10_000
    _refused_within(lambda: Capture.load(bad), CaptureFormatError, "stores only 0 B", 20)
    chunked = _variant(inputs["cap"], tmp_path / "bigc.h5",
                       lambda f: declare(f, chunks=(1, 3, 4, 1, 128), compression="gzip"))
    _refused(capsys, ["info", chunked], chunked, "never written")
    written = tmp_path / "zeros.h5"                     # every chunk written: memory decides
    radar = RadarConfig.awr1843(num_chirps=1)
    with h5py.File(written, "w") as f:
        f.attrs.update(format="sionna_mmir.capture", version=1, metadata="{}", source="z",
                       radar=__import__("json").dumps(radar.to_dict()))
        f.create_dataset("adc", data=np.zeros((2000, *radar.adc_shape), np.complex64),
                         chunks=(1, *radar.adc_shape), compression="gzip")
    monkeypatch.setenv("SIONNA_MMIR_AVAILABLE_MEMORY", str(2 ** 20))
    with pytest.raises(ResourceError, match="needs about"):
        Capture.load(written)
    _refused(capsys, ["info", written], str(written), "available on this machine")


def test_24_ti_mat_sizes_checked_before_reading(tmp_path, capsys):
    import scipy.io

    from sionna_mmir.captures.ti_mat import read_ti_mat
    from sionna_mmir.errors import CaptureFormatError

    params = {"Slope_MHzperus": 79.0, "Sampling_Rate_sps": 8e6}
    bomb = tmp_path / "bomb.mat"                        # ~300 KB declaring ~300 MB of zeros
    scipy.io.savemat(bomb, {"calibResult": {"Rx_fft": np.zeros((5 * 20000, 16, 12), complex)},
                            "params": params}, do_compression=True)
    assert os.path.getsize(bomb) < 400_000
    _refused_within(lambda: read_ti_mat(bomb), CaptureFormatError, "more than 64 times", 20)
    wrong = tmp_path / "wrong.mat"
    scipy.io.savemat(wrong, {"calibResult": {"Rx_fft": np.ones((7, 16, 12), complex)},
                             "params": params})
    _refused(capsys, ["info", wrong], str(wrong), "Rx_fft has shape (7, 16, 12)")


# ----------------------------------------------------------------- 25-26: the boundary itself
def test_25_unexpected_exception_is_an_internal_error(monkeypatch, capsys):
    from sionna_mmir.cli import info

    def bug(args):
        raise ZeroDivisionError("a bug")

    monkeypatch.setattr(info, "run", bug)
    assert main(["info", "x.h5"]) == EXIT_INTERNAL
    err = capsys.readouterr().err
    assert err.startswith("error: internal error: ZeroDivisionError: a bug")
    assert "please report" in err and "Traceback" not in err
    monkeypatch.setenv("SIONNA_MMIR_TRACEBACK", "1")
    assert main(["info", "x.h5"]) == EXIT_INTERNAL
    assert "Traceback" in capsys.readouterr().err


def _bad_input_table(d, inputs) -> list:
    """``(argv, word)``: one or more bad inputs per command."""
    cap, multi, wall = inputs["cap"], inputs["multi"], inputs["wall"]
    (d / "zero.npy").write_bytes(b"")
    (d / "junk.bin").write_bytes(b"\0" * 7)
    (d / "spec.json").write_text("[1, 2]")
    (d / "text.h5").write_text("not hdf5")
    return [
        (["demo", "--capture", d / "missing.mat", "--out", d / "demo"], "missing.mat"),
        (["demo", "--iterations=-1", "--out", d / "demo"], "--iterations"),
        (["info", d / "zero.npy"], "file is empty"), (["info", d / "junk.bin"], "junk.bin"),
        (["info", d / "text.h5"], "text.h5"), (["info", d / "nothing.h5"], "nothing.h5"),
        (["info", d], "frame_0.bin"), (["info", cap, "--frame", "9"], "frame 9"),
        (["convert", cap, "--out", d], "is a folder"),
        (["convert", cap, "--out", cap], "exists"),
        (["ra", cap, "--frames", "0", "--out", d / "r.png"], "--frames"),
        (["synth", "--target", "abc", "--out", d / "s.h5"], "--target"),
        (["synth", "--target=-1,0", "--out", d / "s.h5"], "range must be positive"),
        (["synth", "--chirps", "0", "--target", "1,0", "--out", d / "s.h5"], "num_chirps"),
        (["render", d / "no.ply", "--out", d / "r.h5"], "no.ply"),
        (["render", wall, "--position", "0,0", "--out", d / "r.h5"], "--position"),
        (["render", wall, "--rays", "0", "--out", d / "r.h5"], "num_rays"),
        (["fit", cap, wall, "--iterations", "0", "--out", d / "f"], "--iterations"),
        (["fit", d / "zero.npy", wall, "--out", d / "f"], "zero.npy"),
        (["compare", cap, wall, "--min-rel-power", "2", "--out", d / "f"], "min_rel_power"),
        (["bench", "--repeat", "0"], "--repeat"), (["bench", "--scene", "moon"], "moon"),
        (["residual", multi, "--model", "static", "--folds", "1", "--out", d / "x"], "--folds"),
        (["residual", multi, "--model", "static", "--frames", "5:2", "--out", d / "x"],
         "--frames"),
        (["residual", multi, "--model", d / "m.h5", "--out", d / "x"], "m.h5: no such file"),
        (["loop", cap, wall, "--folds", "1", "--out", d / "l"], "--folds"),
        (["loop", cap, wall, "--material", "x=metal", "--out", d / "l"], "--material"),
        (["dataset", d / "spec.json", "--out", d / "ds"], "spec.json"),
        (["dataset", d / "none.json", "--out", d / "ds"], "none.json"),
        (["occupancy", wall, "--array", "0x3", "--out", d / "o"], "--array"),
        (["occupancy", d / "no.ply", "--out", d / "o"], "no.ply"),
        (["occupancy", wall, "--percentile", "150", "--out", d / "o"], "--percentile"),
        (["occupancy", wall, "--tau", "nan", "--out", d / "o"], "--tau"),
    ]


def test_26_no_traceback_for_any_bad_input(tmp_path, inputs, capsys):
    table = _bad_input_table(tmp_path, inputs)
    before = set(os.listdir(tmp_path))
    for argv, word in table:
        _refused(capsys, argv, word)
    assert set(os.listdir(tmp_path)) == before          # nothing written by any of them
    # and as a process: stderr holds the one line only
    res = subprocess.run([sys.executable, "-m", "sionna_mmir.cli.main", "info",
                          str(tmp_path / "zero.npy")], capture_output=True, text=True,
                         timeout=300)
    assert res.returncode == EXIT_BAD_INPUT
    assert res.stderr.strip().splitlines() == [f"error: {tmp_path / 'zero.npy'}: file is empty"]


# --------------------------------------------------------------- 27: loop inputs
def test_27_loop_refuses_bad_runs_frames_candidates_and_foreign_checkpoints(tmp_path, inputs,
                                                                            capsys):
    """Each refused before a report folder exists: an unreadable run folder, a
    mesh in a frame the radar cannot see, empty or unknown candidate lists, a
    checkpoint made for another radar."""
    import pickle

    from sionna_mmir.pipeline.loop import STATE_FORMAT

    cap, wall = inputs["cap"], inputs["wall"]
    run = tmp_path / "run"
    (run / "cascade" / "adc_samples").mkdir(parents=True)
    (run / "cascade" / "adc_samples" / "frame_0.bin").write_bytes(b"\x01\x02\x03")
    behind = _wall(tmp_path / "behind.ply", x=-3.0)
    out = tmp_path / "loop"
    cases = [([run, wall], str(run)), ([cap, behind, "--fit-iterations", "0"], "do not overlap"),
             ([cap, wall, "--effects", ","], "empty list of candidate effects"),
             ([cap, wall, "--effects", "gremlins"], "gremlins")]
    for args, word in cases:
        _refused(capsys, ["loop", *args, "--out", out], word)
        assert not out.exists() and not (tmp_path / "loop.partial").exists()
    # a checkpoint of a cascade run resumed with a single-chip capture
    partial = tmp_path / "loop.partial"
    partial.mkdir()
    state = {"format": STATE_FORMAT, "model": {"latents": None, "basis": None, "chain": None,
                                               "radar": RadarConfig.mmwcas().to_dict()},
             "run": None, "timings": {}, "info": {}, "scene_mismatch": None}
    (partial / "loop_state.pkl").write_bytes(pickle.dumps(state))
    _refused(capsys, ["loop", cap, wall, "--fit-iterations", "0", "--out", out, "--resume"],
             "loop_state.pkl", "another radar")
    assert not out.exists() and os.listdir(partial) == ["loop_state.pkl"]


def test_28_workers_must_be_auto_or_a_positive_integer(tmp_path, inputs, capsys):
    for value in ("0", "-2", "1.5", "many", ""):
        _refused(capsys, ["residual", inputs["multi"], "--model", "static", f"--workers={value}",
                          "--out", tmp_path / "rep"], "--workers")
        _refused(capsys, ["loop", inputs["cap"], inputs["wall"], f"--workers={value}",
                          "--out", tmp_path / "loop"], "--workers")
    assert os.listdir(tmp_path) == []

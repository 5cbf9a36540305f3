"""Capture HDF5 format and load_capture dispatch (synthetic data only)."""
from __future__ import annotations

import os

import h5py
import numpy as np
import pytest

from sionna_mmir.captures import Capture, load_capture
from sionna_mmir.errors import CaptureFormatError, InputValueError
from sionna_mmir.radar import RadarConfig


def _random_capture(n_frames=3, seed=0):
    radar = RadarConfig.awr1843(num_chirps=4, position=[1.0, -2.0, 0.5],
                                orientation=[0.1, 0.0, -0.2])
    rng = np.random.default_rng(seed)
    shape = (n_frames,) + radar.adc_shape
    frames = (rng.standard_normal(shape) + 1j * rng.standard_normal(shape)).astype(np.complex64)
    extras = {"peaks": rng.standard_normal((3, 4)) + 1j * rng.standard_normal((3, 4)),
              "bins": rng.integers(0, 640, (3, 4)).astype(np.int32),
              "mask": rng.random(5) > 0.5}
    meta = {"frame_period": 0.02, "note": "synthetic", "nested": {"a": [1, 2.5, None]}}
    return Capture(frames, radar, meta, "synthetic", extras)


def test_01_exact_round_trip(tmp_path):
    cap = _random_capture()
    path = cap.save(tmp_path / "cap.h5")
    back = Capture.load(path)
    assert np.array_equal(back.frames, cap.frames) and back.frames.dtype == np.complex64
    assert back.radar == cap.radar
    np.testing.assert_array_equal(back.radar.position, [1.0, -2.0, 0.5])
    assert back.metadata == cap.metadata and back.source == cap.source
    assert set(back.extras) == set(cap.extras)
    for k, v in cap.extras.items():
        assert np.array_equal(back.extras[k], v) and back.extras[k].dtype == v.dtype
    # through the dispatcher, and one frame of it
    via = load_capture(path)
    assert np.array_equal(via.frames, cap.frames)
    f1 = load_capture(path, frame=1)
    assert f1.num_frames == 1 and np.array_equal(f1.adc, cap.frames[1])
    with pytest.raises(IndexError, match="3 frame"):
        load_capture(path, frame=3)


def test_02_not_a_capture(tmp_path):
    p = tmp_path / "other.h5"
    with h5py.File(p, "w") as f:
        f["x"] = np.arange(3)
    with pytest.raises(CaptureFormatError, match="not a sionna_mmir capture") as e:
        Capture.load(p)
    assert str(p) in str(e.value)


def test_03_truncated_hdf5(tmp_path):
    p = _random_capture(n_frames=8).save(tmp_path / "full.h5")
    with open(p, "rb") as fh:                       # save() returns a str path
        data = fh.read()
    bad = tmp_path / "truncated.h5"
    bad.write_bytes(data[: len(data) // 2])
    with pytest.raises(CaptureFormatError) as e:
        Capture.load(bad)
    assert str(bad) in str(e.value)


def test_04_text_file(tmp_path):
    p = tmp_path / "notes.h5"
    p.write_text("just text\n")
    with pytest.raises(CaptureFormatError, match="HDF5") as e:
        load_capture(p)
    assert str(p) in str(e.value)


def test_05_no_overwrite(tmp_path):
    p = tmp_path / "keep.h5"
    first = _random_capture(seed=1)
    first.save(p)
    before = p.read_bytes()
    with pytest.raises(FileExistsError, match="keep.h5"):
        _random_capture(seed=2).save(p)
    assert p.read_bytes() == before
    assert np.array_equal(Capture.load(p).frames, first.frames)
    _random_capture(seed=2).save(p, overwrite=True)
    assert not np.array_equal(Capture.load(p).frames, first.frames)


def test_06_failed_save_leaves_nothing(tmp_path):
    cap = _random_capture()
    cap.extras["bad"] = np.array([{"a": 1}, None], dtype=object)   # h5py cannot store this
    p = tmp_path / "never.h5"
    with pytest.raises(Exception):
        cap.save(p)
    assert os.listdir(tmp_path) == []


def test_07_nan_rejected():
    radar = RadarConfig.awr1843()
    adc = np.zeros(radar.adc_shape, np.complex64)
    adc[1, 2, 0, 5] = np.nan
    with pytest.raises(InputValueError, match="NaN"):
        Capture(adc, radar)
    with pytest.raises(InputValueError, match="shape"):
        Capture(np.zeros((3, 4, 1, 64), np.complex64), radar)


def test_08_loader_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="nothing.h5"):
        load_capture(tmp_path / "nothing.h5")
    p = tmp_path / "capture.xyz"
    p.write_bytes(b"\0" * 16)
    with pytest.raises(CaptureFormatError, match=r"\.xyz") as e:
        load_capture(p)
    msg = str(e.value)
    assert str(p) in msg
    for fmt in (".h5", ".mat", ".bin", ".npy", "ColoRadar"):
        assert fmt in msg

"""DCA1000 .bin reader: the measured AWR1843 capture and synthetic files."""
from __future__ import annotations

import numpy as np
import pytest

from conftest import measured_file
from sionna_mmir.captures import load_capture, read_dca1000
from sionna_mmir.errors import CaptureFormatError
from sionna_mmir.radar import RadarConfig

C0 = 299_792_458.0
BIN = "awr1843_dca1000/moving_target_500frames.bin"
FRAME_BYTES = 3 * 4 * 128 * 2 * 2          # README: 3 Tx x 4 Rx x 128 complex int16 samples


def _encode(stream: np.ndarray) -> np.ndarray:
    """Complex stream -> int16 in the DCA1000 groups [I(k) I(k+1) Q(k) Q(k+1)]."""
    z = stream.reshape(-1, 2)
    g = np.stack([z[:, 0].real, z[:, 1].real, z[:, 0].imag, z[:, 1].imag], axis=1)
    return g.astype("<i2").reshape(-1)


@pytest.fixture(scope="module")
def cap(measured_dir):
    return read_dca1000(measured_file(measured_dir, BIN))


@pytest.mark.measured
def test_01_measured_loads(cap, measured_dir):
    assert cap.num_frames == 500
    assert cap.frames.shape == (500, 3, 4, 1, 128)
    assert cap.frames.dtype == np.complex64
    assert cap.metadata["frame_period"] == pytest.approx(0.02)
    assert cap.radar.num_tx == 3 and cap.radar.num_rx == 4
    assert (measured_dir / BIN).stat().st_size == 500 * FRAME_BYTES
    # int16 counts: every part is an integer within int16
    parts = cap.frames.view(np.float32)
    assert np.all(parts == np.round(parts)) and parts.min() >= -32768 and parts.max() <= 32767


@pytest.mark.measured
def test_02_mover_range_and_track(cap):
    """A person/object moves at about 1.0-1.9 m: remove static clutter, follow the peak.

    Measured: the track spans ~0.6-2.1 m (median ~1.7 m), so the README's
    "about 1.0 to 1.9 m" holds for the median and the bulk of the frames only.
    """
    x = cap.frames[:, :, :, 0, :].astype(np.complex128)           # [frame, tx, rx, N]
    x = x - x.mean(axis=0, keepdims=True)                           # static clutter out
    n, pad = x.shape[-1], 5
    p = (np.abs(np.fft.fft(x * np.hanning(n), pad * n, axis=-1)) ** 2).sum(axis=(1, 2))
    fs, slope = 2.5e6, 64.598e12                                    # README waveform
    ranges = np.arange(pad * n) * C0 * fs / (2 * slope * pad * n)
    k = np.argmax(p, axis=1)
    r = ranges[k]
    strong = p.max(axis=1) > 30 * np.median(p, axis=1)
    assert strong.mean() > 0.9
    # IQ sign: the mover lies in the positive-frequency half (range < fs c / 4S)
    assert np.mean(k[strong] < pad * n // 2) > 0.95
    rs = r[strong]
    assert 1.0 <= np.median(rs) <= 1.9
    assert np.mean((rs >= 0.55) & (rs <= 2.2)) > 0.9
    # a physical track: frame-to-frame steps (20 ms) well under 0.2 m (< 10 m/s)
    steps = np.abs(np.diff(r))
    assert np.mean(steps < 0.2) > 0.9


@pytest.mark.measured
def test_03_truncated_copy(tmp_path, measured_dir):
    src = measured_file(measured_dir, BIN).read_bytes()
    bad = tmp_path / "truncated.bin"
    bad.write_bytes(src[: 7 * FRAME_BYTES + 1000])
    with pytest.raises(CaptureFormatError) as e:
        read_dca1000(bad)
    msg = str(e.value)
    assert str(bad) in msg and str(FRAME_BYTES) in msg


def test_04_empty_file(tmp_path):
    empty = tmp_path / "empty.bin"
    empty.write_bytes(b"")
    with pytest.raises(CaptureFormatError, match="empty") as e:
        read_dca1000(empty)
    assert str(empty) in str(e.value)
    with pytest.raises(FileNotFoundError):
        read_dca1000(tmp_path / "missing.bin")


def test_05_synthetic_layout_round_trip(tmp_path):
    """Encode [frame][loop][tx slot][rx][sample] by hand; the reader must undo it."""
    radar = RadarConfig.awr1843(num_chirps=2, tdm_order=(2, 0, 1))
    rng = np.random.default_rng(1)
    nf = 3
    want = (rng.integers(-2000, 2000, (nf,) + radar.adc_shape)
            + 1j * rng.integers(-2000, 2000, (nf,) + radar.adc_shape))   # [f, tx, rx, loop, n]
    stream = []
    for f in range(nf):
        for loop in range(radar.num_chirps):
            for tx in radar.tdm_order:
                for rx in range(radar.num_rx):
                    stream.append(want[f, tx, rx, loop])
    path = tmp_path / "synthetic.bin"
    _encode(np.concatenate(stream)).tofile(path)
    got = read_dca1000(path, radar=radar)
    assert got.num_frames == nf
    assert np.array_equal(got.frames, want.astype(np.complex64))
    assert got.metadata["frame_period"] is None
    two = read_dca1000(path, radar=radar, num_frames=2)
    assert np.array_equal(two.frames, want[:2].astype(np.complex64))
    with pytest.raises(CaptureFormatError, match="3 frames"):
        read_dca1000(path, radar=radar, num_frames=5)


def test_06_loader_dispatch(tmp_path):
    radar = RadarConfig.awr1843()
    rng = np.random.default_rng(2)
    data = rng.integers(-100, 100, 4 * 3 * 4 * 128 * 2).astype("<i2")
    path = tmp_path / "capture.bin"
    data.tofile(path)
    cap = load_capture(path)
    assert cap.num_frames == 4 and cap.radar == radar
    one = load_capture(path, frame=2)
    assert one.num_frames == 1 and np.array_equal(one.adc, cap.frames[2])
    with pytest.raises(IndexError, match="4 frame"):
        load_capture(path, frame=4)

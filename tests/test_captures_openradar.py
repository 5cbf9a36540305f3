"""OpenRadar example arrays (.npy)."""
from __future__ import annotations

import numpy as np
import pytest

from conftest import measured_file
from sionna_mmir.captures import load_capture, read_openradar_npy
from sionna_mmir.errors import CaptureFormatError

pytestmark = pytest.mark.measured

DOPPLER = "openradar/openradar_doppler_example_1.npy"
SIMPLE = "openradar/openradar_simple_frame_1.npy"


@pytest.fixture(scope="module")
def doppler(measured_dir):
    return read_openradar_npy(measured_file(measured_dir, DOPPLER))


def _as_int16(path):
    """Independent conversion: the parts are uint16 bit patterns of int16 values."""
    x = np.load(path)
    return (x.real.astype(np.uint16).view(np.int16).astype(np.float64)
            + 1j * x.imag.astype(np.uint16).view(np.int16).astype(np.float64))


def test_01_both_load(measured_dir, doppler):
    assert doppler.frames.shape == (1, 2, 4, 128, 128)
    assert doppler.radar.num_tx == 2 and doppler.radar.num_rx == 4
    # Tx 1 sits 4 lambda/2 from Tx 0 along azimuth: 8 uniform virtual elements
    g = doppler.radar.virtual_grid()[..., 0].reshape(-1)
    assert sorted(np.round(g).astype(int).tolist()) == list(range(8))
    simple = load_capture(measured_file(measured_dir, SIMPLE))
    assert simple.frames.shape == (1, 1, 1, 128, 128)
    assert simple.radar.slope == pytest.approx(60e12) and simple.radar.sample_rate == 2.5e6


def test_02_values_fit_int16(measured_dir, doppler):
    for rel, cap in ((DOPPLER, doppler), (SIMPLE, None)):
        path = measured_file(measured_dir, rel)
        cap = cap or read_openradar_npy(path)
        parts = cap.frames.view(np.float32)
        assert parts.min() >= -32768 and parts.max() <= 32767
        assert np.all(parts == np.round(parts))
        ref = _as_int16(path)
        if ref.ndim == 3:                                   # [chirp, v, N], v = tx*4 + rx
            ref = ref.reshape(128, 2, 4, 128).transpose(1, 2, 0, 3)
        else:
            ref = ref[None, None]
        assert np.array_equal(cap.adc, ref.astype(np.complex64))
        assert np.abs(ref).max() < 1000                     # small signals once signed


def test_03_clear_range_peak(doppler):
    x = doppler.adc.astype(np.complex128)
    x = x - x.mean(axis=-1, keepdims=True)
    p = (np.abs(np.fft.fft(x * np.hanning(128), axis=-1)) ** 2).sum(axis=(0, 1, 2))
    far = p[10:120]                                         # beyond the Tx-Rx leakage
    assert 10 * np.log10(far.max() / np.median(far)) > 15.0


def test_04_leakage_at_positive_beat(doppler):
    """IQ sign: leakage (tiny positive delay) sits at bins 1-3, not at 125-127."""
    x = doppler.adc.astype(np.complex128)
    x = x - x.mean(axis=-1, keepdims=True)
    p = (np.abs(np.fft.fft(x, axis=-1)) ** 2).sum(axis=(0, 1, 2))
    assert p[1:4].sum() > 5 * p[-3:].sum()


def test_05_virtual_index_is_tx_major(doppler):
    """Adjacent-Rx phase steps of the strongest target repeat for both Tx (v = tx*4 + rx)."""
    x = doppler.adc.astype(np.complex128)
    spec = np.fft.fft(x - x.mean(axis=-1, keepdims=True), axis=-1)          # [tx, rx, chirp, bin]
    p = (np.abs(spec) ** 2).sum(axis=(0, 1, 2))
    k = int(np.argmax(p[10:120])) + 10
    s = spec[..., k].reshape(8, 128)                                        # [v, chirp]
    cov = s @ s.conj().T
    steps = np.angle(np.diag(cov, 1), deg=True)                             # v -> v+1
    d = (steps[0:3] - steps[4:7] + 180) % 360 - 180
    assert np.max(np.abs(d)) < 15.0
    # read rx-major instead (Tx 0 = v 0, 2, 4, 6; Tx 1 = v 1, 3, 5, 7) the steps disagree
    sa = np.angle([cov[v, v + 2] for v in (0, 2, 4)], deg=True)
    sb = np.angle([cov[v, v + 2] for v in (1, 3, 5)], deg=True)
    assert np.max(np.abs((sa - sb + 180) % 360 - 180)) > 15.0


def test_06_bad_arrays(tmp_path):
    p = tmp_path / "bad.npy"
    np.save(p, np.zeros((4, 5, 6), complex))
    with pytest.raises(CaptureFormatError, match="shape") as e:
        read_openradar_npy(p)
    assert str(p) in str(e.value)
    np.save(p, np.full((8, 128), -3 + 0j))
    with pytest.raises(CaptureFormatError, match="unsigned 16-bit"):
        read_openradar_npy(p)

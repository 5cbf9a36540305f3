"""TI MMWCAS calibration .mat reader, checked against the real corner captures."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.io

from conftest import measured_file
from sionna_mmir.captures import Capture, read_ti_mat
from sionna_mmir.captures.ti_mat import adc_from_rx_fft
from sionna_mmir.errors import CaptureFormatError
from sionna_mmir.radar import RadarConfig

pytestmark = pytest.mark.measured

C0 = 299_792_458.0
MAT_4M7 = "mmwcas_corner/corner_4m7_slope79.mat"
MAT_6M1 = "mmwcas_corner/corner_6m1_slope79.mat"


def _ti_window(n):
    """The README's window, written out again: w / rms(w), w = 0.5 - 0.5 cos(2 pi k/(N+1))."""
    k = np.arange(1, n + 1)
    w = 0.5 - 0.5 * np.cos(2 * np.pi * k / (n + 1))
    return w / np.sqrt(np.mean(w * w))


def _range_profile(cap, pad=5):
    """Power summed over all channels of a ``pad``x zero-padded Hann range FFT, and its ranges."""
    x = cap.adc[:, :, 0, :].astype(np.complex128)
    n = x.shape[-1]
    nf = pad * n
    p = (np.abs(np.fft.fft(x * np.hanning(n), nf, axis=-1)) ** 2).sum(axis=(0, 1))
    slope = 78.986e12                 # README waveform, not the reader's radar
    fs = 8e6
    ranges = np.arange(nf) * C0 * fs / (2 * slope * nf)
    return p, ranges


def _peak(p, ranges, lo, hi):
    sel = (ranges >= lo) & (ranges <= hi)
    k = np.argmax(np.where(sel, p, -np.inf))
    return ranges[k], p[k]


@pytest.fixture(scope="module")
def cap47(measured_dir):
    return read_ti_mat(measured_file(measured_dir, MAT_4M7))


@pytest.fixture(scope="module")
def cap61(measured_dir):
    return read_ti_mat(measured_file(measured_dir, MAT_6M1))


def test_01_shape_dtype_radar(cap47):
    assert cap47.frames.shape == (1, 12, 16, 1, 256)
    assert cap47.adc.shape == (12, 16, 1, 256)
    assert cap47.frames.dtype == np.complex64
    r = cap47.radar
    # README: 78.986 MHz/us, 8 Msps, 256 samples, loops averaged (1 chirp), device order layout
    assert r.slope == pytest.approx(78.986e12, rel=1e-9)
    assert r.sample_rate == 8e6
    assert r.num_chirps == 1
    ref = RadarConfig.mmwcas(num_chirps=1)
    np.testing.assert_array_equal(r.tx_positions, ref.tx_positions)
    np.testing.assert_array_equal(r.rx_positions, ref.rx_positions)
    assert cap47.metadata["chirps_averaged"] is True
    assert cap47.metadata["frame_period"] is None
    assert cap47.metadata["iq_conjugated"] is False


def test_02_corner_4m7_and_leakage(cap47):
    p, ranges = _range_profile(cap47)
    r_corner, p_corner = _peak(p, ranges, 1.0, 10.0)
    r_leak, p_leak = _peak(p, ranges, 0.0, 1.0)
    assert r_corner == pytest.approx(4.74, abs=0.06)
    assert 0.06 <= r_leak <= 0.3
    # README: leakage about 9 dB under the corner; corner ~43 dB over the noise floor
    gap = 10 * np.log10(p_corner / p_leak)
    assert 4.0 < gap < 15.0
    assert 10 * np.log10(p_corner / np.median(p)) > 35.0


def test_03_corner_6m1_leakage_stronger(cap61):
    p, ranges = _range_profile(cap61)
    r_corner, p_corner = _peak(p, ranges, 1.0, 10.0)
    r_leak, p_leak = _peak(p, ranges, 0.0, 1.0)
    assert r_corner == pytest.approx(6.07, abs=0.06)
    assert 0.06 <= r_leak <= 0.3
    # README: leakage ~26 dB stronger than the corner in this capture
    assert 10 * np.log10(p_leak / p_corner) > 15.0


def test_04_target_at_positive_beat_frequency(cap47):
    """IQ sign: the corner is in the lower half of the plain FFT (no conjugation needed)."""
    x = cap47.adc[:, :, 0, :].astype(np.complex128)
    n = x.shape[-1]
    p = (np.abs(np.fft.fft(x * np.hanning(n), axis=-1)) ** 2).sum(axis=(0, 1))
    expected_bin = round(n * 78.986e12 * 2 * 4.74 / C0 / 8e6)
    k = int(np.argmax(p[8:-8])) + 8            # skip the leakage around DC
    assert abs(k - expected_bin) <= 1
    assert p[k] > 100 * p[n - k]


@pytest.mark.parametrize("rel", [MAT_4M7, MAT_6M1])
def test_05_recovery_is_exact(measured_dir, rel):
    path = measured_file(measured_dir, rel)
    X = scipy.io.loadmat(path)["calibResult"][0, 0]["Rx_fft"]          # [5N, rx, tx enable]
    adc = adc_from_rx_fft(X)                                            # [tx dev, rx, N]
    n = adc.shape[-1]
    # re-FFT in the file's own layout: Tx enable order is device order reversed
    again = np.fft.fft(adc[::-1].transpose(2, 1, 0) * _ti_window(n)[:, None, None], 5 * n, axis=0)
    assert np.max(np.abs(again - X)) / np.max(np.abs(X)) < 1e-9
    # the complex64 capture holds the same numbers to float32 precision
    cap = read_ti_mat(path)
    d = np.abs(cap.adc[:, :, 0, :] - adc).max() / np.abs(adc).max()
    assert d < 1e-6


def test_06_rangemat_peakvalmat_indexing(measured_dir, cap47):
    """extras are [device Tx, device Rx]: own 5x peak bins agree with TI's RangeMat within 1 bin."""
    x = cap47.adc[:, :, 0, :].astype(np.complex128)
    n = x.shape[-1]
    spec = np.fft.fft(x * _ti_window(n), 5 * n, axis=-1)               # [tx, rx, 5N]
    lo, hi = 300, 500                                                   # corner near bin 400
    own = np.argmax(np.abs(spec[:, :, lo:hi]), axis=-1) + lo + 1        # 1-based like MATLAB
    rm = cap47.extras["RangeMat"]
    assert rm.shape == (12, 16)
    assert np.max(np.abs(own - rm)) <= 1
    # and TI's peak values are our spectra at TI's bins (float32 ADC -> ~1e-6)
    pv = cap47.extras["PeakValMat"]
    ours = np.take_along_axis(spec, (rm - 1)[..., None].astype(int), -1)[..., 0]
    assert np.max(np.abs(ours - pv) / np.abs(pv)) < 1e-4
    # the un-reversed Tx order would not match the peak values
    assert np.median(np.abs(ours[::-1] - pv) / np.abs(pv)) > 0.1
    # AngleMat is the phase of PeakValMat [deg], same indexing
    d = np.angle(np.exp(1j * (np.radians(cap47.extras["AngleMat"]) - np.angle(pv))))
    assert np.max(np.abs(d)) < 1e-9
    # TxMismatch (device order) ~ circular mean over Rx of the phase relative to Tx 1
    tm = np.angle(np.mean(pv / np.abs(pv) * np.conj(pv[:1] / np.abs(pv[:1])), axis=1), deg=True)
    dd = (cap47.extras["TxMismatch"] - tm + 180) % 360 - 180
    assert np.max(np.abs(dd)) < 2.0


def test_07_hdf5_round_trip(tmp_path, cap47):
    out = cap47.save(tmp_path / "c.h5")
    back = Capture.load(out)
    assert np.array_equal(back.frames, cap47.frames)
    assert back.radar == cap47.radar
    assert back.metadata == cap47.metadata
    assert set(back.extras) == set(cap47.extras)
    for k, v in cap47.extras.items():
        assert np.array_equal(back.extras[k], v) and back.extras[k].dtype == v.dtype


def test_08_bad_files(tmp_path):
    p = tmp_path / "nocalib.mat"
    scipy.io.savemat(p, {"params": {"Slope_MHzperus": 79.0, "Sampling_Rate_sps": 8e6}})
    with pytest.raises(CaptureFormatError, match="calibResult") as e:
        read_ti_mat(p)
    assert str(p) in str(e.value)
    p2 = tmp_path / "norxfft.mat"
    scipy.io.savemat(p2, {"calibResult": {"RangeMat": np.zeros((12, 16))},
                          "params": {"Slope_MHzperus": 79.0, "Sampling_Rate_sps": 8e6}})
    with pytest.raises(CaptureFormatError, match="Rx_fft"):
        read_ti_mat(p2)
    p3 = tmp_path / "real.mat"
    scipy.io.savemat(p3, {"calibResult": {"Rx_fft": np.ones((1280, 16, 12))},
                          "params": {"Slope_MHzperus": 79.0, "Sampling_Rate_sps": 8e6}})
    with pytest.raises(CaptureFormatError, match="complex"):
        read_ti_mat(p3)
    p4 = tmp_path / "shape.mat"
    scipy.io.savemat(p4, {"calibResult": {"Rx_fft": np.ones((1280, 12, 16), complex)},
                          "params": {"Slope_MHzperus": 79.0, "Sampling_Rate_sps": 8e6}})
    with pytest.raises(CaptureFormatError, match="shape") as e:
        read_ti_mat(p4)
    assert str(p4) in str(e.value)
    p5 = tmp_path / "text.mat"
    p5.write_text("not a mat file")
    with pytest.raises(CaptureFormatError, match="text.mat"):
        read_ti_mat(p5)

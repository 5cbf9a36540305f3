"""DCA1000 .bin reader: the measured AWR1843 capture and synthetic files."""
from __future__ import annotations

import numpy as np
import pytest

from conftest import measured_file
from sionna_mmir.captures import load_capture, read_dca1000
from sionna_mmir.captures.dca1000 import (LAYOUTS, decode_dca1000, default_frame_period,
                                          default_radar, frame_bytes)
from sionna_mmir.errors import CaptureFormatError, InputValueError
from sionna_mmir.radar import RadarConfig

C0 = 299_792_458.0
BIN = "awr1843_dca1000/moving_target_500frames.bin"
FRAME_BYTES = 3 * 4 * 128 * 2 * 2          # README: 3 Tx x 4 Rx x 128 complex int16 samples
SLOPE, F0 = 64.598e12, 77e9                # README waveform


def _encode(stream: np.ndarray) -> np.ndarray:
    """Complex stream -> int16 in the DCA1000 groups [I(k) I(k+1) Q(k) Q(k+1)]."""
    z = stream.reshape(-1, 2)
    g = np.stack([z[:, 0].real, z[:, 1].real, z[:, 0].imag, z[:, 1].imag], axis=1)
    return g.astype("<i2").reshape(-1)


# ------------------------------------------------ hand-written encoders, one chirp block each
def _enc_ti(block):                        # block [n_rx, N] complex -> int16
    return np.concatenate([_encode(np.round(b)) for b in block])


def _enc_iq(block):
    out = np.empty((block.shape[0], block.shape[1], 2))
    out[..., 0], out[..., 1] = np.round(block.real), np.round(block.imag)
    return out.astype("<i2").reshape(-1)


def _enc_two_rx(block):                    # [I(rx a) I(rx b) Q(rx a) Q(rx b)] per sample
    out = []
    for a, b in zip(block[0::2], block[1::2]):
        g = np.stack([a.real, b.real, a.imag, b.imag], axis=1)
        out.append(np.round(g).astype("<i2").reshape(-1))
    return np.concatenate(out)


def _enc_real(block):                      # block is already real
    return np.round(block).astype("<i2").reshape(-1)


def _enc_pairs(stream_block):              # [n_rx, 2N] stream at twice the output rate
    out = []
    for s in stream_block:
        a, b = s[0::4], s[1::4]            # samples 4k and 4k+1 kept, 4k+2, 4k+3 dropped
        g = np.stack([a.real, b.real, a.imag, b.imag], axis=1)
        out.append(np.round(g).astype("<i2").reshape(-1))
    return np.concatenate(out)


@pytest.fixture(scope="module")
def cap(measured_dir):
    return read_dca1000(measured_file(measured_dir, BIN), layout="ti")


@pytest.fixture(scope="module")
def pairs_cap(measured_dir):
    return read_dca1000(measured_file(measured_dir, BIN))


@pytest.mark.measured
def test_01_measured_loads(cap, measured_dir):
    """TI's reading (layout="ti"): 500 frames of 3 x 4 x 128 int16 counts."""
    assert cap.num_frames == 500
    assert cap.frames.shape == (500, 3, 4, 1, 128)
    assert cap.frames.dtype == np.complex64
    assert cap.metadata["frame_period"] == pytest.approx(0.02)
    assert cap.metadata["layout"] == "ti"
    assert cap.radar.num_tx == 3 and cap.radar.num_rx == 4
    assert (measured_dir / BIN).stat().st_size == 500 * FRAME_BYTES
    # int16 counts: every part is an integer within int16
    parts = cap.frames.view(np.float32)
    assert np.all(parts == np.round(parts)) and parts.min() >= -32768 and parts.max() <= 32767


@pytest.mark.measured
def test_02_mover_range_and_track(cap):
    """TI's reading puts the mover at about 1.0-1.9 m (the README's numbers).

    Measured: the track spans ~0.6-2.1 m (median ~1.7 m).  test_10 shows why
    this reading is not the default.
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
    for layout, fb in (("ti", FRAME_BYTES), ("pairs", FRAME_BYTES // 2)):
        with pytest.raises(CaptureFormatError) as e:
            read_dca1000(bad, layout=layout)
        msg = str(e.value)
        assert str(bad) in msg and str(fb) in msg and layout in msg
    with pytest.raises(CaptureFormatError, match=str(FRAME_BYTES // 2)):
        read_dca1000(bad)                                      # default layout: pairs


def test_04_empty_file(tmp_path):
    empty = tmp_path / "empty.bin"
    empty.write_bytes(b"")
    for layout in LAYOUTS:
        with pytest.raises(CaptureFormatError, match="empty") as e:
            read_dca1000(empty, layout=layout)
        assert str(empty) in str(e.value)
    with pytest.raises(FileNotFoundError):
        read_dca1000(tmp_path / "missing.bin")


def test_05_synthetic_layout_round_trip(tmp_path):
    """Encode [frame][loop][tx slot][rx][sample] by hand; the TI reader must undo it."""
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
    got = read_dca1000(path, radar=radar, layout="ti")
    assert got.num_frames == nf
    assert np.array_equal(got.frames, want.astype(np.complex64))
    assert got.metadata["frame_period"] is None
    two = read_dca1000(path, radar=radar, num_frames=2, layout="ti")
    assert np.array_equal(two.frames, want[:2].astype(np.complex64))
    with pytest.raises(CaptureFormatError, match="3 frames"):
        read_dca1000(path, radar=radar, num_frames=5, layout="ti")
    # the flat TI stream decode is unchanged
    flat = decode_dca1000(_encode(np.concatenate(stream)), layout="ti")
    assert np.array_equal(flat, np.concatenate(stream).astype(np.complex64))


def test_06_loader_dispatch(tmp_path):
    rng = np.random.default_rng(2)
    data = rng.integers(-100, 100, 4 * 3 * 4 * 128 * 2).astype("<i2")   # 4 x 6144 bytes
    path = tmp_path / "capture.bin"
    data.tofile(path)
    cap = load_capture(path)                       # default layout "pairs": 8 x 3 x 4 x 64
    assert cap.num_frames == 8 and cap.radar == default_radar("pairs")
    assert cap.radar.num_samples == 64 and cap.radar.sample_rate == 1.25e6
    assert cap.metadata["frame_period"] == pytest.approx(0.01)
    one = load_capture(path, frame=2)
    assert one.num_frames == 1 and np.array_equal(one.adc, cap.frames[2])
    with pytest.raises(IndexError, match="8 frame"):
        load_capture(path, frame=8)
    ti = load_capture(path, radar=RadarConfig.awr1843())
    assert ti.num_frames == 4                      # an explicit radar sets the frame size


@pytest.mark.parametrize("layout", LAYOUTS)
def test_07_synthetic_tones_per_layout(tmp_path, layout):
    """Known tone per (frame, loop, tx, rx), hand-encoded: the decoder recovers bin and phase.

    The channel's bin and phase both encode (tx, rx, loop, frame), so a wrong
    Tx / Rx / loop order or a wrong I/Q convention fails too.
    """
    n = 32
    radar = RadarConfig.awr1843(num_chirps=2, tdm_order=(2, 0, 1), num_samples=n,
                                sample_rate=1.25e6)
    nf, amp = 2, 3000.0
    bins = np.empty((nf, 3, 4, 2), int)
    phases = np.empty((nf, 3, 4, 2))
    chunks = []
    for f in range(nf):
        for loop in range(radar.num_chirps):
            for tx in radar.tdm_order:
                k = 1 + (tx * 4 + np.arange(4) + 5 * loop + 3 * f) % (n // 2 - 2)   # < N/2
                ph = 0.3 + 0.5 * np.arange(4) + 1.1 * tx - 0.7 * loop + 0.9 * f
                bins[f, tx, :, loop], phases[f, tx, :, loop] = k, ph
                m = np.arange(n)
                if layout == "pairs":          # stream at twice the rate, 2N samples
                    s = np.arange(2 * n)
                    block = amp * np.exp(1j * (np.pi * k[:, None] * s[None] / n + ph[:, None]))
                    chunks.append(_enc_pairs(block))
                elif layout == "real":
                    block = amp * np.cos(2 * np.pi * k[:, None] * m[None] / n + ph[:, None])
                    chunks.append(_enc_real(block))
                else:
                    block = amp * np.exp(1j * (2 * np.pi * k[:, None] * m[None] / n
                                               + ph[:, None]))
                    chunks.append({"ti": _enc_ti, "iq": _enc_iq,
                                   "two_rx": _enc_two_rx}[layout](block))
    path = tmp_path / f"{layout}.bin"
    raw = np.concatenate(chunks)
    raw.tofile(path)
    assert path.stat().st_size == nf * frame_bytes(radar, layout)
    got = read_dca1000(path, radar=radar, layout=layout)
    assert got.frames.shape == (nf,) + radar.adc_shape and got.metadata["layout"] == layout
    spec = np.fft.fft(got.frames.astype(np.complex128), axis=-1)          # [f, tx, rx, loop, N]
    assert np.array_equal(np.argmax(np.abs(spec), axis=-1), bins)
    peak = np.take_along_axis(spec, bins[..., None], axis=-1)[..., 0]
    err = np.angle(peak * np.exp(-1j * phases))
    assert np.max(np.abs(err)) < 2e-3
    # one clean tone: no image anywhere else in the spectrum
    rest = np.abs(spec) ** 2
    np.put_along_axis(rest, bins[..., None], 0.0, axis=-1)
    assert rest.max() < 1e-5 * np.max(np.abs(peak) ** 2)


def test_08_pairs_rebuild_off_bin_tones():
    """Off-bin tones through the pairs rebuild: stored samples exact, windowed spectrum
    within -30 dB of the uniformly sampled truth over the band, IQ sign kept."""
    n = 64
    s = np.arange(2 * n)
    for w in (0.05, 0.3, 0.7, 0.93, 1.5, 2.5):                 # rad per stream sample
        truth = 1000 * np.exp(1j * (w * s + 0.4))
        g = np.stack([truth[0::4].real, truth[1::4].real, truth[0::4].imag,
                      truth[1::4].imag], axis=1).reshape(-1)
        z = decode_dca1000(g, layout="pairs", num_samples=n)[0].astype(np.complex128)
        assert np.allclose(z[0::2], truth[0::4], atol=1e-6 * 1000)
        h = np.hanning(n)
        Z, T = np.fft.fft(z * h), np.fft.fft(truth[0::2] * h)
        assert np.sum(np.abs(Z - T) ** 2) < 1e-3 * np.sum(np.abs(T) ** 2)
        assert np.argmax(np.abs(Z)) == np.argmax(np.abs(T)) == round(w * 2 * n / (2 * np.pi))


def _moving(frames):
    x = frames[:, :, :, 0, :].astype(np.complex128)
    return x - x.mean(axis=0, keepdims=True)


def _track(x, pad=8):
    """Fine range bin of the strongest moving return per frame (parabolic peak)."""
    n = x.shape[-1]
    p = (np.abs(np.fft.fft(x * np.hanning(n), pad * n, axis=-1)) ** 2).sum(axis=(1, 2))
    i = np.argmax(p, axis=1)
    t = np.arange(len(i))
    lp = np.log(p + 1e-30)
    lo, hi = lp[t, (i - 1) % (pad * n)], lp[t, (i + 1) % (pad * n)]
    d = 0.5 * (lo - hi) / (lo - 2 * lp[t, i] + hi)
    return (i + np.clip(d, -0.5, 0.5)) / pad


@pytest.mark.measured
def test_09_measured_pairs_layout_is_physical(pairs_cap):
    """The default reading passes the physical checks of scripts/dca1000_layout_evidence.py."""
    cap = pairs_cap
    assert cap.frames.shape == (1000, 3, 4, 1, 64)
    assert cap.metadata["layout"] == "pairs" and cap.metadata["frames_in_file"] == 1000
    assert cap.metadata["frame_period"] == pytest.approx(0.01)
    assert cap.radar.sample_rate == 1.25e6 and cap.radar.num_samples == 64
    even = np.ascontiguousarray(cap.frames[..., 0::2]).view(np.float32)   # stored samples
    assert np.all(np.abs(even - np.round(even)) < 1e-3)
    x = _moving(cap.frames)
    n = x.shape[-1]
    bw = C0 * cap.radar.sample_rate / (2 * SLOPE * n)                    # 4.54 cm
    # 1. moving energy balanced over even / odd bins (TI: 0.94)
    p = (np.abs(np.fft.fft(x, axis=-1)) ** 2).sum(axis=(0, 1, 2))
    assert 0.3 < p[0::2].sum() / p.sum() < 0.7
    # 2. leakage below 15 cm: coherent over the 1000 frames (TI: 0.61)
    X = np.fft.fft(cap.frames[:, :, :, 0, :] * np.hanning(n), axis=-1)
    near = slice(0, 3)
    coh = (np.abs(X.mean(axis=0)[..., near]) ** 2).sum() / (np.abs(X[..., near]) ** 2).mean(0).sum()
    assert coh > 0.95
    # 3. a smooth track: steps under 4 cm per 20 ms (two frames)
    kf = _track(x)
    r = kf * bw
    assert np.mean(np.abs(np.diff(r)) * 2 < 0.04) > 0.99
    assert 0.6 < np.median(r) < 1.1                         # README says about 1.0-1.9 m
    # 4. one plane wave over Tx x Rx at the mover: rank-1 share (TI: 0.75)
    kb = np.round(kf).astype(int) % n
    Y = np.fft.fft(x * np.hanning(n), axis=-1)[np.arange(len(kf)), :, :, kb]
    sv = np.linalg.svd(Y, compute_uv=False)
    assert np.mean(sv[:, 0] ** 2 / (sv ** 2).sum(axis=1)) > 0.95
    # 5. Doppler phase step between frames vs range track measures the bin width
    lam = C0 / (F0 + SLOPE * (8.66e-6 + 25.6e-6))
    inc = np.exp(1j * np.angle((Y[1:] * Y[:-1].conj()).sum(axis=(1, 2))))
    ker = np.ones(5) / 5
    ph = np.angle(np.convolve(inc, ker, mode="same"))[5:-5]
    dk = np.diff(np.convolve(kf, ker, mode="same"))[5:-5]
    grid = np.linspace(0.01, 0.12, 221)
    R = np.abs(np.exp(1j * (ph[None] - 4 * np.pi * grid[:, None] * dk[None] / lam)).mean(axis=1))
    assert abs(grid[np.argmax(R)] - bw) < 0.15 * bw and R.max() > 0.6


@pytest.mark.measured
def test_10_measured_ti_layout_pathologies(cap):
    """Why "ti" is not the default: its chirps are two near-copies (even bins), every
    tone has an image N/2 up, the leakage is not stable and Tx x Rx is not rank 1."""
    x = _moving(cap.frames)
    n = x.shape[-1]
    p = (np.abs(np.fft.fft(x, axis=-1)) ** 2).sum(axis=(0, 1, 2))
    assert p[0::2].sum() / p.sum() > 0.9
    P = (np.abs(np.fft.fft(x * np.hanning(n), axis=-1)) ** 2).sum(axis=(1, 2))
    k = np.argmax(P, axis=1)
    t = np.arange(len(k))
    assert np.median(P[t, (k + n // 2) % n] / P[t, k]) > 0.1          # image within 10 dB
    X = np.fft.fft(cap.frames[:, :, :, 0, :] * np.hanning(n), axis=-1)
    near = slice(0, 3)
    coh = (np.abs(X.mean(axis=0)[..., near]) ** 2).sum() / (np.abs(X[..., near]) ** 2).mean(0).sum()
    assert coh < 0.8
    Y = np.fft.fft(x * np.hanning(n), axis=-1)[t, :, :, k]
    sv = np.linalg.svd(Y, compute_uv=False)
    assert np.mean(sv[:, 0] ** 2 / (sv ** 2).sum(axis=1)) < 0.85


def test_11_bad_arguments(tmp_path):
    radar = RadarConfig.awr1843()
    path = tmp_path / "c.bin"
    np.zeros(frame_bytes(radar, "ti") // 2 * 2, "<i2").tofile(path)
    with pytest.raises(InputValueError, match="layout"):
        read_dca1000(path, layout="tii")
    for bad in (0, -1, 1.5):
        with pytest.raises(InputValueError, match="num_frames"):
            read_dca1000(path, num_frames=bad)
    with pytest.raises(CaptureFormatError, match="even"):
        read_dca1000(path, radar=RadarConfig.awr1843(num_samples=63), layout="pairs")
    with pytest.raises(InputValueError, match="num_samples"):
        decode_dca1000(np.zeros(8, "<i2"), layout="pairs")
    with pytest.raises(CaptureFormatError, match="blocks"):
        decode_dca1000(np.zeros(10, "<i2"), layout="pairs", num_samples=4)
    assert default_frame_period("pairs") == pytest.approx(0.01)
    assert default_frame_period("ti") == pytest.approx(0.02)
    assert frame_bytes(default_radar("real"), "real") == FRAME_BYTES
    assert frame_bytes(default_radar(), "pairs") == FRAME_BYTES // 2

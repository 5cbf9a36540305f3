"""ADC synthesis (paper eq. 4): physics, reference twin, gradients, bad input."""
import numpy as np
import pytest

from sionna_mmir import RadarConfig, SPEED_OF_LIGHT
from sionna_mmir.errors import InputValueError
from sionna_mmir.fmcw import synthesize_adc, synthesize_adc_basic

C = SPEED_OF_LIGHT


def _random_paths(radar, P, seed=0, moving=False):
    rng = np.random.default_rng(seed)
    shape = (radar.num_tx, radar.num_rx, P)
    a = rng.normal(size=shape) + 1j * rng.normal(size=shape)
    tau = rng.uniform(1e-9, 0.9 * 2 * radar.max_range / C, size=shape)
    rho = rng.uniform(-2e-7, 2e-7, size=shape) if moving else None
    return a, tau, rho


@pytest.mark.parametrize("moving", [False, True])
def test_01_fast_matches_reference_twin(moving):
    radar = RadarConfig.mmwcas(num_chirps=3)
    a, tau, rho = _random_paths(radar, 40, moving=moving)
    fast = synthesize_adc(radar, a, tau, rho)
    ref = synthesize_adc_basic(radar, a, tau, rho)
    assert fast.shape == radar.adc_shape and fast.dtype == np.complex64
    assert np.abs(fast - ref).max() / np.abs(ref).max() < 2e-4


def test_02_point_target_beat_frequency_and_phase():
    """One path: beat frequency S*tau and phase 2pi(f0 + S t_k) tau, by hand."""
    radar = RadarConfig.awr1843()
    R = 3.1
    tau = 2 * R / C
    s = synthesize_adc(radar, np.array([1.0 + 0j]), np.array([tau]))[0, 0, 0]
    n_fft = 64 * radar.num_samples
    peak = np.argmax(np.abs(np.fft.fft(s, n_fft)))
    f_beat = peak * radar.sample_rate / n_fft
    assert abs(f_beat - radar.slope * tau) < radar.sample_rate / n_fft
    t0 = radar.adc_start_time
    expected_phase = 2 * np.pi * (radar.start_frequency + radar.slope * t0) * tau
    assert abs(np.angle(s[0] * np.exp(-1j * expected_phase))) < 1e-3
    assert np.allclose(np.abs(s), 1.0, atol=1e-4)


def test_03_doppler_phase_across_chirps_and_tdm_slots():
    """A receding target advances the phase by 2 pi f0 (2v/c) dt between chirps."""
    radar = RadarConfig.awr1843(num_chirps=8)
    v = 1.5
    rho = 2 * v / C
    s = synthesize_adc(radar, np.array([1.0 + 0j]), np.array([2 * 2.0 / C]), np.array([rho]))
    lam0 = C / radar.start_frequency
    # same Tx, consecutive loops: loop period apart
    dphi = np.angle(s[0, 0, 1, 0] * np.conj(s[0, 0, 0, 0]))
    expected = 2 * np.pi * (radar.start_frequency + radar.slope * radar.adc_start_time) \
        * rho * radar.loop_period
    assert abs(np.angle(np.exp(1j * (dphi - expected)))) < 1e-3
    # Tx 1 fires one chirp period after Tx 0 (TDM): Doppler phase between slots
    d_slot = np.angle(s[1, 0, 0, 0] * np.conj(s[0, 0, 0, 0]))
    geom = np.angle(synthesize_adc(radar, np.array([1.0 + 0j]), np.array([2 * 2.0 / C]))[1, 0, 0, 0]
                    * np.conj(synthesize_adc(radar, np.array([1.0 + 0j]), np.array([2 * 2.0 / C]))[0, 0, 0, 0]))
    exp_slot = 2 * np.pi * (radar.start_frequency + radar.slope * radar.adc_start_time) * rho * radar.chirp_period
    assert abs(np.angle(np.exp(1j * (d_slot - geom - exp_slot)))) < 1e-3
    assert 2 * v / lam0 > 0


def test_04_broadcast_and_static_chirps_identical():
    radar = RadarConfig.awr1843(num_chirps=4)
    tau = np.array([1e-8, 2e-8])
    s1 = synthesize_adc(radar, np.array([1.0, 0.5j]), tau)
    s2 = synthesize_adc(radar, np.broadcast_to(np.array([1.0, 0.5j]), (3, 4, 2)),
                        np.broadcast_to(tau, (3, 4, 2)))
    assert np.array_equal(s1, s2)
    assert np.array_equal(s1[:, :, 0], s1[:, :, 3])


@pytest.mark.parametrize("bad", ["nan_a", "inf_tau", "shape", "paths"])
def test_05_bad_input_named(bad):
    radar = RadarConfig.awr1843()
    a, tau = np.ones((3, 4, 2), complex), np.full((3, 4, 2), 1e-8)
    if bad == "nan_a":
        a[1, 1, 0] = np.nan
        match = "'a' holds NaN"
    elif bad == "inf_tau":
        tau[0, 0, 1] = np.inf
        match = "'tau' holds NaN"
    elif bad == "shape":
        a = np.ones((2, 4, 2), complex)
        match = "radar has 3 tx"
    else:
        a = np.ones((3, 4, 3), complex)
        match = "path counts differ"
    with pytest.raises(InputValueError, match=match):
        synthesize_adc(radar, a, tau)


def _drjit():
    import sionna_mmir

    sionna_mmir.init_backend()
    import drjit as dr
    import mitsuba as mi
    return dr, mi


def _loss_np(radar, W, a, tau, rho):
    s = synthesize_adc_basic(radar, a, tau, rho)
    return float(np.sum(np.abs(s) ** 2 * np.abs(W)) + np.sum(np.real(s * np.conj(W))) ** 2 / 100)


@pytest.mark.parametrize("moving", [False, True])
def test_06_gradients_match_central_differences(moving):
    """Reverse-mode AD through the Dr.Jit node vs central differences (< 2 %)."""
    dr, mi = _drjit()
    radar = RadarConfig.awr1843(num_chirps=4)
    rng = np.random.default_rng(3)
    P = 3
    shape = (3, 4, P)
    f32 = lambda x: x.astype(np.float32).astype(np.float64)
    a = f32(rng.normal(size=shape)) + 1j * f32(rng.normal(size=shape))
    tau = f32(rng.uniform(1e-8, 3e-8, size=shape))
    rho = f32(rng.uniform(-1e-7, 1e-7, size=shape)) if moving else None
    W = rng.normal(size=radar.adc_shape) + 1j * rng.normal(size=radar.adc_shape)

    t_ar, t_ai, t_tau = (mi.TensorXf(x.astype(np.float32)) for x in (a.real, a.imag, tau))
    t_rho = mi.TensorXf(rho.astype(np.float32)) if moving else None
    for x in (t_ar, t_ai, t_tau, t_rho):
        if x is not None:
            dr.enable_grad(x)
    out = synthesize_adc(radar, (t_ar, t_ai), t_tau, t_rho)
    Wr, Wi = mi.TensorXf(W.real.astype(np.float32)), mi.TensorXf(W.imag.astype(np.float32))
    absW = mi.TensorXf(np.abs(W).astype(np.float32))
    loss = (dr.sum((out.real ** 2 + out.imag ** 2) * absW, axis=None)
            + dr.sum(out.real * Wr + out.imag * Wi, axis=None) ** 2 / 100)
    dr.backward(loss)
    checks = [("a_re", t_ar, 0, 1e-5, 1.0), ("a_im", t_ai, 0, 1e-5, 1j), ("tau", t_tau, 1, 1e-15, 1.0)]
    if moving:
        checks.append(("rho", t_rho, 2, 1e-11, 1.0))
    for name, t, k, h, unit in checks:
        g = np.array(dr.grad(t)).reshape(shape)
        for idx in [(0, 0, 0), (2, 3, 1), (1, 2, 2)]:
            args = [a.copy(), tau.copy(), None if rho is None else rho.copy()]
            args[k] = args[k].astype(complex) if k == 0 else args[k]
            args[k][idx] += h * unit
            lp = _loss_np(radar, W, *args)
            args[k][idx] -= 2 * h * unit
            lm = _loss_np(radar, W, *args)
            fd = (lp - lm) / (2 * h)
            assert abs(g[idx] - fd) <= 0.02 * abs(fd) + 1e-6 * np.abs(g).max(), (name, idx, g[idx], fd)


def test_07_forward_mode_matches_reverse_mode():
    dr, mi = _drjit()
    radar = RadarConfig.awr1843(num_chirps=2)
    rng = np.random.default_rng(5)
    tau = mi.TensorXf(rng.uniform(1e-8, 3e-8, size=(3, 4, 2)).astype(np.float32))
    a_re = mi.TensorXf(np.ones((3, 4, 2), np.float32))
    a_im = mi.TensorXf(np.zeros((3, 4, 2), np.float32))
    dr.enable_grad(tau)
    out = synthesize_adc(radar, (a_re, a_im), tau)
    loss = dr.sum(out.real * out.real * 0.0 + out.real, axis=None)
    dr.forward(tau)   # tangent = 1 in every entry
    fwd = float(np.array(dr.grad(loss)).ravel()[0])
    dr.enable_grad(tau)
    out = synthesize_adc(radar, (a_re, a_im), tau)
    loss = dr.sum(out.real, axis=None)
    dr.backward(loss)
    rev = float(np.sum(np.array(dr.grad(tau))))
    assert abs(fwd - rev) <= 1e-3 * abs(rev)


def test_08_drjit_nan_rejected():
    dr, mi = _drjit()
    radar = RadarConfig.awr1843()
    a = mi.TensorXf(np.array([[[np.nan]]] * 1, np.float32).reshape(1, 1, 1))
    with pytest.raises(InputValueError, match="NaN"):
        synthesize_adc(radar, (a, a), mi.TensorXf(np.full((1, 1, 1), 1e-8, np.float32)))


def test_09_matches_sionna_rt_frequency_response():
    """Sionna RT's own ``Paths.cfr`` at f_k = f0 + S t_k gives the same ADC (conj convention).

    Tolerance 1e-2: Sionna evaluates 2 pi f tau in float32 (f tau ~ 1e4 cycles).
    """
    import pathlib
    import sys

    sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "benchmarks"))
    _drjit()
    from sionna_cfr import sionna_beat_signal

    radar = RadarConfig.awr1843()
    a, tau, _ = _random_paths(radar, 8, seed=11)
    ours = synthesize_adc(radar, a, tau)
    theirs = sionna_beat_signal(radar, a, tau)
    assert np.abs(ours - theirs).max() / np.abs(ours).max() < 1e-2
    # and a deliberately wrong sign convention is far off
    wrong = np.conj(ours)
    assert np.abs(wrong - theirs).max() / np.abs(ours).max() > 0.5

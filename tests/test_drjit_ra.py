"""Differentiable range-azimuth maps and RA loss (Dr.Jit custom op): values, VJP, JVP, errors."""
import numpy as np
import pytest

from sionna_mmir import RadarConfig
from sionna_mmir.errors import ConfigError, InputValueError
from sionna_mmir.metrics.ra import ra_loss
from sionna_mmir.processing.imaging import range_azimuth

from helpers import direct_adc, point_target_delays, target_at


def _drjit():
    import sionna_mmir

    sionna_mmir.init_backend()
    import drjit as dr
    import mitsuba as mi
    return dr, mi


def _small_radar(**kw):
    """AWR1843 with few chirps and samples (fast); options go to ``replace``."""
    return RadarConfig.awr1843(num_chirps=4).replace(num_samples=32, **kw)


def _random_adc(radar, seed):
    """Random complex ADC whose float32 values are exact in float64 too."""
    rng = np.random.default_rng(seed)
    x = rng.normal(size=radar.adc_shape) + 1j * rng.normal(size=radar.adc_shape)
    return x.astype(np.complex64).astype(np.complex128)


def _tensors(x, grad=False):
    dr, mi = _drjit()
    re = mi.TensorXf(np.ascontiguousarray(x.real, np.float32))
    im = mi.TensorXf(np.ascontiguousarray(x.imag, np.float32))
    if grad:
        dr.enable_grad(re, im)
    return re, im


def _grad_complex(re, im, shape):
    dr, _ = _drjit()
    return (np.asarray(dr.grad(re).array, np.float64).reshape(shape)
            + 1j * np.asarray(dr.grad(im).array, np.float64).reshape(shape))


def _central_fd(f, x, idx, h):
    """Central differences of real ``f`` at ``x[idx]`` along Re and Im: ``df/dRe + j df/dIm``."""
    out = []
    for unit in (1.0, 1j):
        xp, xm = x.copy(), x.copy()
        xp[idx] += h * unit
        xm[idx] -= h * unit
        out.append((f(xp) - f(xm)) / (2 * h))
    return out[0] + 1j * out[1]


CASES = [dict(doppler="mean"),
         dict(doppler="noncoherent"),
         dict(doppler="mean", range_window="blackman", azimuth_window="taylor", n_range=40,
              n_azimuth=63),
         dict(doppler="noncoherent", tdm_compensation=False, doppler_window="hamming",
              n_range=48)]


@pytest.mark.parametrize("kw", CASES, ids=["mean", "noncoherent", "mean-opts", "nc-opts"])
def test_01_forward_equals_numpy_range_azimuth(kw):
    from sionna_mmir.processing.drjit_ra import range_azimuth_drjit
    from sionna_mmir.fmcw import DrAdc

    _, mi = _drjit()
    radar = _small_radar()
    x = _random_adc(radar, 1)
    ra = range_azimuth_drjit(DrAdc(*_tensors(x)), radar, **kw)
    ref = range_azimuth(x.astype(np.complex64), radar, **kw)[0]
    assert isinstance(ra, mi.TensorXf) and tuple(ra.shape) == ref.shape
    np.testing.assert_allclose(ra.numpy(), ref, rtol=1e-6, atol=1e-6 * ref.max())


def test_02_forward_negative_slope_and_cascade():
    from sionna_mmir.processing.drjit_ra import range_azimuth_drjit

    radar = _small_radar(slope=-64.598e12)
    x = _random_adc(radar, 2)
    ra = range_azimuth_drjit(_tensors(x), radar, doppler="noncoherent").numpy()
    ref = range_azimuth(x.astype(np.complex64), radar, doppler="noncoherent")[0]
    np.testing.assert_allclose(ra, ref, rtol=1e-6, atol=1e-6 * ref.max())

    cascade = RadarConfig.mmwcas(num_chirps=2)
    x = _random_adc(cascade, 3)
    ra = range_azimuth_drjit(_tensors(x), cascade).numpy()
    ref = range_azimuth(x.astype(np.complex64), cascade)[0]
    assert ra.shape == (256, 128)
    np.testing.assert_allclose(ra, ref, rtol=1e-6, atol=1e-6 * ref.max())


@pytest.mark.parametrize("kw", CASES, ids=["mean", "noncoherent", "mean-opts", "nc-opts"])
def test_03_vjp_of_weighted_map_matches_central_differences(kw):
    """Reverse mode of sum(W * RA) vs float64 central differences at random ADC entries."""
    from sionna_mmir.processing.drjit_ra import range_azimuth_drjit

    dr, mi = _drjit()
    radar = (_small_radar(slope=-64.598e12, num_chirps=5) if kw.get("tdm_compensation") is False
             else _small_radar())
    x = _random_adc(radar, 4)
    re, im = _tensors(x, grad=True)
    ra = range_azimuth_drjit((re, im), radar, **kw)
    W = np.random.default_rng(5).uniform(-1, 1, size=tuple(ra.shape))
    dr.backward(dr.sum(ra * mi.TensorXf(W.astype(np.float32)), axis=None))
    g = _grad_complex(re, im, radar.adc_shape)

    def f(xx):
        return float(np.sum(W * range_azimuth(xx, radar, **kw)[0]))

    rng = np.random.default_rng(6)
    for _ in range(4):
        idx = tuple(int(rng.integers(n)) for n in radar.adc_shape)
        fd = _central_fd(f, x, idx, 1e-5)
        assert abs(g[idx] - fd) <= 1e-3 * abs(fd) + 1e-4 * np.abs(g).max(), (idx, g[idx], fd)


@pytest.mark.parametrize("doppler", ["mean", "noncoherent"])
def test_04_loss_gradient_from_adc_matches_central_differences(doppler):
    from sionna_mmir.processing.drjit_ra import ra_loss_from_adc

    dr, _ = _drjit()
    radar = _small_radar()
    x = _random_adc(radar, 7)
    target = range_azimuth(_random_adc(radar, 8), radar, doppler=doppler)[0]
    re, im = _tensors(x, grad=True)
    loss = ra_loss_from_adc((re, im), radar, target, doppler=doppler)
    dr.backward(loss)
    g = _grad_complex(re, im, radar.adc_shape)
    ref = ra_loss(range_azimuth(x, radar, doppler=doppler)[0], target)
    assert abs(float(loss.numpy()[0]) - ref) <= 1e-5 * ref

    def f(xx):
        return ra_loss(range_azimuth(xx, radar, doppler=doppler)[0], target)

    rng = np.random.default_rng(9)
    for _ in range(4):
        idx = tuple(int(rng.integers(n)) for n in radar.adc_shape)
        fd = _central_fd(f, x, idx, 1e-5)
        assert abs(g[idx] - fd) <= 1e-3 * abs(fd) + 1e-4 * np.abs(g).max(), (idx, g[idx], fd)


@pytest.mark.parametrize("radar_name,doppler", [("awr1843", "mean"), ("awr1843", "noncoherent"),
                                                 ("mmwcas", "mean"), ("mmwcas", "noncoherent")])
def test_05_jvp_dot_product_equals_vjp(radar_name, doppler):
    """<J dx, G> (forward mode) == <dx, J^T G> (reverse mode).

    Forward mode applies the NumPy pipeline, reverse mode the hand-built
    adjoint, so this also checks L^H on the cascade (duplicate virtual
    positions averaged on the azimuth row).
    """
    from sionna_mmir.processing.drjit_ra import range_azimuth_drjit

    dr, mi = _drjit()
    radar = (_small_radar() if radar_name == "awr1843"
             else RadarConfig.mmwcas(num_chirps=2).replace(num_samples=64))
    x = _random_adc(radar, 10)
    rng = np.random.default_rng(11)
    dx = rng.normal(size=radar.adc_shape) + 1j * rng.normal(size=radar.adc_shape)
    G = rng.normal(size=(radar.num_samples, 128))

    re, im = _tensors(x, grad=True)
    dr.set_grad(re, mi.TensorXf(dx.real.astype(np.float32)))
    dr.set_grad(im, mi.TensorXf(dx.imag.astype(np.float32)))
    ra = range_azimuth_drjit((re, im), radar, doppler=doppler)
    dr.forward_to(ra)
    jvp = float(np.sum(ra.grad.numpy() * G))

    re, im = _tensors(x, grad=True)
    ra = range_azimuth_drjit((re, im), radar, doppler=doppler)
    dr.backward(dr.sum(ra * mi.TensorXf(G.astype(np.float32)), axis=None))
    g = _grad_complex(re, im, radar.adc_shape)
    vjp = float(np.sum(g.real * dx.real + g.imag * dx.imag))
    assert abs(jvp - vjp) <= 1e-4 * abs(vjp)


def test_06_zero_magnitude_bins_pass_no_gradient():
    """An all-zero ADC (|z| = 0 everywhere): finite, zero gradients in both modes."""
    from sionna_mmir.processing.drjit_ra import range_azimuth_drjit

    dr, mi = _drjit()
    radar = _small_radar()
    re, im = _tensors(np.zeros(radar.adc_shape, complex), grad=True)
    ra = range_azimuth_drjit((re, im), radar, doppler="noncoherent")
    dr.backward(dr.sum(ra, axis=None))
    g = _grad_complex(re, im, radar.adc_shape)
    assert np.all(ra.numpy() == 0) and np.all(np.isfinite(g)) and np.all(g == 0)
    re, im = _tensors(np.zeros(radar.adc_shape, complex), grad=True)
    dr.set_grad(re, mi.TensorXf(np.ones(radar.adc_shape, np.float32)))
    ra = range_azimuth_drjit((re, im), radar)
    dr.forward_to(ra)
    assert np.all(ra.grad.numpy() == 0)


def test_07_ra_loss_value_and_gradient_at_min_max_bins():
    from sionna_mmir.processing.drjit_ra import ra_loss_drjit

    dr, mi = _drjit()
    rng = np.random.default_rng(12)
    a = rng.uniform(1.0, 2.0, size=(12, 16)).astype(np.float32).astype(np.float64)
    a[3, 4], a[7, 9] = 0.2, 5.0                      # unique min and max, well apart
    b = rng.uniform(0.0, 3.0, size=(12, 16))
    t = mi.TensorXf(a.astype(np.float32))
    dr.enable_grad(t)
    loss = ra_loss_drjit(t, b)
    assert isinstance(loss, mi.Float) and dr.width(loss) == 1
    assert abs(float(loss.numpy()[0]) - ra_loss(a, b)) <= 1e-5 * ra_loss(a, b)
    # a TensorXf target gives the same loss
    loss_t = ra_loss_drjit(t, mi.TensorXf(b.astype(np.float32)))
    assert abs(float(loss_t.numpy()[0]) - ra_loss(a, b.astype(np.float32))) <= 1e-5 * ra_loss(a, b)
    dr.backward(loss)
    g = t.grad.numpy()
    h = 1e-6
    for idx in [(3, 4), (7, 9), (0, 0), (11, 15), (5, 5)]:
        ap, am = a.copy(), a.copy()
        ap[idx] += h
        am[idx] -= h
        fd = (ra_loss(ap, b) - ra_loss(am, b)) / (2 * h)
        assert abs(g[idx] - fd) <= 1e-3 * abs(fd) + 1e-6, (idx, g[idx], fd)
    # the min / max bins carry the normalisation derivative: far larger than a plain bin
    assert abs(g[7, 9]) > 10 * np.median(np.abs(g))
    # constant render: all-zero normalised map, zero gradient, loss = mean(minmax(b)^2)
    c = mi.TensorXf(np.full((12, 16), 3.0, np.float32))
    dr.enable_grad(c)
    loss = ra_loss_drjit(c, b)
    dr.backward(loss)
    assert abs(float(loss.numpy()[0]) - ra_loss(np.full((12, 16), 3.0), b)) <= 1e-5
    assert np.all(c.grad.numpy() == 0)


def test_08_end_to_end_amplitude_and_delay_gradients():
    """synthesize_adc (Dr.Jit) -> RA map -> loss; d/d amplitude and d/d delay vs float64 FD."""
    from sionna_mmir.fmcw import synthesize_adc
    from sionna_mmir.processing.drjit_ra import ra_loss_drjit, range_azimuth_drjit

    dr, mi = _drjit()
    radar = RadarConfig.awr1843(num_chirps=2).replace(num_samples=64)
    pts = [target_at(radar, 2.0, 0.2), target_at(radar, 2.12, -0.1), target_at(radar, 2.3, 0.4)]
    geom = np.concatenate([point_target_delays(radar, p) for p in pts], axis=2)   # [3, 4, 3]
    geom = geom.astype(np.float32).astype(np.float64)
    P = geom.shape[2]
    amp = np.array([1.0, 0.7, 0.5])
    amp_target = np.array([0.6, 1.0, 0.8])

    def loss_np(a, dtau):
        adc = direct_adc(radar, a.astype(complex), geom + dtau[None, None, :])
        return ra_loss(range_azimuth(adc, radar)[0], target)

    target = range_azimuth(direct_adc(radar, amp_target.astype(complex), geom), radar)[0]

    a_re = mi.Float(amp.astype(np.float32))
    a_im = dr.zeros(mi.Float, P)
    dtau = dr.zeros(mi.Float, P)                          # per-target delay offset [s]
    dr.enable_grad(a_re, dtau)
    p_idx = mi.UInt32(np.tile(np.arange(P), radar.num_tx * radar.num_rx).astype(np.uint32))
    tau = mi.TensorXf(mi.Float(geom.astype(np.float32).ravel()) + dr.gather(mi.Float, dtau, p_idx),
                      geom.shape)
    adc = synthesize_adc(radar, (a_re, a_im), tau)
    loss = ra_loss_drjit(range_azimuth_drjit(adc, radar), target)
    dr.backward(loss)
    g_a, g_tau = a_re.grad.numpy(), dtau.grad.numpy()
    zero = np.zeros(P)
    assert abs(float(loss.numpy()[0]) - loss_np(amp, zero)) <= 1e-3 * loss_np(amp, zero)

    # delay step 1e-14 s = 4.8e-3 rad of carrier phase at 77 GHz (1e-12 s would be 0.48 rad,
    # far too coarse for central differences)
    h_a, h_tau = 1e-5, 1e-14
    for p in range(P):
        e = np.eye(P)[p]
        fd_a = (loss_np(amp + h_a * e, zero) - loss_np(amp - h_a * e, zero)) / (2 * h_a)
        fd_t = (loss_np(amp, h_tau * e) - loss_np(amp, -h_tau * e)) / (2 * h_tau)
        assert abs(g_a[p] - fd_a) <= 0.02 * abs(fd_a), (p, g_a[p], fd_a)
        assert abs(g_tau[p] - fd_t) <= 0.02 * abs(fd_t), (p, g_tau[p], fd_t)


def test_09_bad_input_errors():
    from sionna_mmir.processing.drjit_ra import (ra_loss_drjit, ra_loss_from_adc,
                                                 range_azimuth_drjit)

    _, mi = _drjit()
    radar = _small_radar()
    x = _random_adc(radar, 13)
    re, im = _tensors(x)
    wrong = mi.TensorXf(np.zeros((3, 4, 4, 16), np.float32))
    with pytest.raises(InputValueError, match=r"adc.real must be \[tx, rx, chirp, sample\]"):
        range_azimuth_drjit((wrong, wrong), radar)
    with pytest.raises(InputValueError, match="adc.imag must be"):
        range_azimuth_drjit((re, wrong), radar)
    bad = x.copy()
    bad[1, 2, 0, 5] = np.nan
    with pytest.raises(InputValueError, match="NaN"):
        range_azimuth_drjit(_tensors(bad), radar)
    with pytest.raises(InputValueError, match="mi.TensorXf"):
        range_azimuth_drjit((x.real, x.imag), radar)
    with pytest.raises(InputValueError, match="pair"):
        range_azimuth_drjit(re, radar)
    with pytest.raises(ConfigError, match="doppler must be one of"):
        range_azimuth_drjit((re, im), radar, doppler="coherent")
    with pytest.raises(ConfigError, match="unknown option"):
        range_azimuth_drjit((re, im), radar, n_doppler=8)
    ra = range_azimuth_drjit((re, im), radar)
    with pytest.raises(InputValueError, match="shapes differ"):
        ra_loss_drjit(ra, np.ones((32, 64)))
    with pytest.raises(InputValueError, match="shapes differ"):
        ra_loss_from_adc((re, im), radar, np.ones((128, 32)))
    with pytest.raises(InputValueError, match="ra_target holds NaN"):
        ra_loss_drjit(ra, np.full((32, 128), np.nan))
    with pytest.raises(InputValueError, match="complex"):
        ra_loss_drjit(ra, np.ones((32, 128), complex))
    with pytest.raises(InputValueError, match="ra_render holds NaN"):
        ra_loss_drjit(mi.TensorXf(np.full((32, 128), np.nan, np.float32)), np.ones((32, 128)))
    with pytest.raises(InputValueError, match="mi.TensorXf"):
        ra_loss_drjit(np.ones((32, 128)), np.ones((32, 128)))

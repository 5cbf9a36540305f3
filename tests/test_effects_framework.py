"""Effects framework: unitary DFT nodes, the Gaussian NLL model, the first two effects."""
from __future__ import annotations

import numpy as np
import pytest

from sionna_mmir.effects import EffectContext, EffectModel, ops
from sionna_mmir.effects.library.channel_gain import ChannelGain, separable_log
from sionna_mmir.effects.library.dc_offset import DCOffset
from sionna_mmir.errors import InputValueError
from sionna_mmir.fmcw.synthesize import synthesize_adc
from sionna_mmir.radar.config import RadarConfig

dr, mi = ops.dr, ops.mi
C = 299_792_458.0


def _scene(num_chirps=2, noise=0.02, seed=0):
    radar = RadarConfig.awr1843(num_chirps=num_chirps)
    tau = 2 * np.array([2.1, 4.7]) / C
    clean = synthesize_adc(radar, np.array([1.0, 0.4j]), tau)[None].astype(np.complex128)
    rng = np.random.default_rng(seed)
    n = noise * (rng.normal(size=clean.shape) + 1j * rng.normal(size=clean.shape)) / np.sqrt(2)
    return radar, clean, n


def test_01_dft_matches_numpy_and_adjoint_matches_fd():
    rng = np.random.default_rng(1)
    x = rng.normal(size=(2, 16)) + 1j * rng.normal(size=(2, 16))
    w = rng.normal(size=(2, 16))
    z = ops.tensor(x)
    dr.enable_grad(z[0], z[1])
    y = ops.dft(z)
    assert np.allclose(ops.to_numpy(y), np.fft.fft(x, norm="ortho"), atol=1e-5)

    def loss_np(xx):
        yy = np.fft.fft(xx, norm="ortho")
        return np.sum(w * yy.real ** 2 + np.abs(yy) * 0 + yy.imag)

    loss = dr.sum(mi.TensorXf(w.astype(np.float32)) * dr.square(y[0]) + y[1], axis=None)
    dr.backward(loss)
    g = ops.to_numpy((dr.grad(z[0]), dr.grad(z[1])))
    h = 1e-6
    for idx in [(0, 3), (1, 7)]:
        e = np.zeros_like(x)
        e[idx] = h
        fd_re = (loss_np(x + e) - loss_np(x - e)) / (2 * h)
        fd_im = (loss_np(x + 1j * e) - loss_np(x - 1j * e)) / (2 * h)
        assert g[idx].real == pytest.approx(fd_re, rel=1e-3, abs=1e-4)
        assert g[idx].imag == pytest.approx(fd_im, rel=1e-3, abs=1e-4)


def test_02_idft_inverts_dft():
    rng = np.random.default_rng(2)
    x = rng.normal(size=(3, 8)) + 1j * rng.normal(size=(3, 8))
    back = ops.to_numpy(ops.idft(ops.dft(ops.tensor(x))))
    assert np.allclose(back, x, atol=1e-5)


def test_03_nll_of_noise_only_is_the_gaussian_entropy():
    radar, clean, n = _scene(noise=0.05)
    m = EffectModel(EffectContext(radar), clean + n, clean)
    m.fit()
    s2 = np.mean(np.abs(n) ** 2) / m.scale ** 2
    # E[|r|^2 / s2 + log s2] = 1 + log s2 for complex Gaussian noise
    assert m.nll() == pytest.approx(1 + np.log(s2), abs=0.02)


def test_04_channel_gain_recovered_and_residual_at_noise():
    radar, clean, n = _scene()
    rng = np.random.default_rng(3)
    T, R = radar.num_tx, radar.num_rx
    at, ar = rng.normal(0, 0.2, T), rng.normal(0, 0.2, R)
    pt, pr = rng.uniform(-3, 3, T), rng.uniform(-3, 3, R)
    g = np.exp(at[:, None] + ar[None] + 1j * (pt[:, None] + pr[None]))
    meas = clean * g[None, :, :, None, None] + n
    m = EffectModel(EffectContext(radar), meas, clean)
    m.fit()
    before = m.nll()
    comp = m.add(ChannelGain())
    m.fit()
    fitted = (m.mean_adc() / clean)[0, :, :, 0, 0]
    # the product of global and separable gains reproduces the true per-channel gain
    assert np.allclose(fitted / fitted[0, 0], g / g[0, 0], rtol=0.02, atol=0.02)
    s2 = np.mean(np.abs(n) ** 2) / m.scale ** 2
    assert m.nll() == pytest.approx(1 + np.log(s2), abs=0.05)
    assert m.nll() < before - 1.0
    assert comp.n_params == 2 * (T + R)


def _tx_grad(m):
    tens = m._tensors(grad_keys={(0, "tx")})
    mask, cnt = m.mask_tensor()
    dr.backward(m.loss(tens, mask, cnt))
    return np.asarray(dr.grad(tens[(0, "tx")]), np.float64).reshape(3, 2)


def test_05_channel_gain_gradient_matches_finite_differences():
    radar, clean, n = _scene()
    m = EffectModel(EffectContext(radar), clean * 1.1 + n, clean)
    comp = m.add(ChannelGain())
    comp.values["tx"] = comp.values["tx"] + np.array([[0.1, 0.3], [-0.05, 0.2], [0.0, -0.4]])
    with ops.single_thread():
        grad = _tx_grad(m)
    h = 1e-3
    for idx in [(0, 0), (1, 1), (2, 1)]:
        base = comp.values["tx"].copy()
        comp.values["tx"] = base.copy()
        comp.values["tx"][idx] += h
        up = m.nll()
        comp.values["tx"] = base.copy()
        comp.values["tx"][idx] -= h
        down = m.nll()
        comp.values["tx"] = base
        fd = (up - down) / (2 * h)
        assert grad[idx] == pytest.approx(fd, rel=0.02, abs=2e-3)


def test_06_separable_log_splits_a_rank_one_gain():
    rng = np.random.default_rng(4)
    t = rng.normal(size=4) + 1j * rng.uniform(-3, 3, 4)
    r = rng.normal(size=5) + 1j * rng.uniform(-3, 3, 5)
    h = np.exp(t[:, None] + r[None])
    tx, rx = separable_log(h)
    back = np.exp(tx[:, 0][:, None] + rx[:, 0][None] + 1j * (tx[:, 1][:, None] + rx[:, 1][None]))
    assert np.allclose(back, h, rtol=1e-6)


def test_07_dc_offset_shows_in_bin_zero_and_is_recovered():
    radar, clean, n = _scene()
    d = np.array([0.3 + 0.1j, -0.2j, 0.05, 0.1 - 0.1j])
    meas = clean + n + d[None, None, :, None, None]
    # independent check: the unitary DFT puts a constant d into bin 0 as d sqrt(N)
    N = radar.num_samples
    spec = np.fft.fft(meas - clean - n, axis=-1, norm="ortho")
    assert np.allclose(spec[0, 0, :, 0, 0], d * np.sqrt(N))
    m = EffectModel(EffectContext(radar), meas, clean)
    comp = m.add(DCOffset())
    m.fit()
    got = (comp.values["dc"][:, 0] + 1j * comp.values["dc"][:, 1]) * m.scale
    assert np.allclose(got, d, atol=0.01)


def test_08_bad_inputs_name_the_problem():
    radar, clean, n = _scene()
    ctx = EffectContext(radar)
    with pytest.raises(InputValueError, match="shape"):
        EffectModel(ctx, clean[..., :10], clean)
    bad = clean.copy()
    bad[0, 0, 0, 0, 0] = np.nan
    with pytest.raises(InputValueError, match="NaN"):
        EffectModel(ctx, bad, clean)
    with pytest.raises(InputValueError, match="zero"):
        EffectModel(ctx, np.zeros_like(clean), clean)
    m = EffectModel(ctx, clean + n, clean)
    with pytest.raises(InputValueError, match="no cells"):
        m.nll(np.zeros(ctx.shape[:4], bool))


def test_09_repeated_backward_passes_give_the_same_gradient():
    """Guards the single-thread work-around for Dr.Jit 1.5's intermittent lost gradient."""
    st, sr = (1, 3, 1, 1, 1), (1, 1, 4, 1, 1)
    x = ops.tensor(np.ones((1, 3, 4, 2, 8)) * (1 + 0.5j))
    grads = []
    for _ in range(20):
        with ops.single_thread():
            p = mi.TensorXf(np.zeros((3, 2), np.float32))
            q = mi.TensorXf(np.zeros((4, 2), np.float32))
            dr.enable_grad(p)
            amp = dr.exp(ops.column(p, 0, st) + ops.column(q, 0, sr))
            g = ops.scale(ops.cis(ops.column(p, 1, st) + ops.column(q, 1, sr)), amp)
            loss = dr.sum(ops.abs2(ops.cmul(x, g)), axis=None)
            dr.backward(loss)
            grads.append(np.asarray(dr.grad(p)).ravel()[0])
    # d/da sum |x|^2 e^{2a} = 2 * |1 + 0.5j|^2 * (4 rx * 2 chirps * 8 samples) = 160
    assert np.allclose(grads, 160.0, rtol=1e-5)


def test_10_time_domain_nll_is_the_range_domain_nll():
    """A white floor alone: the NLL computed in the time domain (no DFT) equals
    the range-domain NLL computed here with NumPy's FFT, on all cells and on
    a mask; with a noise-shaping effect the range domain is used, split into
    the chirp mean and the deviation (``EffectModel.split_likelihood``)."""
    from sionna_mmir.effects.library.if_filter import IFFilter

    radar, clean, n = _scene()
    ctx = EffectContext(radar)
    m = EffectModel(ctx, clean * 1.1 + n, clean)
    comp = m.add(ChannelGain())
    comp.values["tx"] = comp.values["tx"] + 0.1
    cells = np.random.default_rng(3).random(ctx.shape[:4]) < 0.6

    def range_domain_nll(model, sel):
        x, v = model.mean_variance_numpy()
        Y = np.fft.fft(model.y, axis=-1, norm="ortho")
        X = np.fft.fft(x, axis=-1, norm="ortho")
        per = np.abs(Y - X) ** 2 / v + np.log(v)
        return float(np.mean(per if sel is None else per[sel]))

    def split_nll(model, sel):
        """The split likelihood of ``EffectModel._split_loss`` in NumPy: the
        chirp mean under its profiled white floor, the deviation on the noise
        bins under ``v``."""
        x, v = model.mean_variance_numpy()
        R = np.fft.fft(model.y, axis=-1, norm="ortho") - np.fft.fft(x, axis=-1, norm="ortho")
        C = R.shape[3]
        w = np.broadcast_to(sel[..., None], R.shape).astype(float)
        n, n_m = w.sum(), w.sum() / C
        Rm = R.mean(axis=3, keepdims=True)
        mean_term = n_m * (np.log(np.sum(np.abs(Rm) ** 2 * w.mean(axis=3, keepdims=True))
                                  / n_m) + 1)
        dev = (np.abs(R - Rm) ** 2 / v + (C - 1) / C * np.log(v)) * w
        return float((mean_term + dev[..., model.noise_bins()].sum()) / n)

    assert m._white()
    for sel in (None, cells):
        assert m.nll(sel) == pytest.approx(range_domain_nll(m, sel), rel=1e-5, abs=1e-5)
    m.add(IFFilter())
    assert not m._white() and m.split_likelihood()
    assert m.nll(cells) == pytest.approx(split_nll(m, cells), rel=1e-5, abs=1e-5)


def test_11_a_held_chain_is_evaluated_once_and_gives_the_same_loss():
    """A fit that holds the components before the first trainable one
    evaluates them once (:meth:`EffectModel.frozen_prefix`: ``p0 + g d`` in
    the nuisance gain).  Truth: the same model's loss and gradients through
    the whole chain, at values away from the fitted ones (a missing
    scatterer, ego motion, a mover and per-channel gains held, a DC offset
    fitted); ego motion's geometry, derived from a scene whose layout
    changes with the gain, is held at the current gain's; a held IQ
    imbalance is not affine in the gain and gets no prefix."""
    from sionna_mmir.effects.library.ego_motion import EgoMotion
    from sionna_mmir.effects.library.iq_imbalance import IQImbalance
    from sionna_mmir.effects.library.moving_scatterer import MovingScatterer
    from sionna_mmir.effects.library.scatterer import MissingScatterer
    from sionna_mmir.effects.model import _Prefix

    radar, clean, n = _scene(num_chirps=4)
    ctx = EffectContext(radar)
    m = EffectModel(ctx, clean + n, clean)
    for eff in (MissingScatterer(), EgoMotion(), MovingScatterer(), ChannelGain(), DCOffset()):
        m.add(eff)
    m.components[0].values.update(range=np.array([3.3]), amp=np.array([0.5, 0.4]))
    m.components[1].values["velocity"] = np.array([0.4])
    m.components[2].values.update(amp=np.array([[0.3, -0.2]]), velocity=np.array([1.1]))
    rng = np.random.default_rng(11)
    for c in m.components[3:]:
        c.values = {k: v + 0.05 * rng.normal(size=np.shape(v)) for k, v in c.values.items()}
    m.nuisance.values["gain"] = np.array([0.8, 0.3])
    pre = m.frozen_prefix([4])
    assert isinstance(pre, _Prefix) and pre.skip == frozenset({0, 1, 2, 3})
    keys = {(-1, "gain"), (-1, "log_noise"), (4, "dc")}
    mask, cnt = m.mask_tensor()
    out = []
    for frozen in (None, pre):
        tens = m._tensors(grad_keys=keys)
        with ops.single_thread():                  # as fit() runs (see ops.single_thread)
            loss = m.loss(tens, mask, cnt, frozen)
            dr.backward(loss)
            out.append((ops.item(loss),
                        [np.asarray(dr.grad(tens[k]), np.float64) for k in sorted(keys)]))
    assert out[1][0] == pytest.approx(out[0][0], rel=1e-5)
    for a, b in zip(out[0][1], out[1][1]):
        np.testing.assert_allclose(b, a, rtol=1e-3, atol=1e-4 * np.abs(a).max())
    m.add(IQImbalance())
    m.components[-1].values = {k: v + 0.1 for k, v in m.components[-1].values.items()}
    m.add(DCOffset())
    assert m.frozen_prefix([6]) is None


def test_12_blockwise_refit_reaches_the_joint_fit():
    """:func:`~sionna_mmir.effects.blockwise.fit_joint` beside a mover: the
    static components on the chirp average, the mover on every chirp,
    alternated.  Truth: the one joint fit of the same model on every chirp
    (same objective, same start): the NLL within 2e-3 nats per sample and
    the same values; the static block's optimum is the full objective's
    optimum in those parameters (a full-data fit of them from there gains
    nothing).  The blocks are not taken for one chirp loop, a mask that
    splits a channel's chirps, ego motion (a map of the whole scene), or a
    static model with a noise shaper (its joint fit is on the chirp average)."""
    from sionna_mmir.effects import blockwise
    from sionna_mmir.effects.library.ego_motion import EgoMotion
    from sionna_mmir.effects.library.moving_scatterer import MovingScatterer
    from sionna_mmir.effects.library.scatterer import MissingScatterer

    radar, clean, n = _scene(num_chirps=8, noise=0.01)
    ctx = EffectContext(radar)
    truth = EffectModel(ctx, clean, clean)
    for eff in (MissingScatterer(), MovingScatterer(), ChannelGain()):
        truth.add(eff)
    truth.components[0].values.update(range=np.array([3.3]), amp=np.array([0.5, 0.4]))
    truth.components[1].values.update(range=np.array([4.1]), azimuth=np.array([20.0]),
                                      amp=np.array([[0.3, -0.2]]), velocity=np.array([1.1]))
    rng = np.random.default_rng(12)
    g = truth.components[2]
    g.values = {k: v + 0.1 * rng.normal(size=np.shape(v)) for k, v in g.values.items()}
    y = truth.mean_adc() + n
    models = []
    for _ in range(2):                   # started where the data-driven inits put them
        m = EffectModel(ctx, y, clean)
        for eff in (MissingScatterer(), MovingScatterer(), ChannelGain()):
            m.add(eff)
        models.append(m)
    block, joint = models
    assert blockwise.blocks(block) == ([0], [1, 2])      # the gain also scales the mover
    out = blockwise.fit_joint(block, maxiter=300)
    joint.fit(maxiter=300)
    assert out["cycles"] >= 1
    # both stop by L-BFGS-B's ftol in the shallow valley of the nuisance gain
    # against the channel gains and the mover's azimuth: within 1e-5 nats per
    # sample on an AVX-512 CPU, 1.3e-3 on an AVX2 one (float32 rounding takes
    # the two fits down different paths; NOTES.md)
    assert block.nll() <= joint.nll() + 2e-3
    xb, xj = block.mean_variance_numpy()[0], joint.mean_variance_numpy()[0]
    assert np.sum(np.abs(xb - xj) ** 2) < 1e-4 * np.sum(np.abs(xj) ** 2)
    for m in (block, joint):                     # and both at the planted values
        for c, t in zip(m.components[:2], truth.components[:2]):
            assert c.values["range"] == pytest.approx(t.values["range"], abs=5e-3)
        assert m.components[1].values["velocity"] == pytest.approx(1.1, abs=0.01)
    # the static block is exact: its optimum is the full data's in those parameters
    probe = block.copy()
    blockwise._fit_static(probe, [0], None, 300)
    before = probe.nll()
    probe.fit(trainable=[0], maxiter=300, nuisance=False)
    assert probe.nll() == pytest.approx(before, abs=2e-6)
    one = EffectModel(EffectContext(RadarConfig.awr1843(num_chirps=1)),
                      y[..., :1, :], clean[..., :1, :])
    one.add(MissingScatterer()), one.add(ChannelGain())
    assert blockwise.blocks(one) is None
    cells = np.ones(ctx.shape[:4], bool)
    cells[..., 0] = False
    assert blockwise.blocks(block, cells) is None
    assert blockwise.blocks(block, cells[..., :1] & np.ones(ctx.shape[:4], bool)) is not None
    block.add(EgoMotion())
    assert blockwise.blocks(block) is None
    # nothing chirp-varying in the mean and a noise shaper: the one joint fit
    # runs on the chirp average already (split_averaged), no blocks
    from sionna_mmir.effects.library.if_filter import IFFilter

    static = EffectModel(ctx, y, clean)
    static.add(MissingScatterer()), static.add(ChannelGain())
    static.add(IFFilter(highpass_stages=1, transient=False))
    assert static.split_averaged() is not None and blockwise.blocks(static) is None


def test_13_a_static_model_with_a_noise_shaper_is_fitted_on_the_chirp_average():
    """:meth:`EffectModel.split_averaged`: with every component the same in
    every chirp, the split NLL's deviation term is the data's own, so the
    chirp average plus its deviation power scores the same objective.
    Truth: the full model's split loss and its AD gradients (every key, at
    values away from the optimum, with a training mask), and a fit on every
    chirp (the delegation switched off) reaching the same NLL.  Not taken
    with a mover (chirp-varying) or a mask that splits a channel's chirps."""
    from sionna_mmir.effects.library.if_filter import IFFilter
    from sionna_mmir.effects.library.moving_scatterer import MovingScatterer

    radar, clean, n = _scene(num_chirps=4, noise=0.05)
    ctx = EffectContext(radar)
    m = EffectModel(ctx, clean + n, clean)
    m.add(ChannelGain())
    m.add(IFFilter())
    rng = np.random.default_rng(13)
    for c in m.components:
        c.values = {k: v + 0.05 * rng.normal(size=np.shape(v)) for k, v in c.values.items()}
    cells = np.ones(ctx.shape[:4], bool)
    cells[:, :, ::3] = False                                   # held-out channels
    avg = m.split_averaged(cells)
    assert avg is not None and avg.ctx.shape[3] == 1
    keys = {(-1, "gain"), (-1, "log_noise")} | {(i, k) for i, c in enumerate(m.components)
                                                 for k in c.specs}
    out = []
    for model, mk in ((m, cells), (avg, cells[..., :1])):
        mask, cnt = model.mask_tensor(mk)
        tens = model._tensors(grad_keys=keys)
        with ops.single_thread():
            loss = model.loss(tens, mask, cnt)
            dr.backward(loss)
            out.append((ops.item(loss), [np.asarray(dr.grad(tens[k]), np.float64)
                                         for k in sorted(keys)]))
    assert out[1][0] == pytest.approx(out[0][0], rel=1e-5)
    for a, b in zip(out[0][1], out[1][1]):
        np.testing.assert_allclose(b, a, rtol=2e-3, atol=1e-4 * max(np.abs(a).max(), 1e-3))
    full = m.copy()
    m.fit(cells=cells, maxiter=200)                            # on the average
    orig = EffectModel.split_averaged
    try:
        EffectModel.split_averaged = lambda self, cells=None: None
        full.fit(cells=cells, maxiter=200)                     # on every chirp
    finally:
        EffectModel.split_averaged = orig
    assert m.nll(cells) == pytest.approx(full.nll(cells), abs=2e-5)
    bad = cells.copy()
    bad[0, 0, 1, 0] = False
    assert m.split_averaged(bad) is None
    m.add(MovingScatterer())
    assert m.split_averaged() is None

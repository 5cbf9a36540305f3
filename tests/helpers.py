"""Small test helpers: exact point-target geometry, peak finding."""
from __future__ import annotations

import numpy as np

C = 299_792_458.0


def point_target_delays(radar, xyz) -> np.ndarray:
    """Exact round-trip delays ``tau[tx, rx, 1]`` [s] to a point at ``xyz`` (radar frame, m).

    ``tau_ij = (|x - tx_i| + |x - rx_j|) / c`` with the element positions of
    ``radar.tx_positions`` / ``radar.rx_positions`` (radar at the origin).
    """
    x = np.asarray(xyz, dtype=np.float64).reshape(3)
    dt = np.linalg.norm(x[None, :] - radar.tx_positions, axis=1)
    dr = np.linalg.norm(x[None, :] - radar.rx_positions, axis=1)
    return ((dt[:, None] + dr[None, :]) / C)[:, :, None]


def aperture_centre(radar) -> np.ndarray:
    """Mean effective (two-way) phase centre ``(tx + rx) / 2`` over all pairs [m]."""
    return 0.5 * radar.virtual_positions().reshape(-1, 3).mean(axis=0)


def direction(az, el=0.0) -> np.ndarray:
    """Unit vector for azimuth ``az`` and elevation ``el`` [rad] in the radar frame."""
    return np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])


def target_at(radar, rng, az, el=0.0) -> np.ndarray:
    """Point at range ``rng`` and angles seen from the aperture centre [m]."""
    return aperture_centre(radar) + rng * direction(az, el)


def direct_adc(radar, a, tau, tau_rate=None) -> np.ndarray:
    """Straightforward reference synthesis (independent of the package), complex128.

    ``s = sum_p a exp(j 2 pi (f0 + S t_k)(tau + tau_rate (T_chirp + t_k)))``,
    ``a``, ``tau``, ``tau_rate`` broadcastable to ``[tx, rx, P]``.
    """
    tk = radar.adc_start_time + np.arange(radar.num_samples) / radar.sample_rate
    tc = radar.chirp_start_times()                                     # [tx, L]
    shape = (radar.num_tx, radar.num_rx, np.broadcast(np.asarray(a), np.asarray(tau)).shape[-1])
    a = np.broadcast_to(np.asarray(a, dtype=np.complex128), shape)
    tau = np.broadcast_to(np.asarray(tau, dtype=np.float64), shape)
    rate = np.zeros(shape) if tau_rate is None else np.broadcast_to(
        np.asarray(tau_rate, dtype=np.float64), shape)
    f = radar.start_frequency + radar.slope * tk                        # [K]
    t = tc[:, None, :, None, None] + tk[None, None, None, :, None]      # [tx,1,L,K,1]
    d = tau[:, :, None, None, :] + rate[:, :, None, None, :] * t        # [tx,rx,L,K,P]
    ph = np.exp(2j * np.pi * f[None, None, None, :, None] * d)
    return np.sum(a[:, :, None, None, :] * ph, axis=-1)


def point_targets_adc(radar, targets) -> np.ndarray:
    """ADC ``[1, T, R, C, N]`` of point targets ``(range m, azimuth rad, amplitude)``
    at exact per-pair delays (the package's synthesis)."""
    from sionna_mmir.fmcw.synthesize import synthesize_adc

    T, R = radar.num_tx, radar.num_rx
    a, tau = [], []
    for r_m, az, amp in targets:
        tau.append(point_target_delays(radar, target_at(radar, r_m, az))[..., 0])
        a.append(np.full((T, R), amp, complex))
    return synthesize_adc(radar, np.stack(a, -1), np.stack(tau, -1))[None]


def _nll_ad_grad(m, i, key):
    """AD gradient of model ``m``'s NLL over every cell w.r.t. ``components[i].values[key]``."""
    from sionna_mmir.effects import ops

    dr = ops.dr
    tens = m._tensors(grad_keys={(i, key)})
    mask, cnt = m.mask_tensor()
    _, X, v = m._forward(tens)
    r2 = ops.abs2((m.Y[0] - X[0], m.Y[1] - X[1]))
    loss = dr.sum((r2 / v + dr.log(v)) * mask, axis=None) / cnt
    dr.backward(loss)
    shape = m.components[i].values[key].shape
    return np.asarray(dr.grad(tens[(i, key)]), np.float64).reshape(shape)


def nll_central_difference(m, comp, key, base, d, h) -> float:
    """``(NLL(base + h d) - NLL(base - h d)) / 2h`` for block ``key`` of ``comp``
    (restored to ``base`` afterwards)."""
    comp.values[key] = base + h * d
    up = m.nll()
    comp.values[key] = base - h * d
    down = m.nll()
    comp.values[key] = base
    return (up - down) / (2 * h)


def check_nll_gradients(m, i, steps, seed=0):
    """AD directional derivative of the NLL along a random +-1 direction per block
    vs the central difference with step ``steps[key]`` (values kept float32-exact)."""
    import pytest

    from sionna_mmir.effects import ops

    rng = np.random.default_rng(seed)
    comp = m.components[i]
    errors = {}
    for key, h_target in steps.items():
        val = np.asarray(comp.values[key], np.float32).astype(np.float64)
        comp.values[key] = val
        with ops.single_thread():
            g = _nll_ad_grad(m, i, key)
        d = rng.choice([-1.0, 1.0], size=val.shape)
        h = 2.0 ** np.round(np.log2(h_target))
        fd = nll_central_difference(m, comp, key, val, d, h)
        ad = float(np.sum(g * d))
        errors[key] = abs(ad - fd) / abs(fd)
        assert abs(fd) > 1e-3, (key, fd)
        assert ad == pytest.approx(fd, rel=0.02), (key, ad, fd)
    return errors


def peak_index(arr) -> tuple:
    """Index tuple of the maximum of ``arr``."""
    return np.unravel_index(int(np.argmax(arr)), np.shape(arr))


def sphere_chi2(w, m, s, t, scale, pdf_of_dirs, n_x=20, n_phi=40, sub=12):
    """Chi-square goodness of fit of unit directions ``w`` [n, 3] against a pdf.

    Bins: ``x = log1p(scale (1 - m.w)) / log1p(2 scale)`` (dense near the lobe
    axis ``m``) times the azimuth about ``m`` in the frame ``(s, t)``.  Expected
    counts come from ``pdf_of_dirs(dirs [k, 3]) -> pdf [k]`` (solid-angle
    density) integrated with a ``sub x sub`` midpoint rule per bin; bins with
    fewer than 5 expected samples are pooled.  Returns ``(p_value, integral of
    the pdf over the sphere)``.
    """
    from scipy import stats

    L = np.log1p(2 * scale)
    c = np.clip(w @ m, -1, 1)
    x = np.log1p(scale * (1 - c)) / L
    phi = np.mod(np.arctan2(w @ t, w @ s), 2 * np.pi)
    ok = np.isfinite(x) & np.isfinite(phi)
    obs, _, _ = np.histogram2d(x[ok], phi[ok], bins=[n_x, n_phi], range=[[0, 1], [0, 2 * np.pi]])
    nx, nphi = n_x * sub, n_phi * sub
    X, P = np.meshgrid((np.arange(nx) + 0.5) / nx, (np.arange(nphi) + 0.5) / nphi * 2 * np.pi,
                       indexing="ij")
    C = 1 - np.expm1(X * L) / scale
    S = np.sqrt(np.clip(1 - C * C, 0, None))
    dirs = (C[..., None] * m + S[..., None] * (np.cos(P)[..., None] * s
                                               + np.sin(P)[..., None] * t)).reshape(-1, 3)
    pdf = np.asarray(pdf_of_dirs(dirs), dtype=np.float64)
    jac = L * np.exp(X * L).reshape(-1) / scale
    dens = (pdf * jac).reshape(nx, nphi) * (1.0 / nx) * (2 * np.pi / nphi)
    exp_bins = dens.reshape(n_x, sub, n_phi, sub).sum(axis=(1, 3))
    integral = exp_bins.sum()
    e = exp_bins.ravel() / integral * ok.sum()
    o = obs.ravel()
    assert not np.any((e == 0) & (o > 0)), "samples where the pdf is zero"
    low = e < 5
    e2, o2 = list(e[~low]), list(o[~low])
    if low.any():
        if e[low].sum() >= 5 or not e2:
            e2.append(e[low].sum())
            o2.append(o[low].sum())
        else:  # pool the remainder into the smallest regular bin
            i = int(np.argmin(e2))
            e2[i] += e[low].sum()
            o2[i] += o[low].sum()
    e2, o2 = np.array(e2), np.array(o2)
    e2 *= o2.sum() / e2.sum()
    return stats.chisquare(o2, e2).pvalue, integral


def square_plate(centre, size, yaw_deg=0.0, subdiv=0):
    """Square plate ``size`` x ``size`` [m] in the y-z plane facing -x (the radar),
    turned by ``yaw_deg`` about +z, centred at ``centre``; ``subdiv`` 4:1 splits."""
    import trimesh

    v = np.array([[0, -1, -1], [0, 1, -1], [0, 1, 1], [0, -1, 1]], float) * size / 2
    m = trimesh.Trimesh(v, [[0, 2, 1], [0, 3, 2]], process=False)
    for _ in range(subdiv):
        m = m.subdivide()
    m.apply_transform(trimesh.transformations.rotation_matrix(np.radians(yaw_deg), [0, 0, 1]))
    m.apply_translation(centre)
    return m


def assert_same_paths(paths, *others) -> None:
    """Path amplitudes of ``others`` equal those of ``paths`` to float32
    rounding (rtol 1e-6): the LLVM backend's atomic sums may add in another
    order from run to run (one amplitude of 7254 one ulp apart was seen)."""
    a = paths.numpy()[0]
    for other in others:
        np.testing.assert_allclose(other.numpy()[0], a, rtol=1e-6, atol=1e-6 * np.abs(a).max())


def highpass_noise(noise, f_hp, fs, stages: int = 1) -> np.ndarray:
    """``noise [..., N]`` through ``stages`` first-order high-passes at ``f_hp``
    [Hz] (``scipy.signal.lfilter`` on the bilinear transform, I and Q alike),
    run from a copy of the row before it so the window sees the settled
    filter, as receiver noise behind an IF high-pass does."""
    from scipy import signal

    b, a = signal.butter(1, f_hp, "highpass", fs=fs)
    n = noise.shape[-1]
    x = np.concatenate([noise, noise], -1)
    for _ in range(stages):
        x = signal.lfilter(b, a, x, axis=-1)
    return x[..., n:]

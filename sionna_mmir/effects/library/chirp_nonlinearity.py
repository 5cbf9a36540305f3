"""Chirp nonlinearity: the transmitted ramp's instantaneous-frequency error ``e(t)``.

Model of the error, Legendre polynomials in the normalised fast time
``u = 2 (t - t_0) / (t_{N-1} - t_0) - 1 in [-1, 1]`` over the ADC window::

    e(t) = sum_d c_d P_d(u)            [Hz],  default degrees d = 0, 1, 2, 3

``d = 0`` is a start-frequency error and ``d = 1`` a slope error *over the
ADC window*.  They are kept by default: a VCO's ramp error is small against
its best straight line over the whole ramp, but the ADC window is only part
of the ramp, and over that part a curved error has a mean and a tilt of the
same size as its curvature (a quadratic over the ramp seen in a window from
14 % to 55 % of it: ``|c_0|, |c_1| > |c_2|``).  Neither is degenerate with a
per-channel delay or a constant beat-frequency offset: both act in
proportion to each path's delay.

Derivation.  The chirp's phase (in cycles) is ``psi(t) = f0 t + S t^2 / 2 +
E(t)`` with ``E'(t) = e(t)``.  A path of delay ``tau`` mixes to the beat
phase ``psi(t) - psi(t - tau)``; the error term is
``E(t) - E(t - tau) ~ tau E'(t) = tau e(t)`` (``tau`` of tens of ns is short
against the time scale of ``e``).  So each path's beat tone
``x_p = a_p exp(j 2 pi S tau_p t + ...)`` becomes::

    x_p exp(j 2 pi tau_p e(t)),    and   j 2 pi tau_p e(t) x_p = (e(t) / S) dx_p/dt

because ``dx_p/dt = j 2 pi S tau_p x_p``.  Summed over paths (linear in
``x``), to first order in ``e``, the beat signal is time-warped::

    x'(t) = x(t + e(t) / S) = sum_m (e(t)/S)^m / m!  d^m x / dt^m

which is exactly ``sum_p x_p exp(j 2 pi tau_p e(t))`` expanded to order
``taylor_order`` (default 3; the error of order ``m`` is
``(2 pi tau e)^{m+1} / (m+1)!``).  The derivatives are spectral:
``d^m x / dt^m = IDFT((j 2 pi f_k)^m DFT(x))`` with ``f_k`` the bins'
physical beat frequencies in the band ``[band_start f_s, (band_start + 1) f_s)``
(:func:`~._sensor_common.band_frequencies`; ``-0.1`` keeps near-DC leakage
on the negative side and targets up to ``0.9 max_range`` on the positive).
A plain DFT derivative treats the window as periodic, so an off-bin tone
gets Gibbs ringing in its first and last samples (about 10 % of the
correction); each fast-time row is therefore first extended by
``extension`` samples on both sides by linear prediction
(:class:`~._sensor_common.RowExtension`, order ``prediction_order``, frozen on
the model and renewed when another effect joins it), differentiated on the longer grid and cut back (about
1 % error in the tests); ``extension=0`` gives the plain DFT derivative.

Parameters: ``c`` ``[len(degrees)]`` [MHz].  Typical VCO ramp errors are
0.1-1 MHz; the beat phase error is ``2 pi tau e``, i.e. 0.4 rad for a
1 MHz error at 10 m.

Initial values: the first-order model is linear in ``c``,
``residual ~ sum_d c_d j 2 pi (P_d(u) / S) dx/dt``; least squares over all
samples.
"""
from __future__ import annotations

import math

import numpy as np

from ...errors import ConfigError
from .. import ops
from ..base import Effect, ParamSpec
from ._sensor_common import (ExtendedRows, RowExtension, band_frequencies, check_float, check_int,
                             last_axis, legendre_basis, scalar, unit_fast_time)

MHZ = 1e6


def phase_weights(ctx, degrees) -> np.ndarray:
    """``W[d, n] = 2 pi f_s MHz P_d(u_n) / S``: rad per MHz of ``c_d`` and unit ``f / f_s``."""
    r = ctx.radar
    return 2 * np.pi * r.sample_rate * MHZ * legendre_basis(unit_fast_time(ctx), degrees) / r.slope


def _times_j_power(z, m: int):
    """``j^m z`` for a complex pair."""
    for _ in range(m % 4):
        z = (-z[1], z[0])
    return z


class ChirpNonlinearity(ExtendedRows, Effect):
    """Ramp frequency error as a Legendre series (``len(degrees)`` parameters, MHz)."""

    name = "chirp_nonlinearity"
    every_path = True
    channel_phase = True
    kind = "mean"
    stage = 1
    per_unit = True
    description = "chirp instantaneous-frequency error e(t) (Legendre series), beat time warp"

    def __init__(self, degrees=(0, 1, 2, 3), taylor_order: int = 3, band_start: float = -0.1,
                 extension: int = 32, prediction_order: int = 32):
        owner = type(self).__name__
        self.degrees = _check_degrees(owner, degrees)
        self.taylor_order = check_int(owner, "taylor_order", taylor_order, 1, 8)
        self.band_start = check_float(owner, "band_start", band_start, -1.0, 0.0)
        self.extension = RowExtension(
            check_int(owner, "extension", extension, 0, 4096),
            check_int(owner, "prediction_order", prediction_order, 1, 256))

    def _nu(self, ctx, n: int) -> np.ndarray:
        """Beat frequency / ``f_s`` on the ``n``-point grid."""
        return band_frequencies(ctx, self.band_start, n) / ctx.radar.sample_rate

    # ------------------------------------------------------------------ init
    def param_specs(self, ctx, model, residual):
        ext = self.extension.fit(model)
        W = phase_weights(ctx, self.degrees)                               # [D, N]
        xe = ext.extend_numpy(model, ext.matrix)
        nu = self._nu(ctx, xe.shape[-1])
        d1 = ext.crop_numpy(np.fft.ifft(nu * np.fft.fft(xe, axis=-1), axis=-1),
                            ext.matrix)                                     # dx/dt / (j 2 pi f_s)
        cols = [(1j * W[d] * d1).ravel() for d in range(len(self.degrees))]
        A = np.stack(cols, axis=1)
        c = np.zeros(len(self.degrees))
        if np.any(A != 0):
            Ar = np.concatenate([A.real, A.imag])
            r = residual.ravel()
            c = np.linalg.lstsq(Ar, np.concatenate([r.real, r.imag]), rcond=None)[0]
        return {"c": ParamSpec(c, lower=-50.0, upper=50.0, unit="MHz")}

    # --------------------------------------------------------------- forward
    def apply(self, x, p, ctx):
        W = phase_weights(ctx, self.degrees)
        phi = 0.0
        for d in range(len(self.degrees)):
            phi = phi + scalar(p["c"], d) * last_axis(W[d])               # [1, 1, 1, 1, N] rad
        ext = self.extension
        E = ext.current(lambda: ops.to_numpy(x), ctx.radar.num_samples)
        nu = self._nu(ctx, ctx.radar.num_samples if E is None else E.shape[0])
        derivs = ext.filter(x, E, [nu ** m for m in range(1, self.taylor_order + 1)])
        out, power = x, 1.0
        for m, dm in enumerate(derivs, start=1):        # d^m x / (j 2 pi f_s)^m
            power = power * phi
            out = ops.cadd(out, ops.scale(_times_j_power(dm, m), power / math.factorial(m)))
        return out

    def summary(self, p, ctx):
        c = np.asarray(p["c"], float)
        u = np.linspace(-1, 1, 201)
        e = c @ legendre_basis(u, self.degrees) * MHZ
        return {"degrees": list(self.degrees), "c_mhz": c.round(5).tolist(),
                "peak_freq_error_khz": float(np.max(np.abs(e)) / 1e3),
                "rms_freq_error_khz": float(np.sqrt(np.mean(e ** 2)) / 1e3)}


def _check_degrees(owner: str, degrees) -> tuple:
    """``degrees`` as a tuple of distinct ints in ``[0, 10]`` or ConfigError."""
    msg = (f"{owner}: degrees must be a non-empty sequence of distinct integers "
           f"in [0, 10], got {degrees!r}")
    try:
        degs = tuple(degrees)
    except TypeError:
        raise ConfigError(msg) from None
    if not degs or len(set(degs)) != len(degs):
        raise ConfigError(msg)
    return tuple(check_int(owner, "degrees", d, 0, 10) for d in degs)

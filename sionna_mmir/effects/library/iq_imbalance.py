"""I/Q imbalance of each receiver's quadrature mixer / ADC pair.

Convention: the I branch is the reference; the Q branch has a gain error
``eps`` and a phase error ``phi`` (its LO is ``90 deg + phi``)::

    I' = I
    Q' = (1 + eps) (Q cos(phi) - I sin(phi))

which in complex form is the widely linear map::

    y = mu x + nu conj(x)
    mu = (1 + (1 + eps) e^{-j phi}) / 2,    nu = (1 - (1 + eps) e^{+j phi}) / 2

A beat tone at ``+f`` therefore gets an image at ``-f`` (the negative-
frequency half of the range profile, or ``max_range - r`` in the complex-
sampling range axis) with image-rejection ratio
``|nu / mu|^2 = (1 - 2 g cos phi + g^2) / (1 + 2 g cos phi + g^2)``, ``g = 1 + eps``.

Parameters: ``iq`` ``[R, 2]`` = (gain error ``eps`` [%], phase error ``phi``
[deg]) per receiver (``2 R`` in all).  Stage 3 (ADC).

Initial values: per Rx the least-squares fit ``residual ~ alpha x + beta conj(x)``
gives ``nu = beta``, hence ``(1 + eps) e^{j phi} = 1 - 2 nu``.
"""
from __future__ import annotations

import numpy as np

from .. import ops
from ..base import Effect, ParamSpec
from ._sensor_common import check_float

DEG = np.pi / 180.0


def mu_nu(eps, phi):
    """``(mu, nu)`` of gain error ``eps`` [1] and phase error ``phi`` [rad] (NumPy)."""
    g = 1.0 + np.asarray(eps, float)
    phi = np.asarray(phi, float)
    return 0.5 * (1 + g * np.exp(-1j * phi)), 0.5 * (1 - g * np.exp(1j * phi))


def image_rejection(eps, phi) -> np.ndarray:
    """Image power relative to the tone, ``|nu / mu|^2`` (closed form)."""
    g, c = 1.0 + np.asarray(eps, float), np.cos(phi)
    return (1 - 2 * g * c + g * g) / (1 + 2 * g * c + g * g)


def fit_widely_linear(model: np.ndarray, residual: np.ndarray) -> np.ndarray:
    """Per Rx ``nu`` of ``residual ~ alpha model + nu conj(model)`` (least squares), ``[R]``."""
    R = model.shape[2]
    nu = np.zeros(R, complex)
    for r in range(R):
        x = model[:, :, r].ravel()
        if not np.any(x != 0):
            continue
        A = np.stack([x, np.conj(x)], axis=1)
        coef = np.linalg.lstsq(A, residual[:, :, r].ravel(), rcond=None)[0]
        nu[r] = coef[1]
    return nu


class IQImbalance(Effect):
    """Per-Rx gain and phase error of the Q branch (``2 R`` parameters: %, deg)."""

    name = "iq_imbalance"
    every_path = True
    kind = "mean"
    stage = 3
    per_unit = True
    description = "per-receiver I/Q gain and phase imbalance (image at -f)"

    def __init__(self, max_gain_error: float = 0.5, max_phase_deg: float = 30.0):
        owner = type(self).__name__
        self.max_gain_error = check_float(owner, "max_gain_error", max_gain_error, 0.0, 0.99,
                                          lo_open=True)
        self.max_phase_deg = check_float(owner, "max_phase_deg", max_phase_deg, 0.0, 89.0,
                                         lo_open=True)

    def param_specs(self, ctx, model, residual):
        nu = fit_widely_linear(model, residual)
        ge = 1.0 - 2.0 * nu                                               # (1 + eps) e^{j phi}
        eps = (np.abs(ge) - 1.0) * 100.0
        phi = np.angle(ge) / DEG
        lim_e, lim_p = 100.0 * self.max_gain_error, self.max_phase_deg
        return {"iq": ParamSpec(np.stack([eps, phi], axis=1), lower=[-lim_e, -lim_p],
                                upper=[lim_e, lim_p], unit="%, deg")}

    def apply(self, x, p, ctx):
        R = ctx.radar.num_rx
        s = (1, 1, R, 1, 1)
        g = 1.0 + 0.01 * ops.column(p["iq"], 0, s)
        sin, cos = ops.dr.sincos(DEG * ops.column(p["iq"], 1, s))
        mu = (0.5 * (1.0 + g * cos), -0.5 * g * sin)
        nu = (0.5 * (1.0 - g * cos), -0.5 * g * sin)
        return ops.cadd(ops.cmul(mu, x), ops.cmul(nu, ops.conj(x)))

    def summary(self, p, ctx):
        iq = np.asarray(p["iq"], float)
        irr = image_rejection(iq[:, 0] / 100.0, iq[:, 1] * DEG)
        return {"gain_error_pct": iq[:, 0].round(4).tolist(),
                "phase_error_deg": iq[:, 1].round(4).tolist(),
                "image_rejection_db": (10 * np.log10(np.maximum(irr, 1e-30))).round(2).tolist()}

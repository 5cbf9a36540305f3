"""0006: float32 slab coefficients and their gradient w.r.t. eps'' (low loss).

``itu_coefficients_single_layer_slab`` (eps' = 3, d = 5 cm, 77 GHz, 30 deg
incidence): reverse-mode ``d|T_TE|^2 / d eps''`` for eps'' in
[1e-5, 1e-1], against the closed form in float64 (NumPy, same equations).
The cause is the cancelling ``sqrt((|x| - x_r)/2)`` in ``cpx_sqrt``.
Stock 2.2.0: 13 % error at eps'' = 1e-3, a zero gradient below ~3e-4.
Patched: < 1e-4 relative error everywhere.
"""
from __future__ import annotations

import numpy as np

from _common import report, setup

args, rt = setup(__doc__.splitlines()[0])
import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402
from sionna.rt.utils import itu_coefficients_single_layer_slab  # noqa: E402

EPS_R, D, F_HZ, THETA = 3.0, 0.05, 77e9, np.deg2rad(30.0)
LAM = 299_792_458.0 / F_HZ
COS = np.cos(THETA)
EPS_I = np.array([1e-1, 1e-2, 3e-3, 1e-3, 3e-4, 1e-4, 1e-5])


def t_te_power_ref(eps_i):
    """|T_TE|^2 of the ITU-R P.2040 slab (eqs. 37a, 43b, 44) in float64."""
    eta = EPS_R - 1j * eps_i
    a = np.sqrt(eta - (1 - COS**2))
    q = 2 * np.pi * D / LAM * a
    r = (COS - a) / (COS + a)
    t = (1 - r**2) * np.exp(-1j * q) / (1 - r**2 * np.exp(-2j * q))
    return np.abs(t) ** 2


x = mi.Float(EPS_I.astype(np.float32))
dr.enable_grad(x)
n = len(EPS_I)
_, _, t_te, _ = itu_coefficients_single_layer_slab(
    dr.full(mi.Float, COS, n), mi.Complex2f(dr.full(mi.Float, EPS_R, n), -x),
    dr.full(mi.Float, D, n), dr.full(mi.Float, LAM, n))
power = dr.squared_norm(t_te)
dr.backward(dr.sum(power))
grad = x.grad.numpy().astype(np.float64)
h = EPS_I * 1e-4
grad_ref = (t_te_power_ref(EPS_I + h) - t_te_power_ref(EPS_I - h)) / (2 * h)
err = np.abs(grad - grad_ref) / np.abs(grad_ref)
val_err = np.abs(power.numpy() - t_te_power_ref(EPS_I))
for e, g, gr, er, ve in zip(EPS_I, grad, grad_ref, err, val_err):
    print(f"eps''={e:7.0e}  grad {g:+10.4f}  float64 {gr:+10.4f}  rel. err {er:8.2e}  "
          f"|T|^2 abs. err {ve:.1e}")
worst = float(err.max())
observed = "bug" if worst > 0.05 else ("fixed" if worst < 1e-3 else "inconclusive")
i3 = int(np.argmin(np.abs(EPS_I - 1e-3)))
report("0006 cpx_sqrt cancellation", args.expect, observed,
       f"worst gradient error {worst:.2e} over eps'' in [1e-5, 1e-1]; "
       f"at eps''=1e-3: {err[i3]:.2e}")

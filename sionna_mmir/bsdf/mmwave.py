"""The mmIR physically-based mmWave BSDF (paper Sec. 3.2, eqs. bsdf_full/coh/inc).

    f   = A [ eta f_coh + (1 - eta) f_inc ]
    f_coh = tau f_KA + (1 - tau) f_SPM
    f_inc = gamma f_dir + (1 - gamma) f_broad

==============  ==============================================================
``eta``         Rayleigh roughness factor ``exp(-(2 k sigma_h cos theta_t)^2)``,
                ``k = 2 pi / lambda``, ``cos theta_t = wi.z``
``f_KA``        GGX lobe (:mod:`.ggx`), ``alpha = sqrt(4 pi sigma_h / lambda)``
``f_SPM``       vMF lobe (:mod:`.vmf`) about the mirror direction,
                ``kappa = sqrt(l_c / lambda) / (1 + 3 sigma_h / l_c)``
``f_dir``       broader vMF lobe, **kappa_dir = max(kappa / 4, 1)** (our choice)
``f_broad``     Lambertian (:mod:`.lambertian`)
``gamma``       **gamma = sigmoid((0.1 - sigma_h/lambda) / 0.03)** (our choice):
                the incoherent scatter stays directional for
                ``sigma_h << 0.1 lambda`` and becomes diffuse for
                ``sigma_h >> 0.1 lambda``; smooth in ``sigma_h``
``A``           energy gate in ``[0, 1]``, e.g. from
                :func:`sionna_mmir.radio_materials.fresnel.energy_gate`
                (``gate`` field, default 1)
==============  ==============================================================

The four lobe weights ``w = (eta tau, eta (1-tau), (1-eta) gamma,
(1-eta)(1-gamma))`` sum to one.  :func:`sample` picks a lobe with probability
``w_i`` and returns the balance-heuristic (one-sample MIS) pdf
``sum_i w_i pdf_i`` (full-sphere solid-angle density; directions below the
surface have zero value).  :func:`eval` returns the BSDF value per steradian
**without** the cosine ``cos(theta_o)``.  Since ``f_i cos_o <= pdf_i`` for
every lobe, the directional albedo with ``A = 1`` is ``<= 1``.

Reference: mmIR paper (``shared/reference/mmIR_paper.tex``); Walter et al.
2007; Heitz 2018; Wood 1994; Wei et al. CSVBSDF.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from . import ggx, lambertian, vmf
from ._common import as_float, dr, mi

#: gamma sigmoid centre and width in units of sigma_h / lambda
GAMMA_CENTER = 0.1
GAMMA_WIDTH = 0.03
#: kappa_dir = max(kappa / KAPPA_DIR_DIVISOR, KAPPA_DIR_MIN)
KAPPA_DIR_DIVISOR = 4.0
KAPPA_DIR_MIN = 1.0


@dataclass
class MMWaveParams:
    """Material parameters at one interaction (floats or ``mi.Float``).

    Parameters
    ----------
    sigma_h : float or mi.Float
        RMS surface height [m]
    l_c : float or mi.Float
        surface correlation length [m] (> 0)
    tau : float or mi.Float
        KA / SPM blend in ``[0, 1]``
    wavelength : float or mi.Float
        free-space wavelength ``lambda`` [m]
    gate : float or mi.Float, optional
        energy gate ``A`` in ``[0, 1]`` (default 1)
    """

    sigma_h: Any
    l_c: Any
    tau: Any
    wavelength: Any
    gate: Any = 1.0

    def alpha(self):
        """GGX roughness ``sqrt(4 pi sigma_h / lambda)`` (clamped >= 1e-3 in :mod:`.ggx`)."""
        return dr.sqrt(dr.maximum(4.0 * dr.pi * as_float(self.sigma_h) / as_float(self.wavelength),
                                  1e-12))

    def kappa(self):
        """SPM concentration ``sqrt(l_c/lambda) / (1 + 3 sigma_h / l_c)``."""
        lc = as_float(self.l_c)
        return dr.sqrt(lc / as_float(self.wavelength)) / (1.0 + 3.0 * as_float(self.sigma_h) / lc)

    def kappa_dir(self):
        """Concentration of the broad vMF lobe ``max(kappa/4, 1)``."""
        return dr.maximum(self.kappa() / KAPPA_DIR_DIVISOR, KAPPA_DIR_MIN)

    def gamma(self):
        """Directional fraction of the incoherent part ``sigmoid((0.1 - sigma_h/lambda)/0.03)``."""
        x = (GAMMA_CENTER - as_float(self.sigma_h) / as_float(self.wavelength)) / GAMMA_WIDTH
        return 1.0 / (1.0 + dr.exp(-x))

    def eta(self, cos_t):
        """Rayleigh factor ``exp(-(2 k sigma_h cos theta_t)^2)``."""
        k = 2.0 * dr.pi / as_float(self.wavelength)
        return dr.exp(-dr.square(2.0 * k * as_float(self.sigma_h) * cos_t))

    def weights(self, wi):
        """Lobe weights ``(w_KA, w_SPM, w_dir, w_broad)`` for incident ``wi`` (sum 1)."""
        eta = self.eta(dr.maximum(wi.z, 0.0))
        tau = as_float(self.tau)
        gamma = self.gamma()
        return (eta * tau, eta * (1.0 - tau), (1.0 - eta) * gamma,
                (1.0 - eta) * (1.0 - gamma))


def _lobes(p: MMWaveParams):
    return ((ggx, p.alpha()), (vmf, p.kappa()), (vmf, p.kappa_dir()), (lambertian, None))


def eval(wi, wo, params: MMWaveParams):  # noqa: A001
    """BSDF value ``f`` (per sr, cosine NOT included), differentiable in all params."""
    w = params.weights(wi)
    total = mi.Float(0.0)
    for wk, (lobe, prm) in zip(w, _lobes(params)):
        total += wk * lobe.eval(wi, wo, prm)
    return as_float(params.gate) * total


def pdf(wi, wo, params: MMWaveParams):
    """Solid-angle pdf of :func:`sample`: ``sum_i w_i pdf_i`` (full sphere)."""
    w = params.weights(wi)
    total = mi.Float(0.0)
    for wk, (lobe, prm) in zip(w, _lobes(params)):
        total += wk * lobe.pdf(wi, wo, prm)
    return dr.select(wi.z > 0, total, mi.Float(0.0))


def sample(wi, u1, u2, params: MMWaveParams):
    """Lobe-selection sampling.

    Parameters
    ----------
    wi : mi.Vector3f
        incident direction (local frame)
    u1 : mi.Float
        uniform in ``[0,1)``: picks lobe ``i`` w.p. ``w_i``
    u2 : mi.Point2f
        uniform in ``[0,1)^2``: direction within the lobe
    params : MMWaveParams
        :class:`MMWaveParams`

    Returns
    -------
    wo : mi.Vector3f
        sampled direction
    pdf : mi.Float
        the mixture pdf of :func:`pdf`
    """
    w = params.weights(wi)
    lobes = _lobes(params)
    wo, _ = lobes[3][0].sample(wi, u2, lobes[3][1])
    cdf = mi.Float(0.0)
    for wk, (lobe, prm) in zip(w[:3], lobes[:3]):
        cand, _ = lobe.sample(wi, u2, prm)
        sel = (u1 >= cdf) & (u1 < cdf + wk)
        wo = dr.select(sel, cand, wo)
        cdf = cdf + wk
    return wo, pdf(wi, wo, params)

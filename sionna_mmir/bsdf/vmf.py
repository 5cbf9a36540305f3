"""von Mises-Fisher lobe around the mirror direction (``f_SPM`` and ``f_dir``).

The density on the unit sphere ``S^2`` with mean ``mu = reflect(wi) =
(-wi.x, -wi.y, wi.z)`` and concentration ``kappa`` is

    p(wo) = kappa / (2 pi (1 - exp(-2 kappa))) * exp(kappa (mu . wo - 1))

(written in the numerically stable ``exp(kappa (mu.wo - 1))`` form).

* ``eval`` returns ``p(wo)`` for ``wi.z > 0`` and ``wo.z > 0`` and ``0``
  otherwise: the lobe is **truncated by the hemisphere** (energy leaving
  below the surface is lost, so its albedo is ``<= 1``).  No cosine factor.
* ``pdf`` / ``sample`` are the *full-sphere* vMF density: sampled directions
  below the surface are returned (with their pdf) and carry zero value.
* The lobe is reciprocal: ``mu . wo = -wi.x wo.x - wi.y wo.y + wi.z wo.z`` is
  symmetric in ``(wi, wo)``.

Sampling uses the exact inversion of the ``cos``-marginal on ``S^2``
(Wood 1994, "Simulation of the von Mises Fisher distribution", Commun.
Stat. Simul. Comput. 23(1)):  ``w = 1 + log(u + (1-u) exp(-2 kappa)) / kappa``.

Concentration is clamped to ``kappa >= KAPPA_MIN`` (1e-3) for stability.
In the mmIR paper (Sec. 3.2) ``f_SPM`` uses
``kappa = sqrt(l_c/lambda) / (1 + 3 sigma_h / l_c)``.
"""
from __future__ import annotations

from ._common import as_float, dr, mi, reflect_z

KAPPA_MIN = 1e-3


def _kappa(kappa):
    return dr.maximum(as_float(kappa), KAPPA_MIN)


def density(mu, wo, kappa):
    """Full-sphere vMF density of ``wo`` for mean ``mu`` (no hemisphere test)."""
    k = _kappa(kappa)
    norm = k / (2.0 * dr.pi * (1.0 - dr.exp(-2.0 * k)))
    return norm * dr.exp(k * (dr.dot(mu, wo) - 1.0))


def eval(wi, wo, kappa):  # noqa: A001
    """Hemisphere-truncated vMF BSDF value (per sr, no cosine).

    Parameters
    ----------
    wi, wo : mi.Vector3f
        unit directions, local frame
    kappa : float or mi.Float
        concentration (differentiable)

    Returns
    -------
    mi.Float
    """
    valid = (wi.z > 0) & (wo.z > 0)
    return dr.select(valid, density(reflect_z(wi), wo, kappa), mi.Float(0.0))


def pdf(wi, wo, kappa):
    """Full-sphere solid-angle pdf of :func:`sample` (0 when ``wi.z <= 0``)."""
    return dr.select(wi.z > 0, density(reflect_z(wi), wo, kappa), mi.Float(0.0))


def sample(wi, u2, kappa):
    """Sample ``wo ~ vMF(reflect(wi), kappa)`` on the full sphere (Wood 1994).

    Parameters
    ----------
    wi : mi.Vector3f
        incident direction
    u2 : mi.Point2f
        uniform in ``[0,1)^2``
    kappa : float or mi.Float
        concentration

    Returns
    -------
    wo : mi.Vector3f
        sampled direction; may lie below the surface
    pdf : mi.Float
        its pdf
    """
    k = _kappa(kappa)
    u = dr.maximum(u2.x, 1e-30)
    w = 1.0 + dr.log(u + (1.0 - u) * dr.exp(-2.0 * k)) / k
    w = dr.clip(w, -1.0, 1.0)
    sin_t = dr.safe_sqrt(1.0 - w * w)
    s, c = dr.sincos(2.0 * dr.pi * u2.y)
    local = mi.Vector3f(sin_t * c, sin_t * s, w)
    mu = reflect_z(wi)
    wo = mi.Frame3f(mu).to_world(local)
    return wo, pdf(wi, wo, kappa)

"""Lambertian (ideal diffuse) lobe ``f_broad`` of the mmIR BSDF.

====================  ===================================================
``eval(wi, wo)``      ``1/pi`` when both directions are above the surface
``pdf(wi, wo)``       cosine-weighted hemisphere pdf ``cos(theta_o)/pi``
                      (solid angle; 0 below the surface)
``sample(wi, u2)``    cosine-weighted hemisphere sample (Malley's method)
====================  ===================================================

``eval`` returns the BSDF value per steradian *without* the foreshortening
cosine ``cos(theta_o)``.  The lobe has no parameters; ``params`` is accepted
(and ignored) so that all lobes share one signature.
"""
from __future__ import annotations

from ._common import dr, mi

INV_PI = 1.0 / dr.pi


def eval(wi, wo, params=None):  # noqa: A001  (Mitsuba naming)
    """BSDF value ``1/pi`` on the upper hemisphere (both ``wi.z, wo.z > 0``)."""
    valid = (wi.z > 0) & (wo.z > 0)
    return dr.select(valid, mi.Float(INV_PI), mi.Float(0.0))


def pdf(wi, wo, params=None):
    """Solid-angle pdf of :func:`sample`: ``max(0, wo.z)/pi`` (0 if ``wi.z <= 0``)."""
    valid = (wi.z > 0) & (wo.z > 0)
    return dr.select(valid, wo.z * INV_PI, mi.Float(0.0))


def sample(wi, u2, params=None):
    """Cosine-weighted direction ``wo`` and its pdf for the 2-D uniform sample ``u2``.

    Parameters
    ----------
    wi : mi.Vector3f
        incident direction (local)
    u2 : mi.Point2f
        uniform in ``[0,1)^2``
    params : object, optional
        ignored

    Returns
    -------
    wo : mi.Vector3f
        sampled direction
    pdf : mi.Float
        its pdf; 0 when ``wi.z <= 0``
    """
    wo = mi.warp.square_to_cosine_hemisphere(u2)
    return wo, pdf(wi, wo)

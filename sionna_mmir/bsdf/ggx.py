"""GGX microfacet specular lobe ``f_KA`` (Kirchhoff approximation).

Walter, Marschner, Li, Torrance 2007, "Microfacet Models for Refraction
through Rough Surfaces" (EGSR), with visible-normal sampling of Heitz 2018,
"Sampling the GGX Distribution of Visible Normals" (JCGT 7(4)).

==========  ==============================================================
``D(h)``    ``alpha^2 / (pi ((alpha^2 - 1) h.z^2 + 1)^2)``  (Walter eq. 33)
``G1(w)``   ``2 / (1 + sqrt(1 + alpha^2 tan^2 theta_w))``   (Smith, eq. 34)
``G``       separable ``G1(wi) G1(wo)``
``eval``    ``D(h) G / (4 cos_i cos_o)``, ``h = normalize(wi + wo)``
``pdf``     VNDF: ``D(h) G1(wi) max(0, wi.h) / cos_i / (4 wo.h)``
            ``= D(h) G1(wi) / (4 cos_i)``
==========  ==============================================================

Fresnel is excluded (the mmIR energy gate ``A`` carries it); ``eval`` has no
foreshortening cosine.  ``pdf``/``sample`` are defined on the full sphere:
VNDF reflection can send ``wo`` below the surface, where the value is 0.
``alpha`` is clamped to ``>= ALPHA_MIN`` (1e-3).  In the mmIR paper
``alpha = sqrt(4 pi sigma_h / lambda)``.
"""
from __future__ import annotations

from ._common import as_float, dr, mi

ALPHA_MIN = 1e-3


def _alpha(alpha):
    return dr.maximum(as_float(alpha), ALPHA_MIN)


def distribution(cos_h, alpha):
    """GGX normal distribution ``D`` for ``cos_h = h.z > 0`` (0 otherwise)."""
    a2 = dr.square(_alpha(alpha))
    t = (a2 - 1.0) * cos_h * cos_h + 1.0
    return dr.select(cos_h > 0, a2 / (dr.pi * t * t), mi.Float(0.0))


def smith_g1(w, h, alpha):
    """Smith shadowing ``G1(w, h)`` for GGX (Walter 2007 eq. 34)."""
    a2 = dr.square(_alpha(alpha))
    cos2 = dr.square(w.z)
    tan2 = dr.maximum(1.0 - cos2, 0.0) / dr.maximum(cos2, 1e-12)
    g = 2.0 / (1.0 + dr.sqrt(1.0 + a2 * tan2))
    return dr.select((dr.dot(w, h) * w.z > 0) & (w.z > 0), g, mi.Float(0.0))


def _half(wi, wo):
    h = wi + wo
    n = dr.norm(h)
    return h / dr.maximum(n, 1e-12), n > 1e-6


def eval(wi, wo, alpha):  # noqa: A001
    """GGX reflection value ``D G / (4 cos_i cos_o)`` (per sr, no cosine, no Fresnel).

    Parameters
    ----------
    wi, wo : mi.Vector3f
        unit directions, local frame
    alpha : float or mi.Float
        GGX roughness (differentiable)

    Returns
    -------
    mi.Float
    """
    h, ok = _half(wi, wo)
    valid = ok & (wi.z > 0) & (wo.z > 0) & (h.z > 0)
    val = distribution(h.z, alpha) * smith_g1(wi, h, alpha) * smith_g1(wo, h, alpha) \
        / (4.0 * dr.maximum(wi.z * wo.z, 1e-12))
    return dr.select(valid, val, mi.Float(0.0))


def pdf(wi, wo, alpha):
    """Full-sphere solid-angle pdf of :func:`sample` (VNDF, Heitz 2018 eq. 17 + Jacobian)."""
    h, ok = _half(wi, wo)
    valid = ok & (wi.z > 0) & (h.z > 0) & (dr.dot(wi, h) > 0)
    val = distribution(h.z, alpha) * smith_g1(wi, h, alpha) / (4.0 * dr.maximum(wi.z, 1e-12))
    return dr.select(valid, val, mi.Float(0.0))


def sample_visible_normal(wi, u2, alpha):
    """Heitz 2018 (listing 1): microfacet normal ``h`` ~ visible-normal distribution."""
    a = _alpha(alpha)
    vh = dr.normalize(mi.Vector3f(a * wi.x, a * wi.y, wi.z))
    lensq = vh.x * vh.x + vh.y * vh.y
    inv = dr.rsqrt(dr.maximum(lensq, 1e-20))
    t1 = dr.select(lensq > 1e-14, mi.Vector3f(-vh.y * inv, vh.x * inv, 0.0),
                   mi.Vector3f(1.0, 0.0, 0.0))
    t2 = dr.cross(vh, t1)
    r = dr.sqrt(u2.x)
    s, c = dr.sincos(2.0 * dr.pi * u2.y)
    p1 = r * c
    p2 = r * s
    sw = 0.5 * (1.0 + vh.z)
    p2 = (1.0 - sw) * dr.safe_sqrt(1.0 - p1 * p1) + sw * p2
    nh = p1 * t1 + p2 * t2 + dr.safe_sqrt(1.0 - p1 * p1 - p2 * p2) * vh
    return dr.normalize(mi.Vector3f(a * nh.x, a * nh.y, dr.maximum(nh.z, 0.0)))


def sample(wi, u2, alpha):
    """Sample ``wo`` by reflecting ``wi`` about a VNDF-sampled microfacet normal.

    Parameters
    ----------
    wi : mi.Vector3f
        incident direction (``wi.z > 0``)
    u2 : mi.Point2f
        uniform in ``[0,1)^2``
    alpha : float or mi.Float
        GGX roughness

    Returns
    -------
    wo : mi.Vector3f
        sampled direction; may lie below the surface
    pdf : mi.Float
        its pdf
    """
    h = sample_visible_normal(wi, u2, alpha)
    wo = 2.0 * dr.dot(wi, h) * h - wi
    return wo, pdf(wi, wo, alpha)

"""Exact physical-optics phase average over a flat triangle (Dr.Jit, AD).

A Monte Carlo sample ``x`` on triangle ``t`` stands for the Kirchhoff
integral over ``t``; multiplying its amplitude by the triangle average

    F = (1 / A) int_t exp(-j q . (y - x)) dA(y),     q = k (k_in - k_t)

(``k_in`` incoming propagation direction, ``k_t`` unit vector towards the
transmitter; ``q`` is the gradient of the path phase ``k L(y)``, exact to first
order across the triangle) integrates the phase oscillation inside each
triangle exactly (a Rao-Blackwellisation of the physical-optics estimator,
Gordon 1975 in spirit).  The remaining variance comes only from *which*
triangles are hit, which removes most of the Monte Carlo noise of oblique
flat surfaces.  The solver applies it only to triangles small against the
Fresnel zone (``k D^2 / R < 1`` for the longest edge ``D`` at range ``R``),
where the phase is linear across the triangle -- e.g. LiDAR meshes -- and
keeps the point sample elsewhere.  With ``y = P0 + u e1 + v e2``, by the Hermite-Genocchi
formula

    int_simplex exp(alpha u + beta v) du dv = exp[0, alpha, beta]

(second divided difference of ``exp``), so ``F = exp(-j q.(P0 - x)) * 2 *
exp[0, -j a, -j b]`` with ``a = q.e1``, ``b = q.e2``.  Near-coincident nodes
use series expansions.
"""
from __future__ import annotations

from ..utils.backend import init_backend

init_backend()

import drjit as dr  # noqa: E402

SMALL = 1e-2


def _g1(a):
    """``exp[0, -j a] = (e^{-ja} - 1) / (-j a)`` -> (re, im)."""
    small = dr.abs(a) < SMALL
    a_s = dr.select(small, 1.0, a)
    re = dr.select(small, 1.0 - a * a / 6.0, dr.sin(a_s) / a_s)
    im = dr.select(small, -0.5 * a + a * a * a / 24.0, (dr.cos(a_s) - 1.0) / a_s)
    return re, im


def _g1_prime(c):
    """``d/dz exp[0, z]`` at ``z = -j c`` -> (re, im)."""
    small = dr.abs(c) < 5 * SMALL
    cs = dr.select(small, 1.0, c)
    c2 = cs * cs
    re = dr.select(small, 0.5 - c * c / 8.0, -(1.0 - dr.cos(cs) - cs * dr.sin(cs)) / c2)
    im = dr.select(small, -c / 3.0 + c * c * c / 30.0, -(dr.sin(cs) - cs * dr.cos(cs)) / c2)
    return re, im


def triangle_phase_average(q, p0, p1, p2, x):
    """``F`` of the module docstring -> ``(re, im)`` ``mi.Float``.

    ``q`` ``mi.Vector3f`` [rad/m]; ``p0, p1, p2`` triangle vertices and ``x``
    the sample point (``mi.Point3f``, m).  Differentiable in all inputs.
    """
    a = dr.dot(q, p1 - p0)
    b = dr.dot(q, p2 - p0)
    r1, i1 = _g1(a)
    r2, i2 = _g1(b)
    d = a - b
    close = dr.abs(d) < SMALL
    ds = dr.select(close, 1.0, d)
    # (g1(-ja) - g1(-jb)) / (-j (a - b)) = (Delta) * j / (a - b)
    fr = dr.select(close, 0.0, -(i1 - i2) / ds)
    fi = dr.select(close, 0.0, (r1 - r2) / ds)
    pr, pi_ = _g1_prime(0.5 * (a + b))
    fr = dr.select(close, pr, fr)
    fi = dr.select(close, pi_, fi)
    # times 2 (simplex area 1/2) and exp(-j q.(p0 - x))
    ph = dr.dot(q, p0 - x)
    c, s = dr.cos(ph), -dr.sin(ph)
    return 2.0 * (fr * c - fi * s), 2.0 * (fr * s + fi * c)

"""Jones transport of the polarisation state along a path (Dr.Jit, AD).

The field is a complex transverse 3-vector ``E = E_re + j E_im`` (scene
frame).  At a reflection with unit propagation direction ``k_in``, unit normal
``n`` (either side) and mirror direction ``k_out = k_in - 2 (k_in . n) n``, the
local basis is

    s = normalize(k_in x n)          (TE, perpendicular to the plane of incidence)
    p_in = s x k_in,  p_out = s x k_out   (TM)

and ``E_out = R_s (E . s) s + R_p (E . p_in) p_out``.  With this basis the
ITU-R P.2040 / Born & Wolf coefficients of
:mod:`sionna_mmir.radio_materials.fresnel` (``r_p = -r_s`` at normal
incidence) act isotropically at normal incidence, and a perfect conductor
(``r_s -> -1``, ``r_p -> +1``) reverses the tangential field and keeps the
normal one, as it must.  At normal incidence ``k_in x n`` vanishes; any
``s`` perpendicular to ``k_in`` is then valid and one is chosen from a fixed
helper axis.
"""
from __future__ import annotations

from ..utils.backend import init_backend

init_backend()

import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402


class Field:
    """Complex transverse field vector ``re + j im`` (two ``mi.Vector3f``)."""

    def __init__(self, re, im=None):
        self.re = re
        self.im = im if im is not None else dr.zeros(mi.Vector3f, dr.width(re.x))

    def scale(self, c_re, c_im=0.0):
        """Multiply by the complex scalar ``c_re + j c_im``."""
        return Field(self.re * c_re - self.im * c_im, self.re * c_im + self.im * c_re)

    def dot(self, v):
        """``E . v`` for a real vector ``v`` -> ``(re, im)``."""
        return dr.dot(self.re, v), dr.dot(self.im, v)

    def power(self):
        """``|E|^2``."""
        return dr.squared_norm(self.re) + dr.squared_norm(self.im)

    def select(self, mask, other):
        return Field(dr.select(mask, self.re, other.re), dr.select(mask, self.im, other.im))


def perpendicular_basis(k_in, n):
    """``(s, p_in)`` of the plane of incidence (see module docstring)."""
    s = dr.cross(k_in, n)
    ln = dr.norm(s)
    helper = dr.select(dr.abs(k_in.z) < 0.9, mi.Vector3f(0, 0, 1), mi.Vector3f(1, 0, 0))
    s_alt = dr.normalize(dr.cross(k_in, helper))
    s = dr.select(ln > 1e-6, s / dr.maximum(ln, 1e-20), s_alt)
    return s, dr.cross(s, k_in)


def mirror(k_in, n):
    """Mirror direction ``k_in - 2 (k_in . n) n``."""
    return k_in - 2.0 * dr.dot(k_in, n) * n


def reflect_field(E: Field, k_in, n, r_s, r_p) -> Field:
    """Reflect ``E`` with complex coefficients ``r_s``, ``r_p`` (``mi.Complex2f``).

    Returns the reflected field along ``mirror(k_in, n)``.
    """
    s, p_in = perpendicular_basis(k_in, n)
    p_out = dr.cross(s, mirror(k_in, n))
    es_re, es_im = E.dot(s)
    ep_re, ep_im = E.dot(p_in)
    # (a + jb)(c + jd) = (ac - bd) + j(ad + bc)
    os_re = r_s.real * es_re - r_s.imag * es_im
    os_im = r_s.real * es_im + r_s.imag * es_re
    op_re = r_p.real * ep_re - r_p.imag * ep_im
    op_im = r_p.real * ep_im + r_p.imag * ep_re
    return Field(s * os_re + p_out * op_re, s * os_im + p_out * op_im)


def polarization_fractions(E: Field, k_in, n):
    """Power fractions ``(f_s, f_p)`` of ``E`` in the s/p basis (sum 1 where E != 0)."""
    s, p_in = perpendicular_basis(k_in, n)
    a = dr.square(dr.dot(E.re, s)) + dr.square(dr.dot(E.im, s))
    b = dr.square(dr.dot(E.re, p_in)) + dr.square(dr.dot(E.im, p_in))
    tot = dr.maximum(a + b, 1e-30)
    return a / tot, b / tot


def transverse(v, k):
    """Unit projection of ``v`` onto the plane perpendicular to unit ``k``."""
    t = v - dr.dot(v, k) * k
    return dr.normalize(t)

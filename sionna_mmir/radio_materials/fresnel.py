"""Closed-form interface and slab physics of the mmIR energy gate.

Everything here is a plane wave incident from air (vacuum) on a medium of
complex relative permittivity ``eps_r = eps' - j eps''`` (``eps'' >= 0``,
time dependence ``exp(+j w t)``, non-magnetic ``mu_r = 1``), as a function of
the cosine of the angle of incidence ``theta`` measured from the normal.

Single interface (ITU-R P.2040-3 Section 2.2.1.5, eqs. (37a), (37b);
Born & Wolf, *Principles of Optics*, Sec. 1.5.2)::

    a   = sqrt(eps_r - sin^2 theta)                  (= n cos theta_t)
    r_s = (cos theta - a) / (cos theta + a)          TE  / perpendicular  (37a)
    r_p = (eps_r cos theta - a) / (eps_r cos theta + a)   TM / parallel   (37b)
    t_s = 2 cos theta / (cos theta + a)
    t_p = 2 n cos theta / (eps_r cos theta + a),     n = sqrt(eps_r)

``r``/``t`` are ratios of complex electric-field amplitudes.  With this
(P.2040 / Born & Wolf) sign convention ``r_p = -r_s`` at normal incidence,
``t_s = 1 + r_s`` and ``t_p = (1 + r_p) / n``.  Power balance for a
lossless medium: ``|r|^2 + Re(a) / cos(theta) * |t|^2 = 1`` for both
polarisations.

Single-layer slab of thickness ``d`` with air on both sides, multiple
internal reflections summed coherently (ITU-R P.2040-3 Section 2.2.2.2,
eqs. (43a), (43b), (44))::

    q   = (2 pi d / lambda) sqrt(eps_r - sin^2 theta)                  (44)
    R   = r (1 - e^{-j2q}) / (1 - r^2 e^{-j2q})                         (43a)
    T   = (1 - r^2) e^{-jq} / (1 - r^2 e^{-j2q})                        (43b)

with ``r`` the single-interface coefficient of the same polarisation.  This is
the Airy sum ``R = r12 + t12 t21 r23 e^{-j2q} / (1 - r21 r23 e^{-j2q})`` with
the Stokes relations ``r21 = -r12``, ``t12 t21 = 1 - r12^2`` (Born & Wolf
Sec. 7.6.1 / 1.6.4).  ``T`` of eq. (43b) relates the field leaving the back
face to the field arriving at the front face *at the same lateral position*
(the phase reference of the characteristic-matrix method).  A ray tracer that
treats the wall as an infinitely thin surface already propagates the ray
through the slab region in free space, i.e. adds ``e^{-j q0}`` with
``q0 = 2 pi d cos(theta) / lambda``; for it the insertion coefficient
``T e^{+j q0} = (1 - r^2) e^{-j(q - q0)} / (1 - r^2 e^{-j2q})`` is the right
one (``transmission_phase="insertion"``).  Magnitudes are identical.

The mmIR energy gate (paper Sec. 3.2) is ``A = f_s |R_s|^2 + f_p |R_p|^2``.

Backends
--------
Every public function exists for NumPy (complex128) and Dr.Jit
(``mi.Complex2f`` in the variant chosen by
:func:`sionna_mmir.utils.backend.init_backend`, float32 on the LLVM/CUDA
``*_ad_mono_polarized`` variants).  ``backend="auto"`` picks Dr.Jit when any
argument is a Dr.Jit array.  The Dr.Jit code is branch-free (only
``dr.select``) and differentiable w.r.t. ``eps'``, ``eps''``, ``d`` and
``cos theta``; its complex square root uses ``Im = Im(w) / (2 Re)`` so that
gradients stay finite for lossless media.  Float32 limits the phase accuracy
to about ``|q| * 6e-8`` rad (e.g. 4e-5 rad for a 0.2 m concrete wall at
77 GHz).

``cos_theta`` is used as ``clip(|cos_theta|, 1e-6, 1)``: back-face hits see
the same symmetric slab, and the floor keeps exact grazing incidence away
from ``|r| = 1``.  ``eps_r - sin^2`` is evaluated as ``(eps_r - 1) + cos^2``
(no cancellation for near-vacuum media at grazing incidence in float32).
Where the denominator ``1 - r^2 e^{-j2q}`` of eqs. (43) vanishes (only the
removable ``0/0`` at ``d = 0`` when ``|r|`` rounds to 1, e.g. metals) it is
replaced by 1.  That gives the correct ``R = 0``; ``T = 1 - r^2`` is then
inaccurate (the ``d -> 0`` limit is 1), which only matters for a zero-
thickness slab with ``|r|`` within float rounding of 1.

References
----------
ITU-R P.2040-3 (2023), Sections 2.2.1-2.2.2.
M. Born, E. Wolf, *Principles of Optics*, 7th ed., Secs. 1.5-1.6.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..errors import InputValueError

SPEED_OF_LIGHT = 299_792_458.0
"""[m/s]; same value as :data:`sionna_mmir.radar.config.SPEED_OF_LIGHT`."""

COS_THETA_MIN = 1e-6
"""Floor on ``|cos theta|`` (see the module docstring)."""

TRANSMISSION_PHASES = ("p2040", "insertion")


class InterfaceCoefficients(NamedTuple):
    """Complex single-interface Fresnel coefficients (air -> medium)."""

    r_s: object
    r_p: object
    t_s: object
    t_p: object


class SlabCoefficients(NamedTuple):
    """Complex single-layer slab coefficients (air | slab | air)."""

    r_s: object
    r_p: object
    t_s: object
    t_p: object


# --------------------------------------------------------------------------
# backend selection
# --------------------------------------------------------------------------
def _is_drjit(x) -> bool:
    return type(x).__module__.split(".")[0] == "drjit"


def _resolve_backend(backend: str, *args) -> str:
    if backend == "auto":
        return "drjit" if any(_is_drjit(a) for a in args) else "numpy"
    if backend not in ("numpy", "drjit"):
        raise InputValueError(f"backend must be 'auto', 'numpy' or 'drjit', got {backend!r}")
    return backend


def _check_phase(transmission_phase: str) -> None:
    if transmission_phase not in TRANSMISSION_PHASES:
        raise InputValueError(f"transmission_phase must be one of {TRANSMISSION_PHASES}, "
                              f"got {transmission_phase!r}")


def _drjit():
    """Configure the backend, then return the ``(mitsuba, drjit)`` modules."""
    from ..utils.backend import init_backend

    init_backend()
    import drjit as dr
    import mitsuba as mi

    return mi, dr


def _dr_float(mi, x):
    if _is_drjit(x) or isinstance(x, (int, float)):
        return x
    return mi.Float(np.asarray(x, dtype=np.float32).ravel())


def _dr_complex(mi, x):
    if _is_drjit(x):
        return x
    if isinstance(x, (int, float, complex)) and not isinstance(x, bool):
        z = complex(x)
        return mi.Complex2f(z.real, z.imag)
    z = np.asarray(x, dtype=np.complex128).ravel()
    return mi.Complex2f(mi.Float(z.real.astype(np.float32)), mi.Float(z.imag.astype(np.float32)))


# --------------------------------------------------------------------------
# complex permittivity
# --------------------------------------------------------------------------
def complex_permittivity(eps_real, eps_imag, backend: str = "auto"):
    """``eps_r = eps' - j eps''`` from the two real per-vertex parameters.

    With Dr.Jit the result stays attached to the AD graph of both inputs.

    Parameters
    ----------
    eps_real : float or array_like or mi.Float
        eps' (scalar, array or ``mi.Float``)
    eps_imag : float or array_like or mi.Float
        eps'' >= 0 (loss; same types)
    backend : {"auto", "numpy", "drjit"}, optional
        array library of the computation (``"auto"``: from the inputs)

    Returns
    -------
    numpy.ndarray or mi.Complex2f
        complex128 ndarray or ``mi.Complex2f``
    """
    if _resolve_backend(backend, eps_real, eps_imag) == "drjit":
        mi, _ = _drjit()
        return mi.Complex2f(_dr_float(mi, eps_real), -_dr_float(mi, eps_imag))
    return np.asarray(eps_real, dtype=float) - 1j * np.asarray(eps_imag, dtype=float)


# --------------------------------------------------------------------------
# NumPy backend
# --------------------------------------------------------------------------
def _np_sqrt_passive(w):
    """Principal sqrt; on the cut (w < 0 real) the passive root Im <= 0."""
    w = np.array(w, dtype=np.complex128, copy=True)
    w.imag = np.where(w.imag == 0.0, -0.0, w.imag)
    return np.sqrt(w)


def _np_cos(cos_theta):
    c = np.abs(np.asarray(cos_theta, dtype=float))
    return np.clip(c, COS_THETA_MIN, 1.0)


def _np_interface(c, eps):
    a = _np_sqrt_passive((eps - 1.0) + c * c)          # eps - sin^2, no cancellation
    n = _np_sqrt_passive(eps)
    r_s = (c - a) / (c + a)
    r_p = (eps * c - a) / (eps * c + a)
    t_s = 2.0 * c / (c + a)
    t_p = 2.0 * n * c / (eps * c + a)
    return a, InterfaceCoefficients(r_s, r_p, t_s, t_p)


def _np_slab(cos_theta, eps_r, thickness, frequency, transmission_phase):
    f = np.asarray(frequency, dtype=float)
    if np.any(~np.isfinite(f)) or np.any(f <= 0.0):
        raise InputValueError(f"frequency must be finite and > 0 Hz, got {frequency!r}")
    c = _np_cos(cos_theta)
    eps = np.asarray(eps_r, dtype=np.complex128)
    d = np.maximum(np.asarray(thickness, dtype=float), 0.0)
    k0 = 2.0 * np.pi * f / SPEED_OF_LIGHT
    a, rc = _np_interface(c, eps)
    q = k0 * d * a                                     # eq. (44)
    e1 = np.exp(-1j * q)
    e2 = e1 * e1
    out = []
    for r in (rc.r_s, rc.r_p):
        r2 = r * r
        den = 1.0 - r2 * e2
        den = np.where(den == 0.0, 1.0, den)           # removable 0/0 (see module doc)
        out.append((r * (1.0 - e2) / den, (1.0 - r2) * e1 / den))   # eqs. (43a), (43b)
    (r_s, t_s), (r_p, t_p) = out
    if transmission_phase == "insertion":
        shift = np.exp(1j * k0 * d * c)
        t_s, t_p = t_s * shift, t_p * shift
    return SlabCoefficients(r_s, r_p, t_s, t_p)


# --------------------------------------------------------------------------
# Dr.Jit backend
# --------------------------------------------------------------------------
def _dr_sqrt_passive(mi, dr, w):
    """Branch-free principal complex sqrt with finite gradients.

    ``Re = sqrt((|w| + x) / 2)``, ``Im = y / (2 Re)``; where ``Re`` vanishes
    (``w`` on the negative real axis) the passive root ``Im = -sqrt(|x|)``.
    """
    x, y = dr.real(w), dr.imag(w)
    rad = dr.safe_sqrt(dr.square(x) + dr.square(y))
    u = dr.safe_sqrt(0.5 * (rad + x))
    ok = u > 1e-18
    v = dr.select(ok, y / dr.select(ok, 2.0 * u, 1.0), -dr.safe_sqrt(0.5 * (rad - x)))
    return mi.Complex2f(u, v)


def _dr_cos(dr, cos_theta):
    return dr.clip(dr.abs(cos_theta), COS_THETA_MIN, 1.0)


def _dr_interface(mi, dr, c, eps):
    a = _dr_sqrt_passive(mi, dr, (eps - 1.0) + c * c)  # eps - sin^2, no cancellation
    n = _dr_sqrt_passive(mi, dr, eps)
    ec = eps * c
    r_s = (c - a) / (c + a)
    r_p = (ec - a) / (ec + a)
    t_s = (2.0 * c) / (c + a)
    t_p = (2.0 * c) * n / (ec + a)
    return a, InterfaceCoefficients(r_s, r_p, t_s, t_p)


def _dr_exp_mj(mi, dr, q, scale=1.0):
    """``exp(-j * scale * q)`` for complex ``q`` via real ops."""
    s, co = dr.sincos(scale * dr.real(q))
    m = dr.exp(scale * dr.imag(q))
    return mi.Complex2f(m * co, -m * s)


def _dr_slab(cos_theta, eps_r, thickness, frequency, transmission_phase):
    mi, dr = _drjit()
    c = _dr_cos(dr, _dr_float(mi, cos_theta))
    eps = _dr_complex(mi, eps_r)
    d = dr.maximum(_dr_float(mi, thickness), 0.0)
    f = _dr_float(mi, frequency)
    k0 = (2.0 * np.pi / SPEED_OF_LIGHT) * f
    a, rc = _dr_interface(mi, dr, c, eps)
    q = (k0 * d) * a                                    # eq. (44)
    e1 = _dr_exp_mj(mi, dr, q)
    e2 = _dr_exp_mj(mi, dr, q, 2.0)
    out = []
    for r in (rc.r_s, rc.r_p):
        r2 = r * r
        den = 1.0 - r2 * e2
        # removable 0/0 at d = 0 with |r| rounding to 1 (grazing, metals)
        den = dr.select(dr.squared_norm(den) > 1e-30, den, mi.Complex2f(1.0, 0.0))
        inv_den = dr.rcp(den)
        out.append((r * (1.0 - e2) * inv_den, (1.0 - r2) * e1 * inv_den))  # eqs. (43a), (43b)
    (r_s, t_s), (r_p, t_p) = out
    if transmission_phase == "insertion":
        s, co = dr.sincos(k0 * d * c)
        shift = mi.Complex2f(co, s)
        t_s, t_p = t_s * shift, t_p * shift
    return SlabCoefficients(r_s, r_p, t_s, t_p)


# --------------------------------------------------------------------------
# public API
# --------------------------------------------------------------------------
def fresnel_coefficients(cos_theta, eps_r, backend: str = "auto") -> InterfaceCoefficients:
    """Complex Fresnel coefficients of a planar air -> ``eps_r`` interface.

    ITU-R P.2040-3 eqs. (37a), (37b) (reflection) and the matching
    transmission coefficients, Born & Wolf Sec. 1.5.2 (see module docstring
    for the sign convention).

    Parameters
    ----------
    cos_theta : array_like or mi.Float
        cosine of the incidence angle from the normal; ``|.|`` is
        used, clipped to ``[1e-6, 1]`` (array / ``mi.Float``)
    eps_r : array_like or mi.Complex2f
        complex relative permittivity ``eps' - j eps''``
        (complex array / ``mi.Complex2f``)
    backend : {"auto", "numpy", "drjit"}, optional
        array library of the computation (``"auto"``: from the inputs)

    Returns
    -------
    InterfaceCoefficients
        ``(r_s, r_p, t_s, t_p)``:
        E-field ratios, TE (s, perpendicular) and TM (p, parallel)
    """
    if _resolve_backend(backend, cos_theta, eps_r) == "drjit":
        mi, dr = _drjit()
        c = _dr_cos(dr, _dr_float(mi, cos_theta))
        return _dr_interface(mi, dr, c, _dr_complex(mi, eps_r))[1]
    return _np_interface(_np_cos(cos_theta), np.asarray(eps_r, dtype=np.complex128))[1]


def slab_coefficients(cos_theta, eps_r, thickness, frequency, backend: str = "auto",
                      transmission_phase: str = "p2040") -> SlabCoefficients:
    """ITU-R P.2040-3 single-layer slab reflection / transmission coefficients.

    Implements ITU-R P.2040-3 eqs. (43a), (43b) and (44) with the single-
    interface ``r`` of eqs. (37a), (37b); see the module docstring.  All
    inputs broadcast against each other.

    Parameters
    ----------
    cos_theta : array_like or mi.Float
        cosine of the incidence angle (see
        :func:`fresnel_coefficients`)
    eps_r : array_like or mi.Complex2f
        complex relative permittivity ``eps' - j eps''``
    thickness : float or array_like or mi.Float
        slab thickness ``d`` [m] (negative values -> 0)
    frequency : float
        frequency [Hz] (wavelength ``lambda = c / f``)
    backend : {"auto", "numpy", "drjit"}, optional
        array library of the computation (``"auto"``: from the inputs)
    transmission_phase : str, optional
        ``"p2040"``: ``T`` exactly as eq. (43b), phase
        referenced front face -> back face;
        ``"insertion"``: ``T * exp(+j 2 pi d cos(theta) /
        lambda)``, relative to free-space propagation over
        the same region (for thin-surface ray tracing)

    Returns
    -------
    SlabCoefficients
        ``(r_s, r_p, t_s, t_p)``
    """
    _check_phase(transmission_phase)
    if _resolve_backend(backend, cos_theta, eps_r, thickness, frequency) == "drjit":
        return _dr_slab(cos_theta, eps_r, thickness, frequency, transmission_phase)
    return _np_slab(cos_theta, eps_r, thickness, frequency, transmission_phase)


def energy_gate(cos_theta, eps_r, thickness, frequency, f_s=0.5, f_p=0.5,
                backend: str = "auto"):
    """Polarisation-weighted slab reflectance ``A = f_s |R_s|^2 + f_p |R_p|^2``.

    The mmIR BSDF energy gate (paper Sec. 3.2) with ``R_s``, ``R_p`` from
    :func:`slab_coefficients` (ITU-R P.2040-3 eq. (43a)).

    Parameters
    ----------
    cos_theta : array_like or mi.Float
        cosine of the incidence angle
    eps_r : array_like or mi.Complex2f
        complex relative permittivity ``eps' - j eps''``
    thickness : float or array_like or mi.Float
        slab thickness [m]
    frequency : float
        frequency [Hz]
    f_s, f_p : float, optional
        power fractions of the incident wave in s and p
        polarisation (antenna dependent; ``f_s + f_p <= 1``)
    backend : {"auto", "numpy", "drjit"}, optional
        array library of the computation (``"auto"``: from the inputs)

    Returns
    -------
    numpy.ndarray or mi.Float
        real array / ``mi.Float`` in ``[0, 1]``
    """
    for name, v in (("f_s", f_s), ("f_p", f_p)):
        if not _is_drjit(v) and np.any(np.asarray(v, dtype=float) < 0.0):
            raise InputValueError(f"{name} must be >= 0, got {v!r}")
    kind = _resolve_backend(backend, cos_theta, eps_r, thickness, frequency, f_s, f_p)
    sc = slab_coefficients(cos_theta, eps_r, thickness, frequency, backend=kind)
    if kind == "drjit":
        mi, dr = _drjit()
        return _dr_float(mi, f_s) * dr.squared_norm(sc.r_s) + \
            _dr_float(mi, f_p) * dr.squared_norm(sc.r_p)
    return (np.asarray(f_s, dtype=float) * np.abs(sc.r_s) ** 2
            + np.asarray(f_p, dtype=float) * np.abs(sc.r_p) ** 2)

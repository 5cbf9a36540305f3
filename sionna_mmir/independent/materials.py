"""Materials: ITU-R P.2040 permittivity, Fresnel and slab reflection, co-pol.

Permittivity (ITU-R P.2040-3, Sec. 2.1.2 and 2.1.4), ``f`` in GHz::

    eps'  = a f^b,   sigma = c f^d [S/m],   eps'' = sigma / (2 pi f eps0)
    eps_r = eps' - j eps''                       (time dependence exp(+j w t))

The coefficients ``a, b, c, d`` (Table 3) and the roughness / thickness
defaults are read as data from :mod:`sionna_mmir.radio_materials.itu_table`;
the formulas here are written independently.

Half-space reflection of a plane wave from air (Born & Wolf, *Principles of
Optics*, Sec. 1.5.2), ``a = sqrt(eps_r - sin^2 theta)`` (branch ``Im <= 0``)::

    r_s = (cos - a) / (cos + a)
    r_p = (a - eps_r cos) / (a + eps_r cos)

``r_p`` is taken with the sign for which ``r_p = r_s`` at normal incidence
(the opposite of the P.2040 eq. 37b convention), so that a perfect conductor
has ``r_s = r_p = -1`` at every angle.  Slab of thickness ``d`` in air
(ITU-R P.2040-3 eqs. 43a, 44)::

    q = (2 pi d / lambda) a,     R = r (1 - e^{-j 2q}) / (1 - r^2 e^{-j 2q})

Polarisation is reduced to a scalar: every bounce multiplies the field by
the unpolarised reflection amplitude with the TE phase::

    Gamma = sqrt((|R_s|^2 + |R_p|^2) / 2) * R_s / |R_s|

(the r.m.s. of the two eigen-polarisations: the field amplitude that carries
the mean reflected power of an unpolarised wave).  It equals ``r`` at normal
incidence, ``-1`` for perfect conductors at every angle (which reproduces the
co-polar RCS of plates, dihedrals and trihedrals) and tends to magnitude 1
at grazing incidence like both eigen-coefficients.  Not modelled: the
polarisation of the elements, polarisation rotation between bounces (e.g.
the cross-polar return of a dihedral at 45 deg), the opposite signs of HH
and VV for even bounces, the phase difference between ``R_s`` and ``R_p``.
"""
from __future__ import annotations

import numpy as np

from ..errors import ConfigError, InputValueError
from .constants import C0, EPS0

#: Parameter columns of a material function's output ``[N, 6]``.
PARAMETER_COLUMNS = ("eps_real", "eps_imag", "sigma_h", "l_c", "tau", "thickness")


def itu_parameters(name: str, frequency_hz: float, allow_out_of_band: bool = False) -> np.ndarray:
    """Parameters of an ITU-R P.2040 material class at one frequency.

    Parameters
    ----------
    name : str
        Material class, e.g. ``"concrete"`` (case, blanks, ``itu_`` ignored).
    frequency_hz : float
        Frequency [Hz].
    allow_out_of_band : bool
        Use the nearest band's fit outside the Table 3 ranges instead of
        raising.

    Returns
    -------
    numpy.ndarray
        ``[6]`` float64 in :data:`PARAMETER_COLUMNS` order: ``eps'``,
        ``eps''``, rms height [m], correlation length [m], (unused), slab
        thickness [m].

    Raises
    ------
    ConfigError
        Unknown material, or a frequency outside its bands.
    """
    from ..radio_materials.itu_table import ITU_TABLE, SURFACE_DEFAULTS  # table data only

    key = str(name).strip().lower().replace("-", "_").replace(" ", "_")
    key = key[4:] if key.startswith("itu_") else key
    if key not in ITU_TABLE:
        raise ConfigError(f"unknown material {name!r}; ITU-R P.2040 classes: {sorted(ITU_TABLE)}")
    f_ghz = float(frequency_hz) / 1e9
    rows = ITU_TABLE[key]
    inside = [r for r in rows if r.f_min_ghz <= f_ghz <= r.f_max_ghz]
    if not inside and not allow_out_of_band:
        bands = ", ".join(f"{r.f_min_ghz:g}-{r.f_max_ghz:g} GHz" for r in rows)
        raise ConfigError(f"material {key!r} has no ITU-R P.2040 fit at {f_ghz:g} GHz "
                          f"(valid: {bands}); pass allow_out_of_band=True to extrapolate")
    row = inside[0] if inside else min(
        rows, key=lambda r: min(abs(f_ghz - r.f_min_ghz), abs(f_ghz - r.f_max_ghz)))
    eps_real = row.a * f_ghz ** row.b
    sigma = row.c * f_ghz ** row.d
    eps_imag = sigma / (2.0 * np.pi * float(frequency_hz) * EPS0)
    s = SURFACE_DEFAULTS[key]
    return np.array([eps_real, eps_imag, s.sigma_h, s.l_c, s.tau, s.thickness], dtype=np.float64)


def fresnel_half_space(cos_theta, eps_r):
    """Reflection coefficients of a dielectric half-space, ``(r_s, r_p)``.

    Parameters
    ----------
    cos_theta : array_like
        ``[N]`` cosine of the angle of incidence (clipped to ``[1e-9, 1]``).
    eps_r : array_like
        ``[N]`` complex relative permittivity ``eps' - j eps''``.

    Returns
    -------
    tuple of numpy.ndarray
        ``r_s``, ``r_p``: ``[N]`` complex128 (convention of the module
        docstring: ``r_p = r_s`` at normal incidence).
    """
    c = np.clip(np.abs(np.asarray(cos_theta, dtype=np.float64)), 1e-9, 1.0)
    eps = np.asarray(eps_r, dtype=np.complex128)
    a = _root(eps - (1.0 - c * c))
    r_s = (c - a) / (c + a)
    r_p = (a - eps * c) / (a + eps * c)
    return r_s, r_p


def _root(z):
    """Square root on the branch ``Im <= 0`` (decaying wave for exp(+j w t))."""
    r = np.sqrt(z)
    return np.where(r.imag > 0, -r, r)


def slab_reflection(cos_theta, eps_r, thickness, frequency_hz):
    """Reflection of a slab of thickness ``d`` in air, ``(R_s, R_p)``.

    Parameters
    ----------
    cos_theta, eps_r : array_like
        ``[N]`` as in :func:`fresnel_half_space`.
    thickness : array_like
        ``[N]`` slab thickness [m]; ``inf`` gives the half-space.
    frequency_hz : float
        Frequency [Hz].

    Returns
    -------
    tuple of numpy.ndarray
        ``R_s``, ``R_p``: ``[N]`` complex128.
    """
    c = np.clip(np.abs(np.asarray(cos_theta, dtype=np.float64)), 1e-9, 1.0)
    eps = np.asarray(eps_r, dtype=np.complex128)
    d = np.broadcast_to(np.asarray(thickness, dtype=np.float64), c.shape)
    r_s, r_p = fresnel_half_space(c, eps)
    finite = np.isfinite(d)
    q = 2.0 * np.pi * float(frequency_hz) / C0 * np.where(finite, d, 0.0) * _root(eps - (1 - c * c))
    e = np.where(finite, np.exp(-2j * q), 0.0)
    out = []
    for r in (r_s, r_p):
        den = 1.0 - r * r * e
        den = np.where(np.abs(den) < 1e-300, 1.0, den)
        out.append(r * (1.0 - e) / den)
    return out[0], out[1]


def copol_reflection(cos_theta, params, frequency_hz):
    """Scalar reflection ``Gamma`` of the slab model (module docstring).

    Parameters
    ----------
    cos_theta : array_like
        ``[N]`` cosine of the local angle of incidence.
    params : numpy.ndarray
        ``[N, 6]`` material parameters (:data:`PARAMETER_COLUMNS`).
    frequency_hz : float
        Frequency [Hz].

    Returns
    -------
    numpy.ndarray
        ``[N]`` complex128, ``sqrt((|R_s|^2 + |R_p|^2) / 2) R_s / |R_s|``.
    """
    eps = params[:, 0] - 1j * params[:, 1]
    R_s, R_p = slab_reflection(cos_theta, eps, params[:, 5], frequency_hz)
    mag_s = np.abs(R_s)
    phase = np.where(mag_s > 0, R_s / np.where(mag_s > 0, mag_s, 1.0), -1.0)
    return np.sqrt(0.5 * (mag_s ** 2 + np.abs(R_p) ** 2)) * phase


def material_function(spec, name: str, frequency_hz: float, allow_out_of_band: bool = False):
    """A function ``points [N, 3] -> parameters [N, 6]`` for one object.

    Parameters
    ----------
    spec : str, dict or callable
        ITU-R P.2040 class name; or a dict with ``eps_real``, ``eps_imag``
        and optionally ``sigma_h`` [m] (default 0), ``l_c`` [m] (default
        0.01), ``thickness`` [m] (default ``inf``: half-space); or a callable
        ``points [N, 3] (m, world) -> [N, 6]`` in :data:`PARAMETER_COLUMNS`
        order (e.g. ground-truth materials that vary with position).
    name : str
        Object name, for error messages.
    frequency_hz : float
        Frequency [Hz].
    allow_out_of_band : bool
        See :func:`itu_parameters`.

    Returns
    -------
    callable
        ``points [N, 3] -> numpy.ndarray [N, 6]`` float64, validated.

    Raises
    ------
    ConfigError
        Unknown material class or a dict with missing / unknown keys.
    """
    if isinstance(spec, str):
        row = itu_parameters(spec, frequency_hz, allow_out_of_band)
        return lambda points: np.tile(row, (len(points), 1))
    if isinstance(spec, dict):
        row = _dict_parameters(spec, name)
        return lambda points: np.tile(row, (len(points), 1))
    if callable(spec):
        return lambda points: _checked(np.asarray(spec(points), dtype=np.float64), name, len(points))
    raise ConfigError(f"material of {name!r} must be an ITU class name, a parameter dict or a "
                      f"callable, got {type(spec).__name__}")


def _dict_parameters(spec: dict, name: str) -> np.ndarray:
    allowed = {"eps_real", "eps_imag", "sigma_h", "l_c", "tau", "thickness"}
    unknown = set(spec) - allowed
    if unknown or not {"eps_real", "eps_imag"} <= set(spec):
        raise ConfigError(f"material dict of {name!r} needs eps_real and eps_imag and may have "
                          f"{sorted(allowed)}; got {sorted(spec)}")
    row = np.array([spec["eps_real"], spec["eps_imag"], spec.get("sigma_h", 0.0),
                    spec.get("l_c", 0.01), spec.get("tau", 1.0),
                    spec.get("thickness", np.inf)], dtype=np.float64)
    return _checked(row[None], name, 1)[0]


def _checked(p: np.ndarray, name: str, n: int) -> np.ndarray:
    if p.shape != (n, 6):
        raise InputValueError(f"material of {name!r}: expected parameters [{n}, 6], got {p.shape}")
    if np.isnan(p).any() or not np.isfinite(p[:, :5]).all():
        raise InputValueError(f"material of {name!r}: parameters hold NaN or Inf")
    if (p[:, 0] <= 0).any() or (p[:, 1] < 0).any() or (p[:, 2] < 0).any() \
            or (p[:, 3] <= 0).any() or (p[:, 5] <= 0).any():
        raise InputValueError(f"material of {name!r}: need eps_real > 0, eps_imag >= 0, "
                              "sigma_h >= 0, l_c > 0 and thickness > 0")
    return p

r"""Antenna element beam patterns for the radar's Tx/Rx elements.

A beam pattern maps a direction in the **radar frame** (``+x`` boresight,
``+y`` left = positive azimuth, ``+z`` up) to the element's *power* gain
``G`` (linear, dBi = ``10 log10 G``), its field amplitude ``sqrt(G)`` and the
unit direction of the radiated (or received) electric field.  Directions are
unit vectors, given as a Dr.Jit ``mi.Vector3f`` (differentiable; the Dr.Jit
path is branch-free, so it can be called inside Dr.Jit loops) or as a NumPy
array ``[..., 3]``.  Angles used below::

    az = atan2(y, x)        azimuth, in the x-y plane, positive towards +y
    el = asin(z)            elevation above the x-y plane
    theta = acos(z), phi = az   Sionna RT's zenith / azimuth angles

Patterns
--------
:class:`CosinePowerPattern`
    learnable separable ``G0 cos(az)^q_az cos(el)^q_el``
    (front hemisphere), per-element ``q``, normalised
    to directivity in closed form
:class:`SharedShapePattern`
    one learnable ``cos^q`` shape per array plus
    per-element gain residuals (the shape transfers
    to another array, the residuals do not)
:class:`IsotropicPattern`
    ``G = 1``
:class:`SionnaPattern`
    Sionna RT 2.2's own patterns ("iso", "dipole",
    "hw_dipole", "tr38901"), ``|C_theta|^2+|C_phi|^2``

:func:`make_pattern` builds one from a string (``"cos"``, ``"iso"``,
``"sionna:tr38901"``, ``"sionna:dipole:H"``) or passes a pattern through.

Element selection
-----------------
Patterns with per-element parameters hold ``n_elements`` sets of them.  The
``element`` argument of :meth:`BeamPattern.gain` etc. is a ``mi.UInt32``
(or integer / integer array) with one element index per query direction
(or a single index for all); it is applied with ``dr.gather`` so a MIMO path
solver can evaluate every (Tx, Rx, path) in one kernel.  ``element=None`` is
allowed when the pattern has a single element.  Dr.Jit index arrays are not
range-checked (that would force an evaluation); NumPy / int ones are.

Learning
--------
:meth:`BeamPattern.params` returns the learnable Dr.Jit arrays by name (the
objects stored in the pattern, so ``dr.enable_grad`` on them works in place);
:meth:`BeamPattern.set_params` writes optimiser values back, e.g.::

    opt = mi.ad.Adam(lr=0.05, params=pattern.params())
    ...; dr.backward(loss); opt.step(); pattern.set_params(opt)

Polarisation conventions
------------------------
For a linear polarisation the transverse field direction of
:class:`CosinePowerPattern` / :class:`IsotropicPattern` is the projection of
a reference axis onto the plane normal to the direction: ``+z`` for ``"V"``,
``+y`` for ``"H"`` (so at boresight V = ``+z``, H = ``+y``).  Where the
projection vanishes (``d = +-z`` for V, ``d = +-y`` for H) the limit taken
along the boresight side, ``-sign(d_ref) x``, is used, so the result is
always a unit vector orthogonal to ``d``.  :class:`SionnaPattern` returns
Sionna's own field direction ``Re(C_theta) theta_hat + Re(C_phi) phi_hat``;
Sionna's ``theta_hat`` points *down* at the horizon, so Sionna's "V" is
``-1`` times the "V" above (a sign is a convention: it only changes a global
phase of pi).

References
----------
C. A. Balanis, *Antenna Theory: Analysis and Design*, Wiley: Ch. 2
(radiation intensity ``U``, directivity ``D = 4 pi U / P_rad``, and the
``cos^n`` intensity patterns used as its worked examples); Ch. 4, short
dipole (``D = 1.5``, Eq. (4-26a) of the 2nd ed. as cited by Sionna) and
half-wave dipole (``D = 1.643``, Eq. (4-84)).
M. Abramowitz, I. Stegun, *Handbook of Mathematical Functions*, 6.2.1-6.2.2
(Beta function), giving the Wallis integral used for the normalisation.
3GPP TR 38.901, Table 7.3-1 (the "tr38901" element, 8 dBi peak gain).
"""
from __future__ import annotations

import math
from numbers import Integral, Real
from typing import Mapping

import numpy as np

from ..errors import ConfigError, InputValueError
from ..utils.backend import init_backend

init_backend()

import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402

__all__ = [
    "BeamPattern",
    "CosinePowerPattern",
    "IsotropicPattern",
    "SharedShapePattern",
    "SionnaPattern",
    "make_pattern",
    "available_patterns",
    "cosine_power_normalisation_np",
    "DEFAULT_Q_AZ",
    "DEFAULT_Q_EL",
    "Q_MIN",
    "HALF_POWER_DB",
    "QUARTER_POWER_DB",
]

#: Default azimuth exponent: cos(az)^2 is 6 dB down at az = +-60 deg
#: (3 dB down at +-45 deg).
DEFAULT_Q_AZ = 2.0
#: Default elevation exponent: cos(el)^10 is 6 dB down at el = +-29.5 deg
#: (3 dB down at +-21.1 deg).  With DEFAULT_Q_AZ the peak gain is 10.35 dBi.
DEFAULT_Q_EL = 10.0
#: Smallest exponent stored: ``q < Q_MIN`` (e.g. 0) is stored as ``Q_MIN`` so that
#: ``log q`` stays finite (the gain then differs by a factor
#: ``cos^Q_MIN``, < 1e-5 relative within 89.99 deg of boresight).
Q_MIN = 1e-6

#: ``10 log10 2``: the "3 dB" (half-power) level, exactly.
HALF_POWER_DB = 10.0 * math.log10(2.0)
#: ``10 log10 4``: the "6 dB" (quarter-power) level, exactly.
QUARTER_POWER_DB = 10.0 * math.log10(4.0)

_TINY = 1e-30          # floor inside logarithms (float32 normal range)
_DEGENERATE = 1e-12    # squared norm below which a projection is degenerate
_POLARIZATIONS = ("V", "H")


# --------------------------------------------------------------------------
# input helpers
# --------------------------------------------------------------------------
def _is_drjit(x) -> bool:
    return bool(dr.is_array_v(x))


def _as_vector3f(direction):
    """Dr.Jit vector -> ``mi.Vector3f``; NumPy ``[..., 3]`` -> flattened one."""
    if _is_drjit(direction):
        return mi.Vector3f(direction)
    d = np.asarray(direction, dtype=np.float64)
    if d.ndim < 1 or d.shape[-1] != 3:
        raise InputValueError(
            f"direction: expected an array of shape [..., 3], got shape {d.shape}")
    if not np.all(np.isfinite(d)):
        raise InputValueError("direction: holds NaN or Inf")
    d = d.reshape(-1, 3)
    if d.shape[0] == 0:
        raise InputValueError("direction: empty array")
    return mi.Vector3f(d[:, 0].astype(np.float32), d[:, 1].astype(np.float32),
                       d[:, 2].astype(np.float32))


def _np_directions(direction) -> np.ndarray:
    """NumPy / Dr.Jit direction -> float64 array ``[..., 3]`` (validated)."""
    if _is_drjit(direction):
        v = mi.Vector3f(direction)
        return np.stack([np.asarray(v.x, dtype=np.float64),
                         np.asarray(v.y, dtype=np.float64),
                         np.asarray(v.z, dtype=np.float64)], axis=-1)
    d = np.asarray(direction, dtype=np.float64)
    if d.ndim < 1 or d.shape[-1] != 3:
        raise InputValueError(
            f"direction: expected an array of shape [..., 3], got shape {d.shape}")
    if not np.all(np.isfinite(d)):
        raise InputValueError("direction: holds NaN or Inf")
    if d.size == 0:
        raise InputValueError("direction: empty array")
    return d


def _check_polarization(pol) -> str:
    if not isinstance(pol, str) or pol.upper() not in _POLARIZATIONS:
        raise ConfigError(f"polarization: expected 'V' or 'H', got {pol!r}")
    return pol.upper()


def _linear_polarization(d: mi.Vector3f, pol: str) -> mi.Vector3f:
    """Projection of +z ("V") or +y ("H") onto the plane normal to ``d``."""
    d = dr.normalize(d)
    zero = dr.zeros(mi.Float, dr.width(d))
    if pol == "V":
        ref = mi.Vector3f(zero, zero, zero + 1.0)
        side = d.z
    else:
        ref = mi.Vector3f(zero, zero + 1.0, zero)
        side = d.y
    p = ref - dr.dot(ref, d) * d
    # Degenerate (d parallel to the reference axis): the limit approached from
    # the boresight side is -sign(d_ref) * x; project it for orthogonality.
    alt_ref = mi.Vector3f(dr.select(side >= 0.0, -1.0, 1.0), zero, zero)
    p_alt = alt_ref - dr.dot(alt_ref, d) * d
    deg = dr.squared_norm(p) < _DEGENERATE
    p = dr.select(deg, p_alt, p)
    return dr.normalize(p)


# --------------------------------------------------------------------------
# base class
# --------------------------------------------------------------------------
class BeamPattern:
    """Base class of antenna element patterns (radar frame, power gain).

    Subclasses implement :meth:`gain` (and, where needed, :meth:`field`,
    :meth:`polarization`, :meth:`params`).  What the methods return:

    ``gain``
        ``mi.Float [N]``, linear power gain (dBi = 10 log10).
    ``field``
        ``mi.Float [N]``, ``sqrt(gain)`` (field amplitude factor).
    ``polarization``
        ``mi.Vector3f [N]``, unit E-field direction, orthogonal to the
        direction.
    ``params``
        ``dict[str, mi.Float]`` of learnable arrays (may be empty).
    ``gain_np``
        ``np.ndarray [...]`` float64, for tests and plots.

    Arguments common to all methods:

    ``direction``
        Unit vectors in the radar frame: ``mi.Vector3f [N]`` or NumPy ``[...,
        3]`` (flattened to ``N`` queries).
    ``element``
        ``None`` (single-element patterns), or element index per query:
        ``mi.UInt32 [N]`` / ``[1]``, int, or int array.
    """

    #: number of per-element parameter sets
    n_elements: int = 1

    # -- to implement -----------------------------------------------------
    def gain(self, direction, element=None) -> mi.Float:
        """Linear power gain ``G`` towards ``direction`` (see class table)."""
        raise NotImplementedError

    # -- defaults -----------------------------------------------------------
    def field(self, direction, element=None) -> mi.Float:
        """Field amplitude factor ``sqrt(G)`` (linear)."""
        return dr.sqrt(dr.maximum(self.gain(direction, element), 0.0))

    def polarization(self, direction, element=None) -> mi.Vector3f:
        """Unit transverse E-field direction (``mi.Vector3f``).

        Linear polarisation given by ``self.polarization_name`` ("V": the
        projection of ``+z``, "H": of ``+y``, onto the plane normal to the
        direction; see the module notes for the degenerate directions).
        ``element`` is accepted for symmetry and unused here.
        """
        return _linear_polarization(_as_vector3f(direction),
                                    getattr(self, "polarization_name", "V"))

    def params(self) -> dict:
        """Learnable Dr.Jit arrays by name (empty for fixed patterns)."""
        return {}

    def set_params(self, values: Mapping) -> None:
        """Assign learnable arrays (e.g. from an optimiser), validated.

        ``values`` maps names of :meth:`params` to Dr.Jit arrays (a dict or
        a ``mi.ad.Optimizer``); other keys are ignored, since an optimiser
        may also hold scene parameters.  Non-finite values or a wrong length
        raise :class:`~sionna_mmir.errors.ConfigError`.
        """
        own = self.params()
        for key in own:
            if key in values:
                self._assign_param(key, values[key])

    def _assign_param(self, key, value):  # pragma: no cover - per subclass
        raise ConfigError(f"{type(self).__name__} has no parameter {key!r}")

    def gain_np(self, direction, element=None) -> np.ndarray:
        """NumPy float64 gain for a ``[..., 3]`` array of directions."""
        d = _np_directions(direction)
        g = np.asarray(self.gain(_as_vector3f(d), self._np_element(element, d)),
                       dtype=np.float64)
        n = int(np.prod(d.shape[:-1]))
        return (np.full(n, g[0]) if g.size == 1 else g).reshape(d.shape[:-1])

    def polarization_np(self, direction, element=None) -> np.ndarray:
        """NumPy float64 ``[..., 3]`` unit E-field directions."""
        d = _np_directions(direction)
        p = self.polarization(_as_vector3f(d), self._np_element(element, d))
        out = np.stack([np.asarray(p.x, dtype=np.float64), np.asarray(p.y, dtype=np.float64),
                        np.asarray(p.z, dtype=np.float64)], axis=-1)
        return out.reshape(d.shape)

    # -- element handling ---------------------------------------------------
    def _np_element(self, element, d):
        if element is None or _is_drjit(element):
            return element
        e = np.asarray(element)
        if e.ndim > 0 and e.size not in (1, int(np.prod(d.shape[:-1]))):
            raise InputValueError(
                f"element: expected one index or one per direction "
                f"({int(np.prod(d.shape[:-1]))}), got {e.size}")
        return e.ravel() if e.ndim > 0 else int(e)

    def _element_index(self, element):
        """``element`` -> ``mi.UInt32`` (or ``None`` for a single element)."""
        if element is None:
            if self.n_elements != 1:
                raise InputValueError(
                    f"element: this {type(self).__name__} has {self.n_elements} "
                    "elements; pass an element index per query (mi.UInt32)")
            return None
        if _is_drjit(element):
            return mi.UInt32(element)
        e = np.asarray(element)
        if e.dtype == bool or not np.issubdtype(e.dtype, np.integer):
            raise InputValueError(f"element: expected integer indices, got dtype {e.dtype}")
        e = e.ravel()
        if e.size == 0:
            raise InputValueError("element: empty index array")
        if e.min() < 0 or e.max() >= self.n_elements:
            raise InputValueError(
                f"element: indices must lie in [0, {self.n_elements - 1}], "
                f"got [{e.min()}, {e.max()}]")
        return mi.UInt32(e.astype(np.uint32))

    def __repr__(self):
        return f"{type(self).__name__}()"


# --------------------------------------------------------------------------
# isotropic
# --------------------------------------------------------------------------
class IsotropicPattern(BeamPattern):
    """Isotropic element: ``G = 1`` (0 dBi) in every direction.

    ``element`` is accepted and ignored (all elements are isotropic).

    Parameters
    ----------
    polarization : {"V", "H"}, optional
        Linear polarisation, see module notes (default ``"V"``).
    """

    def __init__(self, polarization: str = "V"):
        self.polarization_name = _check_polarization(polarization)

    def gain(self, direction, element=None) -> mi.Float:
        d = _as_vector3f(direction)  # element: ignored (same for all elements)
        return dr.full(mi.Float, 1.0, dr.width(d))

    def field(self, direction, element=None) -> mi.Float:
        return self.gain(direction, element)

    def __repr__(self):
        return f"IsotropicPattern(polarization={self.polarization_name!r})"


# --------------------------------------------------------------------------
# learnable cos^q
# --------------------------------------------------------------------------
def cosine_power_normalisation_np(q_az, q_el) -> np.ndarray:
    r"""Closed-form ``G0(q_az, q_el)`` (NumPy float64) of :class:`CosinePowerPattern`.

    ``G0 = 4 pi / (W(q_az) W(q_el + 1))`` with the Wallis integral
    ``W(p) = int_{-pi/2}^{pi/2} cos^p t dt = sqrt(pi) Gamma((p+1)/2) / Gamma(p/2+1)``.
    """
    from scipy.special import gammaln

    def log_w(p):
        p = np.asarray(p, dtype=np.float64)
        return 0.5 * np.log(np.pi) + gammaln(0.5 * (p + 1.0)) - gammaln(0.5 * p + 1.0)

    return np.exp(np.log(4.0 * np.pi) - log_w(q_az) - log_w(np.asarray(q_el, np.float64) + 1.0))


def _validated_q(name: str, value, n: int) -> np.ndarray:
    if _is_drjit(value):
        value = np.asarray(dr.detach(value), dtype=np.float64)
    try:
        q = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{name}: expected a number or {n} numbers, got {value!r}") from exc
    if q.ndim == 0:
        q = np.full(n, float(q))
    q = q.ravel()
    if q.size != n:
        raise ConfigError(f"{name}: expected 1 or n_elements={n} values, got {q.size}")
    if not np.all(np.isfinite(q)):
        raise ConfigError(f"{name}: must be finite, got {q.tolist()}")
    if np.any(q < 0):
        raise ConfigError(f"{name}: exponents must be >= 0, got {q.tolist()}")
    return np.maximum(q, Q_MIN)


class CosinePowerPattern(BeamPattern):
    r"""Learnable separable ``cos^q`` element pattern, directivity-normalised.

    Power gain (Balanis Sec. 2.6-2.7: ``G`` here is the directivity of a
    lossless element, ``int G dOmega = 4 pi``)::

        G(az, el) = G0 * cos(az)^q_az * cos(el)^q_el     for x > 0 (|az| < 90 deg)
        G         = 0                                    behind (x <= 0)

    In direction components (unit ``d``): ``cos(el) = rho = sqrt(x^2+y^2)``,
    ``cos(az) = x / rho``, so ``G = G0 x^q_az rho^(q_el - q_az)``; it is
    evaluated as ``exp(log G0 + q_az log x + (q_el-q_az)/2 log rho^2)``,
    which keeps gradients finite everywhere.

    **Normalisation.**  With ``dOmega = cos(el) d(el) d(az)`` the integral
    separates into two Wallis integrals (Abramowitz & Stegun 6.2.1)::

        int G dOmega = G0 W(q_az) W(q_el + 1) = 4 pi,
        W(p) = int_{-pi/2}^{pi/2} cos^p t dt = sqrt(pi) Gamma((p+1)/2) / Gamma(p/2 + 1)

    so ``G0 = 4 pi / (W(q_az) W(q_el + 1))``, e.g. ``G0(0, 0) = 2`` (a
    hemisphere, 3.01 dBi) and ``G0(2, 10) = 10.83`` (10.35 dBi).  It is
    computed with ``dr.lgamma`` in float64 (exact to ~1e-10, differentiable:
    the gradient of the gain w.r.t. ``q`` includes ``d log G0 / dq``, a
    digamma difference), then cast to the variant's float.

    **Beamwidths.**  On the principal cuts the gain falls to a fraction
    ``r`` of the peak at ``acos(r^(1/q))``: full widths
    ``2 acos(0.5^(1/q))`` (half power, "3 dB") and ``2 acos(0.25^(1/q))``
    (quarter power, "6 dB"); see :meth:`beamwidth`.

    **Defaults** (``q_az = 2``, ``q_el = 10``): quarter-power half-widths of
    60 deg (azimuth) and 29.5 deg (elevation), half-power half-widths
    45 / 21.1 deg (full widths 90 / 42.2 deg), peak
    gain 10.35 dBi.  This matches the target shape set for a TI 77 GHz EVM
    patch element (6 dB half-widths of about +-60 deg azimuth and +-30 deg
    elevation, ~10 dBi); round exponents were preferred over exact fits
    (``q_el = 9.64`` would put the 6 dB point at exactly 30 deg).  They are a
    starting point for the fit, not a measured pattern.

    **Parameterisation.**  The learnable arrays are ``log_q_az`` and
    ``log_q_el`` (``q = exp(log q)``), which keeps ``q > 0`` under any
    gradient step; ``q < Q_MIN`` (e.g. 0) is stored as :data:`Q_MIN`.  Use
    :attr:`q_az` / :attr:`q_el` to read ``q``.

    Parameters
    ----------
    q_az : float or array_like, optional
        Azimuth exponent(s), >= 0, unitless: one value for all elements or
        ``[n_elements]``, one per element.
    q_el : float or array_like, optional
        Elevation exponent(s), >= 0, same forms.
    n_elements : int, optional
        Number of elements (parameter sets), >= 1.
    polarization : {"V", "H"}, optional
        Linear polarisation (module notes).

    Raises
    ------
    ConfigError
        Invalid values (negative, NaN/Inf, wrong length).
    """

    def __init__(self, q_az=DEFAULT_Q_AZ, q_el=DEFAULT_Q_EL, n_elements: int = 1,
                 polarization: str = "V"):
        if isinstance(n_elements, bool) or not isinstance(n_elements, Integral) or n_elements < 1:
            raise ConfigError(f"n_elements: expected an integer >= 1, got {n_elements!r}")
        self.n_elements = int(n_elements)
        self.polarization_name = _check_polarization(polarization)
        qa = _validated_q("q_az", q_az, self.n_elements)
        qe = _validated_q("q_el", q_el, self.n_elements)
        self.log_q_az = mi.Float(np.log(qa).astype(np.float32))
        self.log_q_el = mi.Float(np.log(qe).astype(np.float32))

    # -- parameters ---------------------------------------------------------
    def params(self) -> dict:
        """``{"log_q_az": mi.Float[n_elements], "log_q_el": mi.Float[n_elements]}``."""
        return {"log_q_az": self.log_q_az, "log_q_el": self.log_q_el}

    def _assign_param(self, key, value):
        if key not in ("log_q_az", "log_q_el"):
            raise ConfigError(f"CosinePowerPattern has no parameter {key!r}")
        v = mi.Float(value)
        arr = np.asarray(dr.detach(v), dtype=np.float64)
        if arr.size != self.n_elements:
            raise ConfigError(f"{key}: expected {self.n_elements} values, got {arr.size}")
        if not np.all(np.isfinite(arr)):
            raise ConfigError(f"{key}: must be finite, got {arr.tolist()}")
        setattr(self, key, v)

    @property
    def q_az(self) -> mi.Float:
        """Azimuth exponents ``exp(log_q_az)``, ``mi.Float [n_elements]``."""
        return dr.exp(self.log_q_az)

    @property
    def q_el(self) -> mi.Float:
        """Elevation exponents ``exp(log_q_el)``, ``mi.Float [n_elements]``."""
        return dr.exp(self.log_q_el)

    def q_np(self) -> tuple[np.ndarray, np.ndarray]:
        """``(q_az, q_el)`` as float64 NumPy arrays ``[n_elements]``."""
        return (np.exp(np.asarray(dr.detach(self.log_q_az), dtype=np.float64)),
                np.exp(np.asarray(dr.detach(self.log_q_el), dtype=np.float64)))

    # -- closed forms -------------------------------------------------------
    def log_normalisation(self) -> mi.Float:
        """``log G0`` per element, ``mi.Float [n_elements]`` (differentiable)."""
        qa = dr.exp(mi.Float64(self.log_q_az))
        qe = dr.exp(mi.Float64(self.log_q_el))

        def log_w(p):
            return 0.5 * math.log(math.pi) + dr.lgamma(0.5 * (p + 1.0)) - dr.lgamma(0.5 * p + 1.0)

        return mi.Float(math.log(4.0 * math.pi) - log_w(qa) - log_w(qe + 1.0))

    def peak_gain_dbi(self) -> np.ndarray:
        """Boresight gain ``10 log10 G0`` per element [dBi], NumPy."""
        qa, qe = self.q_np()
        return 10.0 * np.log10(cosine_power_normalisation_np(qa, qe))

    def beamwidth(self, level_db: float = HALF_POWER_DB) -> np.ndarray:
        """Full widths [rad] of the azimuth and elevation principal cuts.

        Returns ``[n_elements, 2]`` = ``2 acos(r^(1/q))`` for ``(q_az, q_el)``,
        ``r = 10^(-level_db/10)``: the default :data:`HALF_POWER_DB`
        (3.0103 dB) gives ``r = 1/2``, :data:`QUARTER_POWER_DB` ``r = 1/4``.
        The azimuth cut is ``el = 0``, the elevation cut ``az = 0``.
        """
        if not (isinstance(level_db, Real) and level_db > 0 and math.isfinite(level_db)):
            raise ConfigError(f"level_db: expected a positive number, got {level_db!r}")
        r = 10.0 ** (-float(level_db) / 10.0)
        q = np.stack(self.q_np(), axis=-1)
        return 2.0 * np.arccos(r ** (1.0 / q))

    # -- evaluation ---------------------------------------------------------
    def _log_gain(self, direction, element):
        d = dr.normalize(_as_vector3f(direction))
        idx = self._element_index(element)
        la, le, lg0 = self.log_q_az, self.log_q_el, self.log_normalisation()
        if idx is not None:
            la = dr.gather(mi.Float, la, idx)
            le = dr.gather(mi.Float, le, idx)
            lg0 = dr.gather(mi.Float, lg0, idx)
        qa, qe = dr.exp(la), dr.exp(le)
        x = d.x
        rho2 = dr.square(d.x) + dr.square(d.y)
        log_g = (lg0 + qa * dr.log(dr.maximum(x, _TINY))
                 + 0.5 * (qe - qa) * dr.log(dr.maximum(rho2, _TINY)))
        return log_g, x > 0.0

    def gain(self, direction, element=None) -> mi.Float:
        """Power gain ``G0 cos(az)^q_az cos(el)^q_el`` (0 behind), ``mi.Float``."""
        log_g, front = self._log_gain(direction, element)
        return dr.select(front, dr.exp(log_g), 0.0)

    def field(self, direction, element=None) -> mi.Float:
        """Amplitude ``sqrt(G)`` as ``exp(log G / 2)`` (finite gradients)."""
        log_g, front = self._log_gain(direction, element)
        return dr.select(front, dr.exp(0.5 * log_g), 0.0)

    def gain_np(self, direction, element=None) -> np.ndarray:
        """Float64 NumPy gain from the angle definition (independent path)."""
        d = _np_directions(direction)
        d = d / np.linalg.norm(d, axis=-1, keepdims=True)
        qa, qe = self.q_np()
        if element is None:
            if self.n_elements != 1:
                raise InputValueError(
                    f"element: this pattern has {self.n_elements} elements; pass indices")
            e = 0
        else:
            e = np.asarray(element)
            if e.dtype == bool or not np.issubdtype(e.dtype, np.integer):
                raise InputValueError(f"element: expected integer indices, got dtype {e.dtype}")
            if e.size and (e.min() < 0 or e.max() >= self.n_elements):
                raise InputValueError(
                    f"element: indices must lie in [0, {self.n_elements - 1}]")
            if e.ndim > 0:
                e = e.reshape(d.shape[:-1]) if e.size > 1 else e.ravel()[0]
        qa, qe = qa[e], qe[e]
        g0 = cosine_power_normalisation_np(qa, qe)
        az = np.arctan2(d[..., 1], d[..., 0])
        el = np.arcsin(np.clip(d[..., 2], -1.0, 1.0))
        front = d[..., 0] > 0
        with np.errstate(invalid="ignore", divide="ignore"):
            g = g0 * np.abs(np.cos(az)) ** qa * np.abs(np.cos(el)) ** qe
        return np.where(front, g, 0.0)

    def __repr__(self):
        qa, qe = self.q_np()
        return (f"CosinePowerPattern(q_az={qa.tolist()}, q_el={qe.tolist()}, "
                f"n_elements={self.n_elements}, polarization={self.polarization_name!r})")


# --------------------------------------------------------------------------
# shared cos^q shape + per-element gain residuals
# --------------------------------------------------------------------------
class SharedShapePattern(CosinePowerPattern):
    r"""One ``cos^q`` shape for a whole array plus a gain residual per element.

    Power gain of element ``e``::

        G_e(az, el) = exp(log_gain[e]) G0(q_az, q_el) cos(az)^q_az cos(el)^q_el

    (front hemisphere, :class:`CosinePowerPattern`'s normalisation).  The
    shape ``(q_az, q_el)`` is a property of the element type and of the
    scene side of the fit (it describes how the array sees directions); the
    residuals ``log_gain`` absorb per-element gain differences of one
    particular board (feed losses, calibration), which do not carry over to
    another sensor.  :meth:`transfer` gives the pattern of another array of
    the same element type: the fitted shape with zero residuals.

    Parameters
    ----------
    q_az, q_el : float, optional
        Shared exponents (>= 0).
    n_elements : int, optional
        Number of elements (residuals).
    log_gain : float or array_like, optional
        Natural-log power-gain residuals, one or ``[n_elements]`` (default 0).
    polarization : {"V", "H"}, optional
        Linear polarisation (module notes).

    Raises
    ------
    ConfigError
        Invalid exponents, residuals or element count.
    """

    def __init__(self, q_az=DEFAULT_Q_AZ, q_el=DEFAULT_Q_EL, n_elements: int = 1,
                 log_gain=0.0, polarization: str = "V"):
        super().__init__(q_az=float(np.ravel(q_az)[0]), q_el=float(np.ravel(q_el)[0]),
                         n_elements=1, polarization=polarization)
        if isinstance(n_elements, bool) or not isinstance(n_elements, Integral) or n_elements < 1:
            raise ConfigError(f"n_elements: expected an integer >= 1, got {n_elements!r}")
        self.n_elements = int(n_elements)
        g = np.broadcast_to(np.asarray(log_gain, dtype=np.float64), (self.n_elements,))
        if not np.all(np.isfinite(g)):
            raise ConfigError(f"log_gain: must be finite, got {g.tolist()}")
        self.log_gain = mi.Float(g.astype(np.float32))

    def params(self) -> dict:
        """``{"log_q_az": [1], "log_q_el": [1], "log_gain": [n_elements]}`` (``mi.Float``)."""
        return {"log_q_az": self.log_q_az, "log_q_el": self.log_q_el, "log_gain": self.log_gain}

    def _assign_param(self, key, value):
        sizes = {"log_q_az": 1, "log_q_el": 1, "log_gain": self.n_elements}
        if key not in sizes:
            raise ConfigError(f"SharedShapePattern has no parameter {key!r}")
        v = mi.Float(value)
        arr = np.asarray(dr.detach(v), dtype=np.float64)
        if arr.size != sizes[key] or not np.all(np.isfinite(arr)):
            raise ConfigError(f"{key}: expected {sizes[key]} finite values, got {arr.tolist()}")
        setattr(self, key, v)

    def transfer(self, n_elements: int) -> "SharedShapePattern":
        """The pattern of another array of this element type: same shape, no residuals."""
        qa, qe = self.q_np()
        return SharedShapePattern(q_az=float(qa[0]), q_el=float(qe[0]), n_elements=n_elements,
                                  polarization=self.polarization_name)

    def _log_gain(self, direction, element):
        d = dr.normalize(_as_vector3f(direction))
        idx = self._element_index(element)
        res = self.log_gain if idx is None else dr.gather(mi.Float, self.log_gain, idx)
        qa, qe = dr.exp(self.log_q_az), dr.exp(self.log_q_el)
        rho2 = dr.square(d.x) + dr.square(d.y)
        log_g = (self.log_normalisation() + res + qa * dr.log(dr.maximum(d.x, _TINY))
                 + 0.5 * (qe - qa) * dr.log(dr.maximum(rho2, _TINY)))
        return log_g, d.x > 0.0

    def gain_np(self, direction, element=None) -> np.ndarray:
        """Float64 NumPy gain (shape from the angle definition, times the residual)."""
        d = _np_directions(direction)
        shape = CosinePowerPattern(*(float(q[0]) for q in self.q_np())).gain_np(d)
        res = np.asarray(dr.detach(self.log_gain), dtype=np.float64)
        if element is None:
            if self.n_elements != 1:
                raise InputValueError(
                    f"element: this pattern has {self.n_elements} elements; pass indices")
            return shape * np.exp(res[0])
        e = np.asarray(element)
        if e.dtype == bool or not np.issubdtype(e.dtype, np.integer) or (
                e.size and (e.min() < 0 or e.max() >= self.n_elements)):
            raise InputValueError(f"element: integer indices in [0, {self.n_elements - 1}] "
                                  f"expected, got {element!r}")
        return shape * np.exp(res[e.reshape(shape.shape) if e.size > 1 else e.ravel()[0]])

    def __repr__(self):
        qa, qe = self.q_np()
        return (f"SharedShapePattern(q_az={qa[0]:.4g}, q_el={qe[0]:.4g}, "
                f"n_elements={self.n_elements}, polarization={self.polarization_name!r})")


# --------------------------------------------------------------------------
# Sionna RT patterns
# --------------------------------------------------------------------------
def _sionna_registries():
    from sionna.rt import antenna_pattern as ap  # heavy import, on first use

    return ap


def available_patterns() -> list[str]:
    """Names accepted by :func:`make_pattern`."""
    ap = _sionna_registries()
    return ["cos", "iso"] + [f"sionna:{n}" for n in sorted(ap.antenna_pattern_registry._registry)]


class SionnaPattern(BeamPattern):
    r"""Adapter around a Sionna RT 2.2 antenna pattern, in radar-frame directions.

    Sionna's element patterns are functions ``(theta, phi) -> (C_theta, C_phi)``
    (complex field patterns in the antenna's local spherical basis; ``theta``
    from ``+z``, ``phi`` from ``+x`` towards ``+y``).  The antenna's local
    frame coincides with the radar frame (its boresight is ``+x``, e.g. the
    tr38901 element peaks at ``theta = 90 deg, phi = 0``), so a radar-frame
    direction maps to ``(theta, phi)`` with Sionna's own
    ``theta_phi_from_unit_vec`` (``phi = 0`` at the poles).  The power gain
    is ``|C_theta|^2 + |C_phi|^2`` (Sionna's ``compute_gain`` definition).

    Sionna 2.2's registered patterns (``sionna.rt.antenna_pattern``), with
    their vertically polarised ``C_theta`` and peak gain:

    ``iso``
        1; 0 dBi.
    ``dipole``
        ``sqrt(1.5) |sin theta|`` (Balanis 4-26a); 1.76 dBi.
    ``hw_dipole``
        ``sqrt(1.643) |cos(pi/2 cos theta) / sin theta|``; 2.16 dBi.
    ``tr38901``
        TR 38.901 Table 7.3-1, 65 deg 3 dB widths, 30 dB floor (not
        normalised: efficiency 66 %); 8 dBi.

    No learnable parameters; ``element`` is ignored (all elements share the
    pattern).  :meth:`polarization` is Sionna's field direction (module notes).

    Parameters
    ----------
    name : str
        Registered Sionna pattern name (above).
    polarization : {"V", "H", "VH", "cross"}, optional
        Sionna polarisation.
    polarization_model : {"tr38901_2", "tr38901_1"}, optional
        Sionna's polarisation model (default ``"tr38901_2"``, Sionna's
        default).
    port : {0, 1}, optional
        Which pattern of a dual-polarised antenna.
    """

    def __init__(self, name: str, polarization: str = "V",
                 polarization_model: str = "tr38901_2", port: int = 0):
        ap = _sionna_registries()
        names = sorted(ap.antenna_pattern_registry._registry)
        if not isinstance(name, str) or name not in names:
            raise ConfigError(f"SionnaPattern: unknown Sionna pattern {name!r}; "
                              f"Sionna RT provides {names}")
        pols = sorted(ap.polarization_registry._registry)
        if not isinstance(polarization, str) or polarization not in pols:
            raise ConfigError(f"SionnaPattern: unknown polarization {polarization!r}; "
                              f"choose one of {pols}")
        models = sorted(ap.polarization_model_registry._registry)
        if not isinstance(polarization_model, str) or polarization_model not in models:
            raise ConfigError(f"SionnaPattern: unknown polarization_model "
                              f"{polarization_model!r}; choose one of {models}")
        antenna = ap.antenna_pattern_registry.get(name)(
            polarization=polarization, polarization_model=polarization_model)
        n_ports = len(antenna.patterns)
        if isinstance(port, bool) or not isinstance(port, Integral) or not 0 <= port < n_ports:
            raise ConfigError(f"SionnaPattern: port must be in [0, {n_ports - 1}] for "
                              f"polarization {polarization!r}, got {port!r}")
        self.name = name
        self.sionna_polarization = polarization
        self.polarization_model = polarization_model
        self.port = int(port)
        self.sionna_antenna_pattern = antenna
        self._pattern = antenna.patterns[self.port]

    def theta_phi(self, direction):
        """Sionna's ``(theta, phi)`` [rad] of radar-frame directions (``mi.Float``)."""
        from sionna.rt.utils import theta_phi_from_unit_vec

        return theta_phi_from_unit_vec(dr.normalize(_as_vector3f(direction)))

    def components(self, direction):
        """Sionna's ``(C_theta, C_phi)`` (``mi.Complex2f``) towards ``direction``."""
        theta, phi = self.theta_phi(direction)
        return self._pattern(theta, phi)

    def gain(self, direction, element=None) -> mi.Float:
        """``|C_theta|^2 + |C_phi|^2`` (linear power gain), ``mi.Float``."""
        c_t, c_p = self.components(direction)
        return (dr.square(dr.real(c_t)) + dr.square(dr.imag(c_t))
                + dr.square(dr.real(c_p)) + dr.square(dr.imag(c_p)))

    def polarization(self, direction, element=None) -> mi.Vector3f:
        """Unit ``Re(C_theta) theta_hat + Re(C_phi) phi_hat`` (Sionna's sign).

        Uses the imaginary parts where the real parts vanish, and Sionna's
        ``theta_hat`` where the pattern has a null (e.g. a dipole's axis).
        """
        from sionna.rt.utils import phi_hat, theta_hat

        theta, phi = self.theta_phi(direction)
        c_t, c_p = self._pattern(theta, phi)
        t_hat, p_hat = theta_hat(theta, phi), phi_hat(phi)
        e_re = dr.real(c_t) * t_hat + dr.real(c_p) * p_hat
        e_im = dr.imag(c_t) * t_hat + dr.imag(c_p) * p_hat
        scale = dr.maximum(dr.squared_norm(e_re) + dr.squared_norm(e_im), _TINY)
        e = dr.select(dr.squared_norm(e_re) > _DEGENERATE * scale, e_re, e_im)
        e = dr.select(dr.squared_norm(e) > _DEGENERATE * _DEGENERATE, e, t_hat)
        return dr.normalize(e)

    def __repr__(self):
        return (f"SionnaPattern({self.name!r}, polarization={self.sionna_polarization!r}, "
                f"polarization_model={self.polarization_model!r}, port={self.port})")


# --------------------------------------------------------------------------
# factory
# --------------------------------------------------------------------------
_COS_NAMES = ("cos", "cosine", "cos^q", "cosine_power")
_ISO_NAMES = ("iso", "isotropic")


def make_pattern(spec, **kwargs) -> BeamPattern:
    """Build a :class:`BeamPattern` from a specification.

    Parameters
    ----------
    spec : BeamPattern or str
        A :class:`BeamPattern` (returned unchanged; no ``kwargs``);
        ``"cos"`` / ``"cosine"``: ``CosinePowerPattern(**kwargs)``;
        ``"iso"`` / ``"isotropic"``: ``IsotropicPattern(**kwargs)``;
        ``"sionna:NAME"``: ``SionnaPattern(NAME, **kwargs)``;
        ``"sionna:NAME:POL"``: the same, with Sionna polarisation ``POL``.
    **kwargs
        Go to the constructor (e.g. ``q_az=3, n_elements=12``).

    Returns
    -------
    BeamPattern

    Raises
    ------
    ConfigError
        Any other ``spec``.
    """
    if isinstance(spec, BeamPattern):
        if kwargs:
            raise ConfigError(f"make_pattern: keyword arguments {sorted(kwargs)} given "
                              "with an existing BeamPattern instance")
        return spec
    if not isinstance(spec, str):
        raise ConfigError(f"beam pattern: expected a name or a BeamPattern, "
                          f"got {type(spec).__name__} {spec!r}")
    s = spec.strip()
    low = s.lower()
    try:
        if low in _COS_NAMES:
            return CosinePowerPattern(**kwargs)
        if low in _ISO_NAMES:
            return IsotropicPattern(**kwargs)
    except TypeError as exc:
        raise ConfigError(f"beam pattern {spec!r}: {exc}") from exc
    if low.startswith("sionna:"):
        parts = s.split(":")
        if len(parts) not in (2, 3) or not parts[1]:
            raise ConfigError(f"beam pattern {spec!r}: expected 'sionna:NAME' or "
                              "'sionna:NAME:POLARIZATION'")
        if len(parts) == 3:
            if "polarization" in kwargs:
                raise ConfigError(f"beam pattern {spec!r}: polarization given twice")
            kwargs["polarization"] = parts[2]
        try:
            return SionnaPattern(parts[1], **kwargs)
        except TypeError as exc:
            raise ConfigError(f"beam pattern {spec!r}: {exc}") from exc
    raise ConfigError(f"unknown beam pattern {spec!r}; choose one of "
                      f"{available_patterns()} (or pass a BeamPattern)")

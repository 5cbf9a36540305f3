"""ITU-R P.2040-3 Table 3 material properties and per-vertex initial values.

Frequency model (ITU-R P.2040-3, Section 2.1.4; eps'' from Section 2.1.2)::

    eps'(f)  = a * f_GHz ** b            real relative permittivity
    sigma(f) = c * f_GHz ** d            conductivity [S/m]
    eps''    = sigma / (2 pi f eps0)     = 17.98 * sigma / f_GHz
    eps_r    = eps' - j eps''            (time dependence exp(+j w t))

Each row of Table 3 is only valid over its stated frequency range.  At the
77 GHz automotive band the rows for brick (1-40 GHz), plywood (1-40 GHz),
marble (1-60 GHz) and the three ground types (1-10 GHz) do **not** apply;
:func:`itu_material` raises :class:`~sionna_mmir.errors.ConfigError` for them
unless ``allow_out_of_band=True`` is passed.

The coefficients below are those of ITU-R P.2040-3 Table 3.  They were
cross-checked row by row against ``ITU_MATERIALS_PROPERTIES`` in Sionna RT
2.2 (``sionna/rt/radio_materials/itu.py``), which ships the same table; the
test-suite repeats that comparison at run time.  Sionna RT additionally lists
rows above 100 GHz (110-330 and 100-400 GHz fits) and materials (clear
acrylic, vinyl/carpet tile, asphalt concrete) that it takes from the newer
P.2040-4; those are not reproduced here because this package targets the
60-81 GHz radar bands.  Note that the original P.2040-0 (2013) table had
different fits (e.g. concrete a = 5.31); the values here are those of
P.2040-1 and later.

References
----------
ITU-R P.2040-3 (2023), "Effects of building materials and structures on
radiowave propagation above about 100 MHz", Table 3.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ConfigError

EPSILON_0 = 8.8541878128e-12
"""Vacuum permittivity [F/m] (CODATA 2018)."""

VERTEX_PARAMETER_NAMES = ("eps_real", "eps_imag", "sigma_h", "l_c", "tau", "thickness")
"""Order of the six per-vertex material parameters (mmIR paper, Sec. 3.2)."""


@dataclass(frozen=True)
class ItuRow:
    """One row of ITU-R P.2040-3 Table 3.

    Parameters
    ----------
    name : str
        material class (lower case, ``_`` for blanks)
    a, b : float
        real permittivity fit ``eps' = a f_GHz^b``
    c, d : float
        conductivity fit ``sigma = c f_GHz^d`` [S/m]
    f_min_ghz : float
        lower end of the valid frequency range [GHz]
    f_max_ghz : float
        upper end of the valid frequency range [GHz]
    """

    name: str
    a: float
    b: float
    c: float
    d: float
    f_min_ghz: float
    f_max_ghz: float

    def covers(self, f_ghz: float) -> bool:
        """True when ``f_ghz`` lies in the row's (closed) valid range."""
        return self.f_min_ghz <= f_ghz <= self.f_max_ghz


# ITU-R P.2040-3 Table 3.  Columns: name, a, b, c, d, f_min [GHz], f_max [GHz].
ITU_P2040_TABLE3: tuple[ItuRow, ...] = (
    ItuRow("vacuum",            1.0,   0.0, 0.0,     0.0,    0.001, 100.0),
    ItuRow("concrete",          5.24,  0.0, 0.0462,  0.7822, 1.0,   100.0),
    ItuRow("brick",             3.91,  0.0, 0.0238,  0.16,   1.0,   40.0),
    ItuRow("plasterboard",      2.73,  0.0, 0.0085,  0.9395, 1.0,   100.0),
    ItuRow("wood",              1.99,  0.0, 0.0047,  1.0718, 0.001, 100.0),
    ItuRow("glass",             6.31,  0.0, 0.0036,  1.3394, 0.1,   100.0),
    ItuRow("glass",             5.79,  0.0, 0.0004,  1.658,  220.0, 450.0),
    ItuRow("ceiling_board",     1.48,  0.0, 0.0011,  1.0750, 1.0,   100.0),
    ItuRow("ceiling_board",     1.52,  0.0, 0.0029,  1.029,  220.0, 450.0),
    ItuRow("chipboard",         2.58,  0.0, 0.0217,  0.7800, 1.0,   100.0),
    ItuRow("plywood",           2.71,  0.0, 0.33,    0.0,    1.0,   40.0),
    ItuRow("marble",            7.074, 0.0, 0.0055,  0.9262, 1.0,   60.0),
    ItuRow("floorboard",        3.66,  0.0, 0.0044,  1.3515, 50.0,  100.0),
    ItuRow("metal",             1.0,   0.0, 1.0e7,   0.0,    1.0,   100.0),
    ItuRow("very_dry_ground",   3.0,   0.0, 0.00015, 2.52,   1.0,   10.0),
    ItuRow("medium_dry_ground", 15.0, -0.1, 0.035,   1.63,   1.0,   10.0),
    ItuRow("wet_ground",        30.0, -0.4, 0.15,    1.30,   1.0,   10.0),
)

ITU_TABLE: dict[str, tuple[ItuRow, ...]] = {}
for _row in ITU_P2040_TABLE3:
    ITU_TABLE[_row.name] = ITU_TABLE.get(_row.name, ()) + (_row,)
del _row


@dataclass(frozen=True)
class SurfaceDefaults:
    """Initial values of the non-ITU per-vertex parameters of one material.

    Parameters
    ----------
    sigma_h : float
        RMS surface height [m]
    l_c : float
        surface correlation length [m]
    tau : float
        KA/SPM blend factor in [0, 1] (1 = pure Kirchhoff/GGX)
    thickness : float
        slab thickness ``d`` of the P.2040 slab model [m]
    """

    sigma_h: float
    l_c: float
    tau: float
    thickness: float


# Initial values only: ITU-R P.2040 gives no roughness or thickness data, and
# the inverse renderer learns all four per vertex.  Assumptions:
# * thickness: common construction dimensions (0.2 m cast concrete wall,
#   12.5 mm gypsum board, 6 mm float glass, 30 mm timber, 18 mm chip/plywood
#   board, 15 mm mineral ceiling tile, 20 mm marble tile/floor board).  Metal
#   is "thick": 10 mm >> the 0.18 um skin depth at 77 GHz, so the slab
#   response equals the half-space Fresnel response for any d >~ 1 um.
#   Ground types are modelled as a 1 m (effectively semi-infinite) layer.
# * sigma_h: Rayleigh criterion at 77 GHz (lambda = 3.9 mm) calls a surface
#   smooth for sigma_h < lambda / (8 cos theta) ~ 0.5 mm.  Float glass,
#   polished marble and sheet metal are optically smooth (um scale); painted
#   board and timber ~0.1-0.2 mm; cast concrete ~0.5 mm; brick / textured
#   ceiling tile ~0.3-1 mm; natural ground several mm.
# * l_c: a few millimetres (~ lambda) for textured building surfaces, ~1 cm
#   for smooth ones and several cm for ground.
# * tau: close to 1 (Kirchhoff / microfacet) for smooth, large-l_c surfaces,
#   0.5 where both regimes plausibly apply, lower for small-scale roughness.
SURFACE_DEFAULTS: dict[str, SurfaceDefaults] = {
    "vacuum":            SurfaceDefaults(sigma_h=0.0,    l_c=1.0e-2, tau=1.0, thickness=0.0),
    "concrete":          SurfaceDefaults(sigma_h=5.0e-4, l_c=5.0e-3, tau=0.5, thickness=0.2),
    "brick":             SurfaceDefaults(sigma_h=1.0e-3, l_c=1.0e-2, tau=0.5, thickness=0.1),
    "plasterboard":      SurfaceDefaults(sigma_h=1.0e-4, l_c=5.0e-3, tau=0.7, thickness=0.0125),
    "wood":              SurfaceDefaults(sigma_h=2.0e-4, l_c=5.0e-3, tau=0.7, thickness=0.03),
    "glass":             SurfaceDefaults(sigma_h=1.0e-6, l_c=1.0e-2, tau=0.9, thickness=0.006),
    "ceiling_board":     SurfaceDefaults(sigma_h=3.0e-4, l_c=3.0e-3, tau=0.5, thickness=0.015),
    "chipboard":         SurfaceDefaults(sigma_h=1.0e-4, l_c=5.0e-3, tau=0.7, thickness=0.018),
    "plywood":           SurfaceDefaults(sigma_h=1.0e-4, l_c=5.0e-3, tau=0.7, thickness=0.018),
    "marble":            SurfaceDefaults(sigma_h=2.0e-5, l_c=1.0e-2, tau=0.9, thickness=0.02),
    "floorboard":        SurfaceDefaults(sigma_h=1.0e-4, l_c=5.0e-3, tau=0.7, thickness=0.02),
    "metal":             SurfaceDefaults(sigma_h=1.0e-5, l_c=1.0e-2, tau=0.9, thickness=0.01),
    "very_dry_ground":   SurfaceDefaults(sigma_h=5.0e-3, l_c=5.0e-2, tau=0.3, thickness=1.0),
    "medium_dry_ground": SurfaceDefaults(sigma_h=5.0e-3, l_c=5.0e-2, tau=0.3, thickness=1.0),
    "wet_ground":        SurfaceDefaults(sigma_h=5.0e-3, l_c=5.0e-2, tau=0.3, thickness=1.0),
}


@dataclass(frozen=True)
class ItuMaterial:
    """An ITU-R P.2040 material evaluated at one frequency.

    Parameters
    ----------
    name : str
        material class (key of :data:`ITU_TABLE`)
    eps_real : float
        eps', real relative permittivity
    eps_imag : float
        eps'' >= 0, so that ``eps_r = eps' - j eps''``
    conductivity : float
        sigma [S/m]
    valid_range_ghz : tuple[float, float]
        (f_min, f_max) of the Table 3 row used [GHz]
    frequency_hz : float, optional
        frequency the values were evaluated at [Hz]
    in_band : bool, optional
        False when the row was extrapolated out of its range
    """

    name: str
    eps_real: float
    eps_imag: float
    conductivity: float
    valid_range_ghz: tuple[float, float]
    frequency_hz: float = float("nan")
    in_band: bool = True

    @property
    def eps_r(self) -> complex:
        """Complex relative permittivity ``eps' - j eps''``."""
        return complex(self.eps_real, -self.eps_imag)


def _normalise_name(name: str) -> str:
    key = str(name).strip().lower().replace("-", "_").replace(" ", "_")
    if key.startswith("itu_"):
        key = key[4:]
    return key


def _check_frequency(frequency_hz) -> float:
    try:
        f = float(frequency_hz)
    except (TypeError, ValueError):
        raise ConfigError(f"frequency_hz must be a number in Hz, got {frequency_hz!r}") from None
    if not np.isfinite(f) or f <= 0.0:
        raise ConfigError(f"frequency_hz must be finite and > 0 Hz, got {frequency_hz!r}")
    return f


def _bands(rows) -> str:
    return ", ".join(f"{r.f_min_ghz:g}-{r.f_max_ghz:g} GHz" for r in rows)


def eps_imag_from_conductivity(conductivity, frequency_hz):
    """eps'' = sigma / (2 pi f eps0) (ITU-R P.2040-3, Section 2.1.2).

    Numerically ``17.98 * sigma / f_GHz``.

    Parameters
    ----------
    conductivity : float or array_like
        sigma [S/m] (scalar or array)
    frequency_hz : float
        frequency [Hz]

    Returns
    -------
    float or numpy.ndarray
        eps'' (dimensionless, >= 0)
    """
    return np.asarray(conductivity, dtype=float) / (2.0 * np.pi * float(frequency_hz) * EPSILON_0)


def itu_material(name: str, frequency_hz: float, allow_out_of_band: bool = False) -> ItuMaterial:
    """Evaluate ITU-R P.2040-3 Table 3 for material ``name`` at ``frequency_hz``.

    When ranges overlap, the first row of the table that covers ``f`` wins.

    Parameters
    ----------
    name : str
        material class, e.g. ``"concrete"``, ``"ceiling board"``
        (case, blanks, hyphens and an ``itu_`` prefix ignored)
    frequency_hz : float
        frequency [Hz]
    allow_out_of_band : bool, optional
        if True, a frequency outside every Table 3 range of
        the material uses the row whose range is nearest
        (result flagged ``in_band=False``) instead of raising

    Returns
    -------
    ItuMaterial

    Raises
    ------
    ConfigError
        Unknown materials and, unless ``allow_out_of_band``, frequencies
        outside the material's bands (the message names the material, the
        frequency and the valid bands).
    """
    key = _normalise_name(name)
    if key not in ITU_TABLE:
        raise ConfigError(f"unknown ITU-R P.2040 material {name!r}; "
                          f"choose one of {sorted(ITU_TABLE)}")
    f = _check_frequency(frequency_hz)
    f_ghz = f / 1e9
    rows = ITU_TABLE[key]
    row = next((r for r in rows if r.covers(f_ghz)), None)
    in_band = row is not None
    if row is None:
        if not allow_out_of_band:
            valid = available_materials(f)
            raise ConfigError(
                f"ITU-R P.2040 material {key!r} is not defined at {f_ghz:g} GHz: "
                f"its Table 3 fit is valid for {_bands(rows)} only. "
                f"Materials valid at {f_ghz:g} GHz: {valid}. "
                "Pass allow_out_of_band=True to extrapolate the nearest band's fit.")
        row = min(rows, key=lambda r: min(abs(f_ghz - r.f_min_ghz), abs(f_ghz - r.f_max_ghz)))
    eps_real = row.a * f_ghz ** row.b
    sigma = row.c * f_ghz ** row.d
    eps_imag = float(eps_imag_from_conductivity(sigma, f))
    return ItuMaterial(name=key, eps_real=float(eps_real), eps_imag=eps_imag,
                       conductivity=float(sigma),
                       valid_range_ghz=(row.f_min_ghz, row.f_max_ghz),
                       frequency_hz=f, in_band=in_band)


def available_materials(frequency_hz: float, include_vacuum: bool = False) -> list[str]:
    """Names of the Table 3 materials with a row valid at ``frequency_hz``.

    At 77 GHz: concrete, plasterboard, wood, glass, ceiling_board, chipboard,
    floorboard, metal.

    Parameters
    ----------
    frequency_hz : float
        frequency [Hz]
    include_vacuum : bool, optional
        also list ``"vacuum"`` (air) when it applies

    Returns
    -------
    list of str
        names, in table order
    """
    f_ghz = _check_frequency(frequency_hz) / 1e9
    names = [n for n, rows in ITU_TABLE.items() if any(r.covers(f_ghz) for r in rows)]
    if not include_vacuum:
        names = [n for n in names if n != "vacuum"]
    return names


def default_vertex_parameters(name: str, frequency_hz: float,
                              allow_out_of_band: bool = False) -> np.ndarray:
    """Initial per-vertex parameter vector of material ``name``.

    Permittivity from ITU-R P.2040-3 Table 3, the rest from
    :data:`SURFACE_DEFAULTS` (documented assumptions, learned later).

    Parameters
    ----------
    name : str
        material class (see :func:`itu_material`)
    frequency_hz : float
        frequency [Hz]
    allow_out_of_band : bool, optional
        forwarded to :func:`itu_material`

    Returns
    -------
    numpy.ndarray
        float64, shape (6,):
        ``[eps_real, eps_imag, sigma_h [m], l_c [m], tau,
        thickness [m]]`` (order :data:`VERTEX_PARAMETER_NAMES`)
    """
    mat = itu_material(name, frequency_hz, allow_out_of_band=allow_out_of_band)
    s = SURFACE_DEFAULTS[mat.name]
    return np.array([mat.eps_real, mat.eps_imag, s.sigma_h, s.l_c, s.tau, s.thickness],
                    dtype=np.float64)

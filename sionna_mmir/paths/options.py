"""``SolverOptions``: the one set of radar path-solver settings and its presets.

Every caller of :class:`~sionna_mmir.paths.RadarPathSolver` -- ``render``,
the fit models, the command line, the benchmark runner and the comparison
scripts -- takes its defaults from here.  Named presets say *why* a setting
differs from the default:

=====================  ======================================================
``SolverOptions()``    a general render: 20k random rays, depth 3, no pruning
``.fit()``             one fit iteration: depth 2 and paths 40 dB under the
                       strongest dropped (they are invisible in a min-max
                       range-azimuth loss, and a fit renders hundreds of times)
``.benchmark()``       the benchmark table's fits: facet quadrature, depth 3,
                       paths 40 dB down dropped (the truth's noise floor)
``.truth()``           benchmark ground truths: facet quadrature, depth 3,
                       diffraction on, no pruning
``.dense()``           dense-aperture inference (paper Sec. 4.3): single
                       bounce, as the paper renders its 100 x 100 array
=====================  ======================================================

The options are validated on construction (:class:`~sionna_mmir.errors.ConfigError`
names the bad field) and are immutable; :meth:`SolverOptions.replace` gives a
changed copy.
"""
from __future__ import annotations

import dataclasses
import math
import numbers
from typing import Any

import numpy as np

from ..errors import ConfigError

SAMPLING = ("random", "facets")


@dataclasses.dataclass(frozen=True)
class SolverOptions:
    """Settings of one radar path-solver call.

    Parameters
    ----------
    num_rays : int
        Candidate rays ``N`` of ``"random"`` sampling (unused by ``"facets"``).
    max_depth : int
        Interactions per path.
    seed : int
        Seed of the shared sampler; the same seed gives identical paths.
    sampling : {"random", "facets"}
        Monte Carlo rays in a cosine-weighted cone, or one ray per (sub-)facet
        centroid weighted by its solid angle (a deterministic quadrature).
    cone_angle_deg : float
        Half-angle of the ray cone about boresight [deg], in ``(0, 90]``.
    coherent, scattering : bool
        Include the physical-optics coherent part / the BSDF-scattered part.
    reciprocal : bool
        Add the reversed twin of specular-then-scatter paths by reciprocity.
    triangle_average : bool
        Integrate the physical-optics phase exactly over each hit triangle.
    diffraction : bool
        Free-space diffraction (FSD) at boundary and crease edges.
    fsd_width : float or None
        Gaussian footprint of the FSD lobe [m] (default 3 wavelengths).
    rr_depth : int
        Depth from which Russian roulette ends paths.
    facet_fresnel : float
        Bound on a (sub-)facet's quadratic phase ``k D^2 / R`` [rad].
    max_facet_split : int
        Most splits per facet edge in ``"facets"`` sampling.
    min_rel_power : float
        Drop paths weaker than this times the strongest before their
        per-element legs are formed, in ``[0, 1)``.
    tx_pattern, rx_pattern : str or BeamPattern
        Element patterns (``"cos"``, ``"iso"``, ``"sionna:tr38901"``, or a
        :class:`~sionna_mmir.radio_devices.BeamPattern`).
    velocities : dict or None
        ``{object: (vx, vy, vz)}`` [m/s] in the scene frame.
    radar_velocity : tuple or None
        ``(vx, vy, vz)`` [m/s] of the radar in the scene frame.
    check_inside : bool
        Raise if the array centre sits inside closed geometry.
    """

    num_rays: int = 20_000
    max_depth: int = 3
    seed: int = 0
    sampling: str = "random"
    cone_angle_deg: float = 90.0
    coherent: bool = True
    scattering: bool = True
    reciprocal: bool = True
    triangle_average: bool = True
    diffraction: bool = False
    fsd_width: float | None = None
    rr_depth: int = 2
    facet_fresnel: float = 0.5
    max_facet_split: int = 64
    min_rel_power: float = 0.0
    tx_pattern: Any = "cos"
    rx_pattern: Any = "cos"
    velocities: dict | None = None
    radar_velocity: tuple | None = None
    check_inside: bool = True

    def __post_init__(self):
        _validate(self)

    # ----------------------------------------------------------------- presets
    @classmethod
    def fit(cls, **changes) -> "SolverOptions":
        """One fit iteration: depth 2, paths 40 dB down dropped."""
        return cls(**{"max_depth": 2, "min_rel_power": 1e-4, **changes})

    @classmethod
    def benchmark(cls, **changes) -> "SolverOptions":
        """The benchmark table's fits: facets, depth 3, paths 40 dB down dropped."""
        return cls(**{"sampling": "facets", "max_depth": 3, "min_rel_power": 1e-4, **changes})

    @classmethod
    def truth(cls, **changes) -> "SolverOptions":
        """Benchmark ground truths: facets, depth 3, diffraction, nothing dropped."""
        return cls(**{"sampling": "facets", "max_depth": 3, "diffraction": True, **changes})

    @classmethod
    def dense(cls, **changes) -> "SolverOptions":
        """Dense-aperture inference: single bounce (paper Sec. 4.3)."""
        return cls(**{"max_depth": 1, **changes})

    @classmethod
    def resolve(cls, options: "SolverOptions | dict | None" = None,
                **overrides) -> "SolverOptions":
        """``options`` (an instance, a dict or ``None`` for the defaults) with
        ``overrides`` applied; unknown names raise :class:`ConfigError`."""
        if options is None:
            base = {}
        elif isinstance(options, SolverOptions):
            base = options.to_dict()
        elif isinstance(options, dict):
            base = dict(options)
        else:
            raise ConfigError(f"solver options must be SolverOptions or a dict, got "
                              f"{type(options).__name__}")
        base.update(overrides)
        unknown = sorted(set(base) - {f.name for f in dataclasses.fields(cls)})
        if unknown:
            raise ConfigError(f"unknown solver option(s) {unknown}")
        return cls(**base)

    def replace(self, **changes) -> "SolverOptions":
        """A copy with ``changes`` applied (validated)."""
        return SolverOptions.resolve(self, **changes)

    def to_dict(self) -> dict:
        """The options as a plain dict (field name -> value)."""
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}

    def describe(self) -> dict:
        """JSON-serialisable summary (patterns by name) for reports and metadata."""
        out = self.to_dict()
        for key in ("tx_pattern", "rx_pattern"):
            if not isinstance(out[key], str):
                out[key] = type(out[key]).__name__
        return out


def _is_int(v) -> bool:
    return isinstance(v, numbers.Integral) and not isinstance(v, bool)


def _is_number(v) -> bool:
    return (isinstance(v, numbers.Real) and not isinstance(v, bool)
            and math.isfinite(float(v)))


def _validate(o: SolverOptions) -> None:
    checks = (
        ("num_rays", _is_int(o.num_rays) and int(o.num_rays) >= 1, ">= 1 (an integer)"),
        ("num_rays", not _is_int(o.num_rays) or int(o.num_rays) < 2 ** 31,
         "< 2^31 (Dr.Jit array limit)"),
        ("max_depth", _is_int(o.max_depth) and int(o.max_depth) >= 1, ">= 1 (an integer)"),
        ("seed", _is_int(o.seed) and int(o.seed) >= 0, ">= 0 (an integer)"),
        ("sampling", o.sampling in SAMPLING, f"one of {SAMPLING}"),
        ("cone_angle_deg", _is_number(o.cone_angle_deg) and 0 < float(o.cone_angle_deg) <= 90,
         "in (0, 90]"),
        ("rr_depth", _is_int(o.rr_depth) and int(o.rr_depth) >= 0, ">= 0 (an integer)"),
        ("facet_fresnel", _is_number(o.facet_fresnel) and float(o.facet_fresnel) > 0, "> 0"),
        ("max_facet_split", _is_int(o.max_facet_split) and int(o.max_facet_split) >= 1,
         ">= 1 (an integer)"),
        ("min_rel_power", _is_number(o.min_rel_power) and 0 <= float(o.min_rel_power) < 1,
         "in [0, 1)"),
        ("fsd_width", o.fsd_width is None or (_is_number(o.fsd_width) and float(o.fsd_width) > 0),
         "> 0 [m] or None"),
    )
    for name, ok, what in checks:
        if not ok:
            raise ConfigError(f"solver option {name} must be {what}, got {getattr(o, name)!r}")
    for name in ("coherent", "scattering", "reciprocal", "triangle_average", "diffraction",
                 "check_inside"):
        if not isinstance(getattr(o, name), (bool, numbers.Integral)):
            raise ConfigError(f"solver option {name} must be True or False, "
                              f"got {getattr(o, name)!r}")
    if o.velocities is not None and not isinstance(o.velocities, dict):
        raise ConfigError(f"solver option velocities must be a dict object -> (vx, vy, vz), "
                          f"got {type(o.velocities).__name__}")
    for name, v in (o.velocities or {}).items():
        _check_velocity(f"velocities[{name!r}]", v)
    if o.radar_velocity is not None:
        _check_velocity("radar_velocity", o.radar_velocity)


def _check_velocity(what: str, value) -> None:
    """Three finite numbers [m/s] of a speed below the speed of light."""
    from ..radar.config import SPEED_OF_LIGHT

    try:
        v = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        v = np.zeros(0)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise ConfigError(f"solver option {what} must be three finite numbers [m/s], "
                          f"got {value!r}")
    if np.linalg.norm(v) >= SPEED_OF_LIGHT:
        raise ConfigError(f"solver option {what}: speed {np.linalg.norm(v):.6g} m/s is not "
                          f"below the speed of light ({SPEED_OF_LIGHT:.0f} m/s)")

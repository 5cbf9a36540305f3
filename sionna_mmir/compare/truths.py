"""Benchmark truths from three renderers, for two co-located sensors, cached on disk.

A fit scored against a truth rendered by the model it fits is
self-referential; these truths come from three renderers that share
progressively less with mmIR:

``"mmir"``
    mmIR's own path solver, deterministic facet quadrature
    (:func:`~sionna_mmir.compare.ground_truth.render_ground_truth`: clean
    geometry refined to 8 cm edges, true spatially varying per-vertex
    materials, depth 3, free-space diffraction), ``cos^q`` elements.
``"sionna"``
    unmodified Sionna RT (:class:`~sionna_mmir.baseline.SionnaBaseline`) on
    the clean geometry with the scene's true materials as far as Sionna can
    hold them: it has one material per object, so every object is cut into
    its material regions (each patch of another material and the host;
    :func:`~sionna_mmir.benchmark_scenes.materials.true_region_materials`),
    one Sionna object per region with the surface mean of the true
    per-vertex materials over that region, mapped the way the baseline
    parameterises a material (:func:`baseline_material_values`); its own
    Monte Carlo ``PathSolver`` at depth 3 with :data:`SIONNA_TRUTH_SAMPLES`
    rays per Tx element, seed 0, isotropic elements (the baseline's).
``"independent"``
    the plain NumPy physical-optics reference
    (:func:`~sionna_mmir.independent.reference_truth`, no code shared with
    the solver): true materials evaluated at the sub-facets themselves,
    depth 3, ``cos^q`` elements.

All three describe the same scene: the clean geometry with the true
materials, which differ from the nominal ITU classes every fitter starts
from.  Each gets complex white receiver noise 40 dB under its peak ADC sample.
Sensors: ``"cascade"`` (:meth:`RadarConfig.mmwcas`, one chirp, at the
scene's radar pose) and ``"awr1843"`` (:meth:`RadarConfig.awr1843` at the
cascade's pose composed with the single-chip mounting relative to the
cascade on the ColoRadar rig, :func:`sensor_radar`).
"""
from __future__ import annotations

import os
import time

import numpy as np

from ..errors import ConfigError

TRUTHS = ("mmir", "sionna", "independent")
SENSORS = ("cascade", "awr1843")
#: Sionna truth rays per Tx element (depth 3).  Cascade (12 sources x 16
#: targets): 100k, 3.3x the fits' 30k and the most that leaves room for other
#: jobs on a 23 GB machine (classroom, the largest scene: peak RSS 8.0 GB at
#: 200k); AWR1843 (3 x 4): Sionna's default 1M (2.7 GB, 9 s).
SIONNA_TRUTH_SAMPLES = {"cascade": 100_000, "awr1843": 1_000_000}
#: receiver noise under the peak ADC sample [dB] (as the benchmark truth)
NOISE_DB = -40.0
#: name of a truth in cache file names where it differs from the truth's name:
#: the Sionna truth with per-region true materials must not read the files of
#: earlier definitions (nominal materials, one true mean per object)
CACHE_LABELS = {"sionna": "sionna-regions"}


def cache_label(truth: str) -> str:
    """The name ``truth`` goes by in cache file names (:data:`CACHE_LABELS`)."""
    return CACHE_LABELS.get(truth, truth)


def calibration_dir():
    """The ColoRadar calibration folder (``<measured>/coloradar_calib``) or raise."""
    from ..captures.measured import find_measured_dir

    root = find_measured_dir()
    path = None if root is None else root / "coloradar_calib"
    if path is None or not (path / "transforms").is_dir():
        raise ConfigError("ColoRadar calibration (coloradar_calib/transforms) not found: set "
                          "$SIONNA_MMIR_MEASURED to the measured-data folder")
    return path


def sensor_radar(spec, sensor: str, calib_dir=None):
    """The radar ``sensor`` of scene ``spec`` (one chirp), posed.

    ``"cascade"``: :func:`~sionna_mmir.benchmark_scenes.catalog.scene_radar`.
    ``"awr1843"``: the AWR1843 at the cascade's pose composed with the
    single-chip mounting relative to the cascade
    (:func:`~sionna_mmir.captures.coloradar_calib.colocated_pose`).
    """
    from ..benchmark_scenes.catalog import scene_radar
    from ..captures.coloradar_calib import colocated_pose
    from ..radar.config import RadarConfig

    cascade = scene_radar(spec)
    if sensor == "cascade":
        return cascade
    if sensor != "awr1843":
        raise ConfigError(f"sensor must be one of {SENSORS}, got {sensor!r}")
    p, o = colocated_pose(cascade.position, cascade.orientation,
                          calib_dir or calibration_dir(), "single_chip", "cascade")
    return RadarConfig.awr1843(num_chirps=1, position=tuple(p), orientation=tuple(o))


def _with_noise(adc: np.ndarray, seed: int, noise_db: float) -> np.ndarray:
    rng = np.random.default_rng(seed)
    sigma = np.abs(adc).max() * np.sqrt(10 ** (noise_db / 10) / 2)
    return adc + sigma * (rng.standard_normal(adc.shape) + 1j * rng.standard_normal(adc.shape))


def baseline_material_values(params: dict, frequency_hz: float = 77e9) -> dict:
    """Material parameters ``{name: (6,)}`` as :class:`~sionna_mmir.baseline.SionnaBaseline` values.

    ``params`` holds ``[eps_real, eps_imag, sigma_h, l_c, tau, d]`` per
    object (e.g. surface means of the true per-vertex materials), mapped
    onto the per-object scalars the baseline has for them:
    ``relative_permittivity = eps_real``, ``conductivity = 2 pi f eps0
    eps_imag`` (ITU-R P.2040-3 2.1.2 at the carrier) and ``thickness = d``.
    The baseline has no counterpart of the roughness terms (``sigma_h``,
    ``l_c``, ``tau``): its ``scattering_coefficient`` and ``xpd_coefficient``
    keep their starting values, as in every Sionna render here.  Returns
    ``{"<object>.<param>": float}`` for :meth:`SionnaBaseline.set_values`.
    """
    from ..radio_materials.itu_table import EPSILON_0

    out = {}
    for name, p in params.items():
        out[f"{name}.relative_permittivity"] = float(p[0])
        out[f"{name}.conductivity"] = float(2 * np.pi * frequency_hz * EPSILON_0 * p[1])
        out[f"{name}.thickness"] = float(p[5])
    return out


def sionna_material_values(spec, seed: int = 0, frequency_hz: float = 77e9) -> dict:
    """The true materials of ``spec`` per object, as :class:`SionnaBaseline` values.

    Per object, the surface mean of the true per-vertex parameters
    (:func:`~sionna_mmir.benchmark_scenes.materials.true_object_materials`)
    through :func:`baseline_material_values`: what a model that keeps one
    material per scene object can hold of the truth at best.
    """
    from ..benchmark_scenes.materials import true_object_materials

    return baseline_material_values(true_object_materials(spec, seed, frequency_hz=frequency_hz),
                                    frequency_hz)


def sionna_truth(spec, radar, *, samples_per_src: int, seed: int = 0,
                 noise_db: float = NOISE_DB):
    """Sionna RT's render of the clean scene cut into true material regions (a ``Capture``)."""
    from ..baseline import SionnaBaseline
    from ..benchmark_scenes.materials import true_region_materials
    from ..captures.capture import Capture
    from ..paths.render import to_numpy

    t0 = time.perf_counter()
    regions = true_region_materials(spec, seed)
    base = SionnaBaseline({k: r[0] for k, r in regions.items()},
                          {k: r[1] for k, r in regions.items()}, radar, max_depth=3,
                          samples_per_src=int(samples_per_src), seed=seed)
    values = baseline_material_values({k: r[2] for k, r in regions.items()}, base.frequency)
    base.set_values(values)
    adc = to_numpy(base.render())[None].astype(np.complex128)
    adc = _with_noise(adc, seed, noise_db)
    meta = {"scene": spec.name, "renderer": "sionna.rt PathSolver (SionnaBaseline)",
            "samples_per_src": int(samples_per_src), "max_depth": 3,
            "materials": "true, surface mean per material region (host, patches, blobs)",
            "regions": len(regions), "material_values": values,
            "noise_db": noise_db, "seconds": time.perf_counter() - t0}
    return Capture(adc.astype(np.complex64), radar, meta, "sionna_mmir.compare.truths.sionna")


def render_truth(truth: str, spec, sensor: str = "cascade", *, seed: int = 0, calib_dir=None):
    """A one-frame :class:`~sionna_mmir.captures.Capture` of ``spec`` by ``truth`` for ``sensor``."""
    from .ground_truth import render_ground_truth

    radar = sensor_radar(spec, sensor, calib_dir)
    t0 = time.perf_counter()
    if truth == "mmir":
        cap = render_ground_truth(spec, radar=radar, seed=seed, num_rays=100_000, max_edge=0.08,
                                  sampling="facets", noise_db=NOISE_DB)
    elif truth == "sionna":
        cap = sionna_truth(spec, radar, samples_per_src=SIONNA_TRUTH_SAMPLES[sensor], seed=seed)
    elif truth == "independent":
        from ..independent import reference_truth

        cap = reference_truth(spec, radar, seed=seed, max_depth=3, noise_db=NOISE_DB)
    else:
        raise ConfigError(f"truth must be one of {TRUTHS}, got {truth!r}")
    cap.metadata["truth"] = truth
    cap.metadata["sensor"] = sensor
    cap.metadata["render_s"] = time.perf_counter() - t0
    return cap


def truth_path(cache_dir, truth: str, scene: str, sensor: str) -> str:
    """Cache file of one truth capture."""
    return os.path.join(os.fspath(cache_dir), "truths",
                        f"{cache_label(truth)}_{scene}_{sensor}.h5")


def cached_truth(cache_dir, truth: str, spec, sensor: str = "cascade", **kwargs):
    """:func:`render_truth`, read from / written to ``cache_dir`` (HDF5 captures)."""
    from ..captures.capture import Capture

    path = truth_path(cache_dir, truth, spec.name, sensor)
    if os.path.exists(path):
        return Capture.load(path)
    cap = render_truth(truth, spec, sensor, **kwargs)
    os.makedirs(os.path.dirname(path), exist_ok=True)
    cap.save(path, overwrite=True)
    return cap

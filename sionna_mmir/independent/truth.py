"""Benchmark captures rendered by the independent reference renderer.

:func:`reference_truth` renders a catalog scene
(:func:`sionna_mmir.benchmark_scenes.build_scene`) the way
:func:`sionna_mmir.compare.ground_truth.render_ground_truth` does -- the
cascade radar at the scene's pose, the clean geometry, the ground-truth
spatially varying materials, complex white receiver noise ``noise_db``
below the peak ADC sample -- but with
:func:`~sionna_mmir.independent.physical_optics.render_reference` instead
of the package's path solver.  The materials are the benchmark's
definition (data): :func:`sionna_mmir.benchmark_scenes.true_vertex_materials` is a
function of 3-D position and is evaluated at the sub-facet centroids and
mirror points themselves, not interpolated from vertices.
"""
from __future__ import annotations

import numpy as np

from ..errors import ConfigError


def _true_material(spec, name: str, seed: int):
    from ..benchmark_scenes.materials import true_vertex_materials

    return lambda points: true_vertex_materials(spec, name, points, seed)


def reference_truth(spec, radar=None, seed: int = 0, *, max_depth: int = 3,
                    noise_db: float = -40.0, true_materials: bool = True, **options):
    """A :class:`~sionna_mmir.captures.Capture` of catalog scene ``spec``.

    Parameters
    ----------
    spec : SceneSpec
        A benchmark scene (``build_scene(name, layout_seed)``).
    radar : RadarConfig or None
        Default: the cascade radar at the scene's pose
        (:func:`sionna_mmir.compare.ground_truth.scene_radar`, one chirp).
    seed : int
        Material seed (as the benchmark truth), seed of the rough-surface
        phases and of the receiver noise.
    max_depth : int
        Surface interactions (1-3; the benchmark truth uses 3, which costs
        about three times depth 2).
    noise_db : float
        Receiver noise power per complex sample relative to the peak ADC
        sample power [dB].
    true_materials : bool
        Ground-truth spatially varying materials (default) or the nominal
        ITU-R P.2040 classes of ``spec.materials``.
    **options
        Passed to :func:`~sionna_mmir.independent.physical_optics.render_reference`
        (e.g. ``tx_pattern``, ``fresnel``, ``merge_fraction``).

    Returns
    -------
    Capture
        One frame, ``[1, T, R, chirps, samples]`` complex64; ``metadata``
        records the renderer, its options, counts and timings.

    Raises
    ------
    ConfigError
        A bad ``seed`` or ``noise_db``.
    """
    from ..captures.capture import Capture
    from ..benchmark_scenes.catalog import scene_radar
    from .physical_optics import render_reference

    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ConfigError(f"reference_truth: seed must be a non-negative int, got {seed!r}")
    if not np.isfinite(noise_db):
        raise ConfigError(f"reference_truth: noise_db must be finite, got {noise_db!r}")
    radar = scene_radar(spec) if radar is None else radar
    materials = ({name: _true_material(spec, name, int(seed)) for name in spec.objects}
                 if true_materials else dict(spec.materials))
    paths = render_reference(spec.objects, materials, radar, max_depth=max_depth,
                             seed=int(seed), **options)
    adc = paths.adc(radar)[None].astype(np.complex128)
    rng = np.random.default_rng(seed)
    sigma = np.abs(adc).max() * np.sqrt(10 ** (noise_db / 10) / 2)
    adc = adc + sigma * (rng.standard_normal(adc.shape) + 1j * rng.standard_normal(adc.shape))
    meta = {"scene": getattr(spec, "name", ""), "layout_seed": int(getattr(spec, "seed", 0)),
            "seed": int(seed), "renderer": "sionna_mmir.independent.render_reference",
            "max_depth": int(max_depth), "noise_db": float(noise_db),
            "true_materials": bool(true_materials), "frames": 1,
            "options": {k: (v if isinstance(v, (int, float, str, bool)) or v is None else str(v))
                        for k, v in options.items()},
            "paths": paths.num_paths, "subfacets": paths.info["subfacets"],
            "chains": paths.info["chains"], "seconds": paths.info["total_seconds"]}
    return Capture(adc.astype(np.complex64), radar, meta, "sionna_mmir.independent.reference_truth")

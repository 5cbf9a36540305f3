"""Fit mmIR and the Sionna RT baseline to the same capture, same budget, same metrics.

Both sides get: the same meshes (the fitter's, e.g. LiDAR-like), the same
nominal ITU materials as initial values, the same radar (elements, pose),
the same ADC synthesis, RA processing, min-max RA loss (paper eq. 7), Adam
settings and iteration budget.  What each side may learn differs by design:
mmIR per-vertex materials, normals and beam patterns; Sionna per-object
material scalars (what it exposes).  Seconds per iteration are measured in
the same run.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np


@dataclass
class SideResult:
    """One model's outcome: metrics before / after, loss curve, timing, RA map."""

    name: str
    metrics_before: dict
    metrics_after: dict
    history: np.ndarray
    seconds_per_it: float
    ra_after: np.ndarray
    extra: dict = field(default_factory=dict)


def target_ra(frames: np.ndarray, radar, **ra_kwargs) -> np.ndarray:
    """Non-coherent mean of the frames' RA maps (``frames`` [F, tx, rx, chirp, sample])."""
    from ..processing.imaging import mean_range_azimuth

    return mean_range_azimuth(frames, radar, **ra_kwargs)


def evaluate(model, latents, ra_ref, adc_ref, seeds=(9001, 9002)):
    """Metrics of ``model`` at ``latents`` (RA averaged over evaluation seeds)."""
    from ..metrics import all_metrics
    from ..paths.render import to_numpy
    from ..processing.imaging import range_azimuth

    ras, adcs = [], []
    for s in seeds:
        adc, _ = model.render(latents, seed=s)
        a = to_numpy(adc)
        adcs.append(a)
        ras.append(range_azimuth(a, model.radar)[0])
    ra = np.mean(ras, axis=0)
    return all_metrics(ra_ref, ra, adc_ref, adcs[0]), ra


def run_side(name, model, ra_ref, adc_ref, *, iterations, lr, seed=0, progress=True,
             checkpoint=None):
    from ..fit import fit

    z0 = model.latents()
    before, _ = evaluate(model, z0, ra_ref, adc_ref)
    t0 = time.perf_counter()
    res = fit(model, ra_ref, iterations=iterations, lr=lr, seed=seed, progress=progress,
              checkpoint=checkpoint)
    wall = time.perf_counter() - t0
    after, ra = evaluate(model, res.latents, ra_ref, adc_ref)
    return SideResult(name=name, metrics_before=before, metrics_after=after,
                      history=res.history, seconds_per_it=res.seconds_per_it, ra_after=ra,
                      extra={"fit_wall_s": wall, "latents": res.latents, "model": model})


def run_sides(models, ra_ref, adc_ref, *, iterations, lr, seed=0, progress=True,
              checkpoints: dict | None = None) -> dict:
    """:func:`run_side` for each ``(label, model)``; returns ``{label: SideResult}``."""
    return {label: run_side(label, model, ra_ref, adc_ref, iterations=iterations, lr=lr,
                            seed=seed, progress=progress,
                            checkpoint=(checkpoints or {}).get(label))
            for label, model in models}

"""Error measures of a model against a capture: the paper's metrics plus residual energy.

The model's RA map is its *expected* magnitude, ``sqrt(|RA(mean)|^2 +
E|RA(noise)|^2)``: the mean render plus the noise power its variance model
predicts (estimated from ``n_noise`` draws), so a model with a noise floor is
compared like for like with a noisy measurement.
"""
from __future__ import annotations

import numpy as np

from ..metrics import all_metrics
from ..processing.imaging import range_azimuth

MAX_FRAMES = 32


def _frames(F: int) -> np.ndarray:
    return np.unique(np.linspace(0, F - 1, min(F, MAX_FRAMES)).round().astype(int))


def ra_power(ctx, adc) -> tuple:
    """Mean over (up to 32 evenly spaced) frames of ``|RA|^2``; ``(map, ranges, az)``."""
    acc = None
    for f in _frames(adc.shape[0]):
        ra, rng, az = range_azimuth(adc[f], ctx.radar)
        p = np.asarray(ra, np.float64) ** 2
        acc = p if acc is None else acc + p
    return acc / len(_frames(adc.shape[0])), rng, az


def model_ra(ctx, mean, variance, n_noise: int = 2, seed: int = 0):
    """Expected RA magnitude of a model with mean ADC and range-bin noise variance."""
    p, rng, az = ra_power(ctx, mean)
    if variance is not None and np.any(variance > 0):
        gen = np.random.default_rng(seed)
        acc = 0.0
        for _ in range(n_noise):
            z = (gen.normal(size=mean.shape) + 1j * gen.normal(size=mean.shape)) / np.sqrt(2)
            noise = np.fft.ifft(z * np.sqrt(np.broadcast_to(variance, mean.shape)), axis=-1,
                                norm="ortho")
            acc = acc + ra_power(ctx, noise)[0]
        p = p + acc / n_noise
    return np.sqrt(p), rng, az


def score(ctx, measured, mean, variance=None) -> dict:
    """Table 2 metrics of the model (mean + variance) against ``measured`` plus
    ``residual_energy_db = 10 log10(|y - mean|^2 / |y|^2)``.

    All arrays complex ``[F, T, R, C, N]`` in the capture's units; ``variance``
    per range bin in the same units squared (broadcastable), or None.
    """
    ra_meas = np.sqrt(ra_power(ctx, measured)[0])
    ra_mod = model_ra(ctx, mean, variance)[0]
    out = all_metrics(ra_mod, ra_meas, mean, measured)
    e = np.sum(np.abs(measured - mean) ** 2) / max(np.sum(np.abs(measured) ** 2), 1e-300)
    out["residual_energy_db"] = float(10 * np.log10(max(e, 1e-30)))
    return {k: float(v) for k, v in out.items()}

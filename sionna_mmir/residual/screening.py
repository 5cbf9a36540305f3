"""Screening: which candidates the data cannot support at all, found cheaply.

Scoring a candidate means fitting it on every cross-validation fold.  Some
effects leave a signature that a one-pass statistic rules out, so they are
not fitted when the statistic says there is nothing for them:

* **chirp-to-chirp change** (``ego_motion``, ``moving_scatterer``,
  ``phase_noise``): the deviation of each chirp from the mean over chirp
  loops, ``d = y - mean_c(y)``, is white receiver noise for a static scene
  and a static sensor.  Its power per range bin ``P[k]`` (averaged over
  frames, channels and chirps) is then flat; motion and LO phase noise put
  range-localised power into it.  The test is the largest ratio of ``P[k]``
  (smoothed over 3 bins) to its median.  LO phase noise at short range is
  nearly white in power, but one LO serves every Rx of a transmit slot:
  ``phase_noise`` is kept while the deviation along the slot's common
  frequency-error direction exceeds white noise's (:func:`coherent_excess`).
* **coloured receiver noise** (``noise_floor``): the same deviation's power,
  median-filtered over a range window wide enough to ignore targets, varies
  across the IF band only when the noise is coloured.
* **ADC saturation** (``adc_clipping``): a hard clip leaves many raw I or Q
  samples at one extreme value; unclipped data has a single extreme.

Each test returns the reason a candidate is left out, which the report
shows.  With one chirp loop (and one frame) nothing can be screened.
"""
from __future__ import annotations

import numpy as np
from scipy.ndimage import median_filter, uniform_filter1d

from ..effects.library._sensor_common import chirp_deviation

#: candidates whose signature is a chirp-to-chirp change
SLOW_TIME = ("ego_motion", "moving_scatterer", "phase_noise")
#: smallest peak excess of the chirp deviation's range profile that counts
SLOW_EXCESS = 1.5
#: smallest :func:`coherent_excess` that keeps ``phase_noise``
COHERENT_EXCESS = 1.5
#: smallest spread [dB] of the deviation's median-filtered profile that counts
COLOUR_SPREAD_DB = 1.0
#: smallest fraction of raw I/Q samples at the extreme that counts as clipping
CLIP_FRACTION = 1e-3


def deviation_profile(y: np.ndarray) -> np.ndarray | None:
    """Power per range bin ``[N]`` of the chirp-to-chirp (else frame-to-frame)
    deviation of ``y [F, T, R, C, N]``
    (:func:`~sionna_mmir.effects.library._sensor_common.chirp_deviation`);
    ``None`` with one chirp and one frame."""
    d = chirp_deviation(y)
    if d is None and y.shape[0] > 1:                    # frames as the slow axis
        d = chirp_deviation(np.moveaxis(y, 0, 3))
    if d is None:
        return None
    D = np.fft.fft(d, axis=-1, norm="ortho")
    return np.mean(np.abs(D) ** 2, axis=(0, 1, 2, 3))


def coherent_excess(y: np.ndarray, ctx) -> float | None:
    """The chirp deviation's energy along the LO's common frequency-error
    direction, in units of white noise's: 1 for independent noise, more where
    one real error ``e`` per slot and sample moves every Rx along
    ``g_r = (1 / S) dx_r/dt`` (:mod:`~sionna_mmir.effects.library.phase_noise`).

    ``y`` ``[F, T, R, C, N]``; ``g`` from the chirp mean of ``y``, ``d`` its
    deviation (:func:`~sionna_mmir.effects.library._sensor_common.chirp_deviation`),
    per slot and sample ``(Re g^H d)^2 / (|g|^2 s^2 / 2)`` averaged, with the
    floor ``s^2`` from the median of ``|d|^2`` (exponential: ``median = s^2 ln 2``).
    A shared amplitude change (a transmit droop) lies along ``x``, at right
    angles to ``g`` for each path, and does not count.  None with one chirp
    loop or one Rx."""
    from ..effects.library.phase_noise import along_common, slope_derivative

    d = chirp_deviation(y)
    if d is None or y.shape[2] < 2:
        return None
    g = slope_derivative(y.mean(axis=3, keepdims=True), ctx)
    floor = max(float(np.median(np.abs(d) ** 2)) / np.log(2.0), 1e-300)
    a2 = along_common(g, d, 1.0 / floor)[0]
    return float(np.mean(a2) / 0.5)


def screen(y: np.ndarray, raw_scale: float, candidates, ctx=None) -> dict:
    """Candidates the data cannot support: ``{name: reason}``.

    Parameters
    ----------
    y : numpy.ndarray
        Capture ADC ``[F, T, R, C, N]`` (any normalisation).
    raw_scale : float
        Factor back to the capture's own units (for the saturation test).
    candidates : iterable of Effect
        The candidates to test.
    ctx : EffectContext, optional
        The capture's context, for :func:`coherent_excess` (without it
        ``phase_noise`` is judged on the range profile alone).
    """
    names = {c.name for c in candidates}
    out = {}
    P = deviation_profile(y)
    if P is not None:
        med = max(float(np.median(P)), 1e-300)
        excess = float(uniform_filter1d(P, 3, mode="wrap").max() / med)
        if excess < SLOW_EXCESS:
            for n in names & set(SLOW_TIME):
                out[n] = (f"no chirp-to-chirp change beyond white noise (peak excess "
                          f"{excess:.2f} < {SLOW_EXCESS})")
            common = coherent_excess(y, ctx) if "phase_noise" in out and ctx is not None else None
            if common is not None:
                if common >= COHERENT_EXCESS:
                    del out["phase_noise"]
                else:
                    out["phase_noise"] += (f"; none along the LO's common frequency error "
                                           f"(excess {common:.2f} < {COHERENT_EXCESS})")
        smooth = median_filter(P, size=max(9, len(P) // 8), mode="wrap")
        spread = float(10 * np.log10(smooth.max() / max(smooth.min(), 1e-300)))
        if "noise_floor" in names and spread < COLOUR_SPREAD_DB:
            out["noise_floor"] = (f"the receiver noise is white (spread {spread:.2f} dB < "
                                  f"{COLOUR_SPREAD_DB} dB across the band)")
    if "adc_clipping" in names:
        raw = np.asarray(y) * raw_scale
        parts = np.concatenate([np.abs(raw.real).ravel(), np.abs(raw.imag).ravel()])
        top = float(parts.max())
        frac = float(np.mean(parts >= 0.999 * top)) if top > 0 else 0.0
        if frac < CLIP_FRACTION:
            out["adc_clipping"] = (f"no saturated samples ({100 * frac:.3f} % of I/Q at the "
                                   f"extreme < {100 * CLIP_FRACTION:.1f} %)")
    return out

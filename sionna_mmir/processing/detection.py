"""Target detection on range-azimuth maps.

:func:`strongest_return` finds the largest cell of a range-azimuth power map
inside a range window.
"""
from __future__ import annotations

import numpy as np

from ..errors import InputValueError


def strongest_return(ra, ranges, az, r_min: float, r_max: float):
    """The range-azimuth maximum within ``[r_min, r_max]``.

    Parameters
    ----------
    ra : numpy.ndarray
        Range-azimuth power ``[range, azimuth]``.
    ranges : numpy.ndarray
        Range bin centres [m].
    az : numpy.ndarray
        Azimuth bin centres [rad].
    r_min, r_max : float
        Range window [m].

    Returns
    -------
    tuple
        ``(range [m], azimuth [rad], value)``.
    """
    sel = (ranges >= r_min) & (ranges <= r_max)
    if not sel.any():
        raise InputValueError(f"no range bins between {r_min} and {r_max} m")
    sub = ra[sel]
    i, j = np.unravel_index(np.argmax(sub), sub.shape)
    return float(ranges[sel][i]), float(az[j]), float(sub[i, j])


#: Hann main-lobe half width [range bins]: a return this close to the leakage spills into it
LEAK_GUARD_BINS = 3
#: how far Tx -> Rx leakage reaches [m] (delays of a few cm of routing and the radome)
LEAK_MAX_RANGE = 0.35


def search_start(radar, r_min: float = 1.0, leak_max: float = LEAK_MAX_RANGE) -> float:
    """Nearest range [m] a target search may start at: past ``r_min`` and past the
    leakage's main lobe (``leak_max`` + :data:`LEAK_GUARD_BINS` range bins), so
    that leakage is never the strongest return when range bins are wide."""
    return max(float(r_min), float(leak_max) + LEAK_GUARD_BINS * float(radar.range_resolution))


def _local_peaks(p: np.ndarray, lo: int, hi: int, count: int) -> list:
    """Indices of the ``count`` largest local maxima of ``p`` in ``[lo, hi)``."""
    idx = [i for i in range(max(lo, 1), min(hi, len(p) - 1))
           if p[i] >= p[i - 1] and p[i] > p[i + 1]]
    return sorted(idx, key=lambda i: -p[i])[:count]


def _comb_members(peaks: list, power: np.ndarray, tol: float = 0.6, span_db: float = 6.0) -> set:
    """Peaks that lie on an equally spaced comb of >= 3 similar tones (``tol`` bins,
    powers within ``span_db``): interference from a tone generator or a switching supply."""
    members = set()
    for i in peaks:
        for j in peaks:
            d = j - i
            if d <= 1:
                continue
            run = [i, j]
            for step in (-1, 1):
                k = (i if step < 0 else j) + step * d
                while True:
                    near = [q for q in peaks if abs(q - k) <= tol]
                    if not near:
                        break
                    run.append(near[0])
                    k = near[0] + step * d
            if len(run) >= 3:
                db = 10 * np.log10(power[run] + 1e-30)
                if np.ptp(db) <= span_db:
                    members.update(run)
    return members


def classify_peaks(adc, radar, r_min: float = 1.0, r_max: float | None = None,
                   count: int = 12, aligned_min: float = 0.97, transient_cv: float = 0.5):
    """Range peaks of a raw capture, each tested for being interference rather than a return.

    Three tests per peak (range bin of the channel-summed Hann range spectrum):

    * **comb** -- it lies on an equally spaced comb of >= 3 tones of similar power;
    * **aligned** -- its phase is the same in every virtual channel (resultant length
      of the unit phasors >= ``aligned_min``): a tone coupled in after the antennas,
      which a return through a real, uncalibrated array never is unless on boresight;
    * **transient** -- it does not persist over chirps / frames (coefficient of
      variation of its magnitude > ``transient_cv``; untested with one chirp).

    A peak meeting two of the three is interference.

    Parameters
    ----------
    adc : numpy.ndarray
        Raw ADC ``[T, R, C, N]`` or ``[F, T, R, C, N]``.
    radar : RadarConfig
        The capture's radar.
    r_min, r_max : float
        Search window [m]; the start is moved past the leakage (:func:`search_start`).

    Returns
    -------
    list of dict
        Strongest first: ``range`` [m], ``bin``, ``power`` (linear), ``comb``,
        ``aligned``, ``transient`` (bool or None), ``interference`` (bool).
    """
    from .range_fft import range_fft

    x = np.asarray(adc)
    x = x[None] if x.ndim == 4 else x
    if x.ndim != 5:
        raise InputValueError(f"classify_peaks: adc must be [T, R, C, N] or [F, T, R, C, N], "
                              f"got shape {x.shape}")
    spec, ranges = range_fft(x, radar, "hann")                           # [F, T, R, C, K]
    half = len(ranges)                      # complex IF: every bin is a positive beat frequency
    mean = spec.mean(axis=(0, 3))                                       # [T, R, K] coherent
    power = np.mean(np.abs(mean) ** 2, axis=(0, 1))                     # [K]
    r_max = ranges[half - 1] if r_max is None else min(float(r_max), ranges[half - 1])
    lo = int(np.searchsorted(ranges, search_start(radar, r_min)))
    wrap = int(np.ceil(search_start(radar, 0.0) / radar.range_resolution))
    # the leakage's negative-frequency side wraps to the top of the complex-IF band
    hi = min(int(np.searchsorted(ranges, r_max, side="right")), half - wrap)
    peaks = _local_peaks(power, lo, hi, count)
    comb = _comb_members(_local_peaks(power, 1, half, 3 * count), power)
    mags = np.abs(spec).reshape(-1, *spec.shape[1:3], spec.shape[-1])   # [F*C, T, R, K]
    out = []
    for b in peaks:
        ph = mean[..., b] / np.maximum(np.abs(mean[..., b]), 1e-30)
        aligned = bool(np.abs(ph.mean()) >= aligned_min)
        transient = None
        if mags.shape[0] > 1:
            m = mags[..., b].mean(axis=(1, 2))
            transient = bool(m.std() / max(m.mean(), 1e-30) > transient_cv)
        flags = (b in comb) + aligned + bool(transient)
        out.append({"range": float(ranges[b]), "bin": int(b), "power": float(power[b]),
                    "comb": b in comb, "aligned": aligned, "transient": transient,
                    "interference": flags >= 2})
    return out


def find_target(adc, radar, r_min: float = 1.0, r_max: float | None = None, **tests):
    """The strongest return that is neither leakage nor interference.

    :func:`classify_peaks` picks the range; the azimuth is the range-azimuth
    map's maximum at that range.

    Returns
    -------
    tuple
        ``(range [m], azimuth [rad], peaks)``, ``peaks`` the classified list.

    Raises
    ------
    InputValueError
        No peak in the window, or every peak is interference.
    """
    from .imaging import range_azimuth

    x = np.asarray(adc)
    frame = x if x.ndim == 4 else x[0]
    peaks = classify_peaks(x, radar, r_min, r_max, **tests)
    real = [p for p in peaks if not p["interference"]]
    if not real:
        raise InputValueError(f"no target between {search_start(radar, r_min):.2f} m and "
                              f"{r_max if r_max is not None else radar.max_range:.2f} m "
                              f"({len(peaks)} peaks, all interference)")
    ra, ranges, az = range_azimuth(frame, radar)
    k = int(np.argmin(np.abs(ranges - real[0]["range"])))
    return real[0]["range"], float(az[int(np.argmax(ra[k]))]), peaks

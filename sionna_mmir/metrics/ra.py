"""Image metrics on range-azimuth (RA) maps (paper Table 2 and eq. 7).

Every metric compares two real maps ``a``, ``b`` of the same shape (any
number of dimensions; SSIM needs 2-D).  By default both are first min-max
normalised (:func:`minmax_normalize`), as in the paper, so that the data range
is 1 and absolute scale (radar gain, FFT scaling) does not matter.  Pass
``normalize=False`` to compare maps that are already on a common scale.

Inputs must be real and finite, with equal shapes; otherwise
:class:`~sionna_mmir.errors.InputValueError` is raised.
"""
from __future__ import annotations

import numpy as np
from scipy import ndimage

from ..errors import InputValueError


def _real_map(x, name, where):
    arr = np.asarray(x)
    if np.iscomplexobj(arr):
        raise InputValueError(f"{where}: {name} is complex; pass magnitudes (np.abs)")
    try:
        arr = arr.astype(np.float64)
    except (TypeError, ValueError):
        raise InputValueError(f"{where}: {name} is not numeric (dtype {arr.dtype})") from None
    if arr.size == 0:
        raise InputValueError(f"{where}: {name} is empty")
    if not np.all(np.isfinite(arr)):
        raise InputValueError(f"{where}: {name} holds NaN or Inf")
    return arr


def _pair(a, b, where, normalize):
    x = _real_map(a, "a", where)
    y = _real_map(b, "b", where)
    if x.shape != y.shape:
        raise InputValueError(f"{where}: shapes differ, a {x.shape} vs b {y.shape}")
    if normalize:
        x, y = minmax_normalize(x), minmax_normalize(y)
    return x, y


def minmax_normalize(x) -> np.ndarray:
    """``(x - min x) / (max x - min x)``, float64, values in ``[0, 1]``.

    A constant map (``max == min``) has no contrast and maps to all zeros.
    NaN / Inf or complex input raise InputValueError.
    """
    arr = _real_map(x, "x", "minmax_normalize")
    lo, hi = float(arr.min()), float(arr.max())
    if hi - lo <= 0.0:
        return np.zeros_like(arr)
    return (arr - lo) / (hi - lo)


def mse(a, b, normalize: bool = True) -> float:
    """Mean squared error ``mean((a~ - b~)^2)`` over all bins."""
    x, y = _pair(a, b, "mse", normalize)
    return float(np.mean((x - y) ** 2))


def ra_loss(a, b) -> float:
    """Paper eq. 7: ``L = 1/|G| sum_{(r,a) in G} (RA~_a(r,a) - RA~_b(r,a))^2``.

    ``RA~`` is the min-max normalised map, ``G`` the set of all bins; i.e.
    the MSE of the min-max normalised maps (``== rmse(a, b) ** 2``).
    """
    x, y = _pair(a, b, "ra_loss", True)
    return float(np.mean((x - y) ** 2))


def rmse(a, b, normalize: bool = True) -> float:
    """Root mean squared error ``sqrt(mean((a~ - b~)^2))``; lower is better."""
    x, y = _pair(a, b, "rmse", normalize)
    return float(np.sqrt(np.mean((x - y) ** 2)))


def psnr(a, b, normalize: bool = True, data_range: float = 1.0) -> float:
    """Peak signal-to-noise ratio ``10 log10(data_range^2 / MSE)`` [dB].

    With min-max normalisation ``data_range = 1``: ``PSNR = 10 log10(1 / MSE)``.
    Identical maps (MSE = 0) give ``inf``.
    """
    x, y = _pair(a, b, "psnr", normalize)
    m = float(np.mean((x - y) ** 2))
    if m == 0.0:
        return float("inf")
    return float(10.0 * np.log10(data_range ** 2 / m))


def pearson(a, b, normalize: bool = True) -> float:
    """Pearson correlation ``cov(a, b) / (std a std b)`` over all bins.

    Invariant to the (affine) min-max normalisation.  If either map is
    constant the correlation is undefined; this returns 1.0 when both maps
    are equal (after normalisation) and 0.0 otherwise.
    """
    x, y = _pair(a, b, "pearson", normalize)
    xc = x - x.mean()
    yc = y - y.mean()
    den = np.sqrt(np.sum(xc * xc) * np.sum(yc * yc))
    if den == 0.0:
        return 1.0 if np.array_equal(x, y) else 0.0
    return float(np.clip(np.sum(xc * yc) / den, -1.0, 1.0))


def ssim(a, b, normalize: bool = True, data_range: float = 1.0, sigma: float = 1.5,
         k1: float = 0.01, k2: float = 0.03, return_map: bool = False):
    """Structural similarity (Wang, Bovik, Sheikh, Simoncelli 2004), 2-D maps.

    With Gaussian-weighted local statistics (``sigma = 1.5``, 11 x 11 taps,
    weights summing to 1)::

        mu_a = G * a,  sigma_a^2 = G * a^2 - mu_a^2,  sigma_ab = G * (a b) - mu_a mu_b
        SSIM = (2 mu_a mu_b + C1)(2 sigma_ab + C2) / ((mu_a^2 + mu_b^2 + C1)(sigma_a^2 + sigma_b^2 + C2))
        C1 = (K1 L)^2, C2 = (K2 L)^2, K1 = 0.01, K2 = 0.03, L = data_range = 1

    The map is averaged over the pixels whose 11 x 11 window lies inside the
    image (Wang's "valid" windows; the whole image when it is smaller than
    the window, with reflected borders).  ``ssim(x, x) == 1``; symmetric;
    at most 1.  ``return_map=True`` also returns the full SSIM map.
    """
    x, y = _pair(a, b, "ssim", normalize)
    if x.ndim != 2:
        raise InputValueError(f"ssim: maps must be 2-D, got {x.ndim}-D")
    truncate = 3.5
    radius = int(truncate * sigma + 0.5)

    def filt(z):
        return ndimage.gaussian_filter(z, sigma, mode="reflect", truncate=truncate)

    c1 = (k1 * data_range) ** 2
    c2 = (k2 * data_range) ** 2
    mx, my = filt(x), filt(y)
    vx = filt(x * x) - mx * mx
    vy = filt(y * y) - my * my
    cxy = filt(x * y) - mx * my
    smap = ((2 * mx * my + c1) * (2 * cxy + c2)) / ((mx * mx + my * my + c1) * (vx + vy + c2))
    if all(s > 2 * radius for s in smap.shape):
        val = float(smap[radius:-radius, radius:-radius].mean())
    else:
        val = float(smap.mean())
    return (val, smap) if return_map else val

"""Azimuth / elevation FFTs over the virtual-array grid.

Convention (derived from the forward model ``exp(+j 2 pi f tau)``): the
virtual element at grid position ``m`` (lambda_d/2 units, ``lambda_d`` at
``radar.design_frequency = f_d``) sees a far target in direction
``u = (cos el cos az, cos el sin az, sin el)`` with the round-trip delay
shortened by ``m (lambda_d / 2) u_y / c``, i.e. with the phase
``-pi (f / f_d) m u_y``.  The spectrum that focuses it is::

    A(k) = sum_m w_m x_m exp(+j 2 pi m k / n_fft)        (= n_fft * ifft)

``fftshift``-ed, ``k = -n_fft/2 .. n_fft/2 - 1``, spatial frequency
``v = 2 k / n_fft`` (cycles per lambda_d/2 element, times 2), and

    sin(az) cos(el) = v * f_d / f_c         (azimuth FFT)
    sin(el)         = w * f_d / f_c         (elevation FFT)

with ``f_c = radar.center_frequency``.  Angles are returned as
``arcsin(clip(v f_d / f_c, -1, 1))`` [rad], increasing.  The azimuth axis is
thus the *direction sine* ``u_y`` mapped through arcsin: a target at true
azimuth ``az`` and elevation ``el`` appears at ``arcsin(sin az cos el)``,
which equals ``az`` only at ``el = 0``.

Windows (unit coherent gain) span the filled extent of the grid along the
transformed axis (``support``); cells outside it are empty (zero) anyway.
"""
from __future__ import annotations

import numpy as np

from ..errors import InputValueError
from ..radar.config import RadarConfig
from .windows import get_window


def spatial_frequencies(n_fft: int) -> np.ndarray:
    """``v = 2 k / n_fft`` for ``k = -n_fft/2 .. n_fft/2 - 1`` (fftshift order), ``[n_fft]``."""
    n_fft = int(n_fft)
    return 2.0 * (np.arange(n_fft) - n_fft // 2) / n_fft


def angles_from_spatial_frequency(v, radar: RadarConfig) -> np.ndarray:
    """``arcsin(clip(v f_d / f_c, -1, 1))`` [rad] for spatial frequencies ``v``."""
    s = np.asarray(v, dtype=np.float64) * radar.design_frequency / radar.center_frequency
    return np.arcsin(np.clip(s, -1.0, 1.0))


def angle_fft(x, axis: int, window="hann", n_fft: int = 128, support=None) -> np.ndarray:
    """``A(k) = sum_m w_m x_m exp(+j 2 pi m k / n_fft)`` along ``axis``, fftshifted.

    Parameters
    ----------
    x : array_like
        Complex array, grid cells ``m = 0 .. n-1`` on ``axis``.
    axis : int
        The axis to transform.
    window : str or None, optional
        Window name (unit coherent gain) or ``None``.
    n_fft : int, optional
        FFT length (>= n), zero padded.
    support : tuple of int, optional
        ``(start, stop)`` cells the window spans (default all).

    Returns
    -------
    numpy.ndarray
        Complex ``x.shape`` with ``axis`` of length ``n_fft``; bin ``i`` has
        spatial frequency :func:`spatial_frequencies` ``(n_fft)[i]``.
    """
    x = np.asarray(x)
    if not np.iscomplexobj(x):
        x = x.astype(np.complex64)
    ax = axis % x.ndim
    n = x.shape[ax]
    n_fft = int(n_fft)
    if n_fft < n:
        raise InputValueError(f"angle_fft: n_fft ({n_fft}) must be >= the {n} grid cells "
                              f"on axis {axis}")
    w = _axis_window(x, ax, window, support)
    spec = np.fft.ifft(x * w, n_fft, axis=ax, norm="forward")
    return np.fft.fftshift(spec, axes=ax)


def _axis_window(x, ax: int, window, support) -> np.ndarray:
    """The window of :func:`angle_fft` along ``ax``, shaped to broadcast against ``x``."""
    n = x.shape[ax]
    start, stop = (0, n) if support is None else (int(support[0]), int(support[1]))
    if not 0 <= start < stop <= n:
        raise InputValueError(f"angle_fft: support {support} outside 0..{n}")
    w = np.zeros(n, dtype=x.real.dtype)
    w[start:stop] = get_window(window, stop - start)
    shape = [1] * x.ndim
    shape[ax] = n
    return w.reshape(shape)


def angle_fft_2d(x, axes, windows, n_ffts, supports=(None, None), workers: int = -1):
    """:func:`angle_fft` along two axes at once, as one multi-threaded 2-D transform.

    The same spectrum as ``angle_fft(angle_fft(x, axes[0], ...), axes[1], ...)``
    (the transforms are separable), computed by ``scipy.fft.ifft2`` with
    ``workers`` threads in the input's precision (complex64 stays complex64).

    Parameters
    ----------
    x : array_like
        Complex array.
    axes : tuple of int
        The two axes to transform.
    windows : tuple
        Window names (or ``None``) per axis.
    n_ffts : tuple of int
        FFT lengths per axis (>= the axis lengths).
    supports : tuple, optional
        ``(start, stop)`` per axis, or ``None`` (all cells).
    workers : int, optional
        Threads of ``scipy.fft`` (-1: all cores).

    Returns
    -------
    numpy.ndarray
        Complex, ``x.shape`` with ``axes`` of lengths ``n_ffts``, fftshifted on both.
    """
    import scipy.fft

    x = np.asarray(x)
    if not np.iscomplexobj(x):
        x = x.astype(np.complex64)
    axes = tuple(a % x.ndim for a in axes)
    for ax, n_fft in zip(axes, n_ffts):
        if int(n_fft) < x.shape[ax]:
            raise InputValueError(f"angle_fft: n_fft ({n_fft}) must be >= the {x.shape[ax]} "
                                  f"grid cells on axis {ax}")
    w = _axis_window(x, axes[0], windows[0], supports[0]) * \
        _axis_window(x, axes[1], windows[1], supports[1])
    spec = scipy.fft.ifft2(x * w, s=tuple(int(n) for n in n_ffts), axes=axes, norm="forward",
                           workers=workers)
    return np.fft.fftshift(spec, axes=axes)


def azimuth_fft(x, radar: RadarConfig, axis: int = 0, window="hann", n_fft: int = 128,
                support=None):
    """Azimuth FFT of grid columns on ``axis``.

    Returns ``(spectrum, azimuths_rad [n_fft])``, azimuth =
    ``arcsin(clip(v f_d / f_c))`` (:mod:`.angle_fft` convention).
    """
    spec = angle_fft(x, axis, window, n_fft, support)
    return spec, angles_from_spatial_frequency(spatial_frequencies(n_fft), radar)


def elevation_fft(x, radar: RadarConfig, axis: int = 0, window="hann", n_fft: int = 128,
                  support=None):
    """Elevation FFT of grid rows on ``axis``.

    Returns ``(spectrum, elevations_rad [n_fft])``, elevation =
    ``arcsin(clip(w f_d / f_c))``.
    """
    spec = angle_fft(x, axis, window, n_fft, support)
    return spec, angles_from_spatial_frequency(spatial_frequencies(n_fft), radar)

"""Differentiable range-azimuth maps and the paper's RA loss (eq. 7) in Dr.Jit.

Range-azimuth processing (:func:`~.imaging.range_azimuth`) is, up to the final
magnitude, a *linear* map ``L`` of the complex ADC ``x``::

    doppler='mean'         RA[r, a] = | z[a, r] |,          z = L x   [A, R]
    doppler='noncoherent'  RA[r, a] = sum_d | z[a, d, r] |,  z = L x   [A, D, R]

``L`` chains: chirp mean (or window + Doppler FFT + fftshift + TDM phase),
range window + FFT (+ bin reversal for a negative slope), averaging scatter
onto the azimuth row, azimuth window + unnormalised inverse DFT + fftshift.
:func:`range_azimuth_drjit` wraps this as a ``dr.CustomOp`` (one node of the
Dr.Jit AD graph, like :mod:`sionna_mmir.fmcw.drjit_op`):

* **forward value**: the NumPy pipeline itself (the same stage functions as
  :func:`~.imaging.range_azimuth`, complex64 for the float32 Dr.Jit input), so
  the map equals ``range_azimuth`` on the same ADC;
* **VJP** (reverse mode): with ``u = z / |z|`` and ``G = dLoss / dRA``,
  ``dLoss/d Re x + j dLoss/d Im x = L^H (G u)``.  ``L^H`` is assembled stage
  by stage from exact adjoints (:class:`RALinearMap.adjoint`): the adjoint of
  an unnormalised forward DFT is the unnormalised inverse DFT and vice versa,
  zero padding becomes truncation, ``fftshift`` becomes ``ifftshift``, the
  averaging scatter becomes a gather divided by the cell counts, the chirp
  mean a broadcast divided by the number of chirps, and phase factors are
  conjugated.  No finite differences;
* **JVP** (forward mode): ``dRA = Re(conj(u) L dx)`` (summed over Doppler
  bins in ``'noncoherent'`` mode).

At ``|z| = 0`` the magnitude is not differentiable; there ``u = 0`` is used
(the minimum-norm subgradient), so such bins pass no gradient.  The adjoint
chain runs in complex128.

:func:`ra_loss_drjit` is paper eq. 7 (:func:`sionna_mmir.metrics.ra.ra_loss`):
the mean squared difference of the min-max normalised maps, built from
Dr.Jit operations; :func:`ra_loss_from_adc` composes the two.
"""
from __future__ import annotations

import inspect

import numpy as np

from ..errors import ConfigError, InputValueError
from ..radar.config import RadarConfig
from .angle_fft import angle_fft
from .doppler_fft import doppler_bins_hz, doppler_fft
from .imaging import _DOPPLER_MODES, range_azimuth
from .range_fft import range_fft
from .virtual_array import VirtualArray
from .windows import get_window

__all__ = ["RALinearMap", "range_azimuth_drjit", "ra_loss_drjit", "ra_loss_from_adc"]

_RA_OPTIONS = tuple(p for p in inspect.signature(range_azimuth).parameters
                    if p not in ("adc", "radar"))


def _ra_settings(kwargs: dict, where: str) -> dict:
    """``range_azimuth``'s keyword options with its defaults filled in."""
    unknown = sorted(set(kwargs) - set(_RA_OPTIONS))
    if unknown:
        raise ConfigError(f"{where}: unknown option(s) {unknown}; range_azimuth accepts "
                          f"{list(_RA_OPTIONS)}")
    bound = inspect.signature(range_azimuth).bind(None, None, **kwargs)
    bound.apply_defaults()
    opts = {k: v for k, v in bound.arguments.items() if k in _RA_OPTIONS}
    if opts["doppler"] not in _DOPPLER_MODES:
        raise ConfigError(f"{where}: doppler must be one of {_DOPPLER_MODES}, "
                          f"got {opts['doppler']!r}")
    return opts


class RALinearMap:
    """The linear part ``z = L x`` of :func:`~.imaging.range_azimuth` and its adjoint.

    ``apply(x)``: complex ADC ``[tx, rx, chirp, sample]`` -> ``z`` complex
    ``[n_azimuth, n_range]`` (``'mean'``) or ``[n_azimuth, num_chirps,
    n_range]`` (``'noncoherent'``), fftshifted azimuth bins; same dtype rules
    as the NumPy stages (complex64 in -> complex64 out).
    ``adjoint(g)``: ``L^H g``, complex128 ``[tx, rx, chirp, sample]``.
    ``magnitude(z)``: the RA map ``[n_range, n_azimuth]`` from ``z``.

    Parameters
    ----------
    radar : RadarConfig
        Waveform and layout.
    **kwargs
        ``range_window``, ``azimuth_window``, ``doppler_window``,
        ``n_range``, ``n_azimuth``, ``doppler``, ``tdm_compensation``,
        ``virtual_array``: as :func:`~.imaging.range_azimuth` (same defaults:
        ``'hann'``, ``n_range = num_samples``, ``n_azimuth = 128``,
        ``doppler = 'mean'``, ``tdm_compensation = True``).
    """

    def __init__(self, radar: RadarConfig, **kwargs):
        opts = _ra_settings(kwargs, "RALinearMap")
        self.radar = radar
        self.opts = opts
        self.mode = opts["doppler"]
        self.va = VirtualArray(radar) if opts["virtual_array"] is None else opts["virtual_array"]
        K, L = radar.num_samples, radar.num_chirps
        self.n_range = K if opts["n_range"] is None else int(opts["n_range"])
        self.n_azimuth = int(opts["n_azimuth"])
        if self.n_range < K:
            raise InputValueError(f"RALinearMap: n_range ({self.n_range}) must be >= "
                                  f"num_samples ({K})")
        if self.n_azimuth < self.va.n_az:
            raise InputValueError(f"RALinearMap: n_azimuth ({self.n_azimuth}) must be >= the "
                                  f"{self.va.n_az} azimuth cells of the virtual array")
        self.w_range = get_window(opts["range_window"], K)                        # [K]
        start, stop = self.va.row_support
        self.w_az = np.zeros(self.va.n_az)
        self.w_az[start:stop] = get_window(opts["azimuth_window"], stop - start)  # [n_az]
        self.w_doppler = get_window(opts["doppler_window"], L)                    # [L]
        self.tdm = (self.va.tdm_phase(doppler_bins_hz(radar))                     # [tx, D]
                    if self.mode == "noncoherent" and opts["tdm_compensation"] else None)
        row = (self.va.el_index == self.va.azimuth_row).ravel()                   # [tx*rx]
        self.row_index = np.flatnonzero(row)
        self.row_cells = self.va.az_index.ravel()[row]
        cnt = np.bincount(self.row_cells, minlength=self.va.n_az)
        self.row_scale = 1.0 / cnt[self.row_cells]                                # [n_row]

    # ----------------------------------------------------------- forward
    def apply(self, x) -> np.ndarray:
        """``z = L x`` with the NumPy stages of :func:`~.imaging.range_azimuth`."""
        o, va, radar = self.opts, self.va, self.radar
        if self.mode == "mean":
            rfft, _ = range_fft(x.mean(axis=2), radar, o["range_window"], o["n_range"])
            row = va.azimuth_row_channels(rfft)                                   # [n_az, R]
            return angle_fft(row, 0, o["azimuth_window"], o["n_azimuth"], va.row_support)
        rfft, _ = range_fft(x, radar, o["range_window"], o["n_range"])           # [tx, rx, L, R]
        dspec, _ = doppler_fft(rfft, radar, o["doppler_window"])                  # [tx, rx, D, R]
        if self.tdm is not None:
            dspec = va.tdm_compensate(dspec, doppler_bins_hz(radar), doppler_axis=2)
        row = va.azimuth_row_channels(dspec)                                      # [n_az, D, R]
        return angle_fft(row, 0, o["azimuth_window"], o["n_azimuth"], va.row_support)

    def magnitude(self, z) -> np.ndarray:
        """RA map ``[n_range, n_azimuth]`` from ``z`` (sum over Doppler bins if any)."""
        mag = np.abs(z)
        if self.mode != "mean":
            mag = mag.sum(axis=1)
        return np.ascontiguousarray(mag.T)

    def reduce(self, per_bin) -> np.ndarray:
        """Like :meth:`magnitude` for a real per-``z``-bin quantity (no abs)."""
        v = per_bin if self.mode == "mean" else per_bin.sum(axis=1)
        return np.ascontiguousarray(v.T)

    def expand(self, g) -> np.ndarray:
        """Adjoint of :meth:`reduce`: ``[n_range, n_azimuth]`` -> shape of ``z``."""
        gt = np.asarray(g).T
        if self.mode == "mean":
            return gt
        return np.broadcast_to(gt[:, None, :], (gt.shape[0], self.radar.num_chirps, gt.shape[1]))

    # ----------------------------------------------------------- adjoint
    def adjoint(self, g) -> np.ndarray:
        """``L^H g`` for ``g`` of the shape of ``z``; complex128 ``[tx, rx, chirp, sample]``."""
        radar, va = self.radar, self.va
        T, Rx, L, K = radar.adc_shape
        g = np.asarray(g, dtype=np.complex128)
        n_az = va.n_az
        # angle FFT: fftshift -> ifftshift; unnormalised inverse DFT (zero padded)
        # -> unnormalised forward DFT, truncated; then the (real) window.
        g = np.fft.ifftshift(g, axes=0)
        g = np.fft.fft(g, axis=0)[:n_az]
        g = g * self.w_az.reshape((n_az,) + (1,) * (g.ndim - 1))
        # averaging scatter onto the azimuth row -> gather / counts; other pairs 0.
        flat = np.zeros((T * Rx,) + g.shape[1:], np.complex128)
        flat[self.row_index] = g[self.row_cells] * self.row_scale.reshape(
            (-1,) + (1,) * (g.ndim - 1))
        g = flat.reshape((T, Rx) + g.shape[1:])                # [tx, rx, (D,) R]
        if self.mode != "mean":
            if self.tdm is not None:                           # phase -> conjugate phase
                g = g * np.conj(self.tdm)[:, None, :, None]
            # Doppler: fftshift -> ifftshift; forward DFT -> unnormalised inverse DFT
            g = np.fft.ifftshift(g, axes=2)
            g = np.fft.ifft(g, axis=2, norm="forward")[:, :, :L]
            g = g * self.w_doppler[:, None]                    # [tx, rx, L, R]
        # range FFT: bin reversal (negative slope) is an involution -> itself;
        # forward DFT (zero padded) -> unnormalised inverse DFT, truncated; window.
        n_r = self.n_range
        if radar.slope < 0:
            g = g[..., (-np.arange(n_r)) % n_r]
        g = np.fft.ifft(g, axis=-1, norm="forward")[..., :K] * self.w_range
        if self.mode == "mean":                                # chirp mean -> broadcast / L
            g = np.broadcast_to((g / L)[:, :, None, :], (T, Rx, L, K))
        return np.ascontiguousarray(g)


# --------------------------------------------------------------------- Dr.Jit
def _make_op():
    import drjit as dr
    import mitsuba as mi

    class RangeAzimuthOp(dr.CustomOp):
        """Custom AD node: (adc_re, adc_im) flat -> RA magnitudes flat ``[R * A]``."""

        def eval(self, re, im, lin=None):
            self.lin = lin
            shape = lin.radar.adc_shape
            x = np.empty(shape, np.complex64)
            x.real = np.asarray(re, dtype=np.float32).reshape(shape)
            x.imag = np.asarray(im, dtype=np.float32).reshape(shape)
            z = lin.apply(x)
            ra = lin.magnitude(z)                               # as range_azimuth
            zz = z.astype(np.complex128)
            amag = np.abs(zz)
            self.u = np.where(amag > 0, zz / np.where(amag > 0, amag, 1.0), 0.0)   # z / |z|
            self.ra_shape = ra.shape
            return mi.Float(ra.astype(np.float32).ravel())

        def forward(self):
            shape = self.lin.radar.adc_shape
            dx = (np.asarray(self.grad_in("re"), np.float64).reshape(shape)
                  + 1j * np.asarray(self.grad_in("im"), np.float64).reshape(shape))
            dz = self.lin.apply(dx)
            dra = self.lin.reduce(np.real(np.conj(self.u) * dz))
            self.set_grad_out(mi.Float(dra.astype(np.float32).ravel()))

        def backward(self):
            g = np.asarray(self.grad_out(), np.float64).reshape(self.ra_shape)
            gx = self.lin.adjoint(self.lin.expand(g) * self.u)
            self.set_grad_in("re", mi.Float(np.ascontiguousarray(gx.real, np.float32).ravel()))
            self.set_grad_in("im", mi.Float(np.ascontiguousarray(gx.imag, np.float32).ravel()))

        def name(self):
            return "RangeAzimuth"

    return RangeAzimuthOp


_OP = None


def _drjit():
    from ..utils.backend import init_backend

    init_backend()
    import drjit as dr
    import mitsuba as mi
    return dr, mi


def _tensor_shape(t, name, where):
    import mitsuba as mi

    if not isinstance(t, mi.TensorXf):
        raise InputValueError(f"{where}: '{name}' must be a mi.TensorXf, got "
                              f"{type(t).__module__}.{type(t).__name__}")
    return tuple(t.shape)


def _split_adc(adc, radar, where):
    """Return (re, im) TensorXf after checking shape and finiteness."""
    import drjit as dr

    if not (isinstance(adc, (tuple, list)) and len(adc) == 2):
        raise InputValueError(f"{where}: adc must be a DrAdc or a (real, imag) pair of "
                              f"mi.TensorXf, got {type(adc).__name__}")
    re, im = adc
    want = tuple(radar.adc_shape)
    for t, name in ((re, "adc.real"), (im, "adc.imag")):
        shape = _tensor_shape(t, name, where)
        if shape != want:
            raise InputValueError(
                f"{where}: {name} must be [tx, rx, chirp, sample] = {want} for radar "
                f"'{radar.name}', got shape {shape}")
        if not np.all(np.isfinite(np.asarray(dr.detach(t).array))):
            raise InputValueError(f"{where}: {name} holds NaN or Inf samples")
    return re, im


def range_azimuth_drjit(adc, radar: RadarConfig, **kwargs):
    """Differentiable range-azimuth magnitude map (Dr.Jit custom op).

    The magnitudes of ``range_azimuth(adc, radar, **kwargs)[0]`` (computed by
    the same NumPy stages on the float32 ADC), with analytic reverse- and
    forward-mode derivatives w.r.t. ``adc.real`` and ``adc.imag`` (module
    docstring).

    Parameters
    ----------
    adc : DrAdc or tuple of mi.TensorXf
        :class:`~sionna_mmir.fmcw.synthesize.DrAdc` or a ``(real, imag)`` pair
        of ``mi.TensorXf``, each ``[tx, rx, chirp, sample]`` (=
        ``radar.adc_shape``), ADC units (as synthesised / captured).
    radar : RadarConfig
        Waveform and layout.
    **kwargs
        Options of :func:`~.imaging.range_azimuth` (``range_window``,
        ``azimuth_window``, ``doppler_window``, ``n_range``, ``n_azimuth``,
        ``doppler`` = ``'mean'`` or ``'noncoherent'``, ``tdm_compensation``,
        ``virtual_array``), same defaults.

    Returns
    -------
    mi.TensorXf
        ``[n_range, n_azimuth]``: rows = range bins ``ranges_m``, columns =
        azimuth bins ``azimuths_rad`` of ``range_azimuth`` (increasing,
        positive = left).

    Raises
    ------
    InputValueError
        Wrong ADC shape, NaN / Inf samples or non-tensor input.
    ConfigError
        An unknown option or ``doppler`` mode.
    """
    global _OP
    dr, mi = _drjit()
    where = "range_azimuth_drjit"
    lin = RALinearMap(radar, **kwargs)
    re, im = _split_adc(adc, radar, where)
    if _OP is None:
        _OP = _make_op()
    out = dr.custom(_OP, re.array, im.array, lin=lin)
    return mi.TensorXf(out, (lin.n_range, lin.n_azimuth))


def _target_map(ra_target, shape, where):
    import drjit as dr
    import mitsuba as mi

    if isinstance(ra_target, mi.TensorXf):
        y = np.asarray(dr.detach(ra_target).array, dtype=np.float64).reshape(ra_target.shape)
    else:
        from ..metrics.ra import _real_map

        y = _real_map(ra_target, "ra_target", where)
    if y.shape != tuple(shape):
        raise InputValueError(f"{where}: shapes differ, ra_render {tuple(shape)} vs "
                              f"ra_target {y.shape}")
    if not np.all(np.isfinite(y)):
        raise InputValueError(f"{where}: ra_target holds NaN or Inf")
    return y


def ra_loss_drjit(ra_render, ra_target):
    """Paper eq. 7 on Dr.Jit: ``mean((minmax(ra_render) - minmax(ra_target))^2)``.

    Equal (to float32 precision) to :func:`sionna_mmir.metrics.ra.ra_loss`:
    ``minmax(x) = (x - min x) / (max x - min x)``, no epsilon; a constant map
    normalises to all zeros (and then passes no gradient).

    Gradients: the minimum and maximum are taken at the bins ``argmin`` /
    ``argmax`` of the detached render and gathered differentiably, so those
    two bins receive the derivative of the normalisation
    (``d/d min`` and ``d/d max`` summed over every bin) besides their own
    term.  This is the exact gradient wherever the extremes are unique.  On
    ties the first extreme bin (NumPy's ``argmin`` / ``argmax`` order, row
    major) takes the whole normalisation derivative: a one-sided derivative,
    exact for perturbations that keep that bin extreme.

    Parameters
    ----------
    ra_render : mi.TensorXf
        RA magnitudes (e.g. ``[n_range, n_azimuth]`` from
        :func:`range_azimuth_drjit`), any units; differentiable.
    ra_target : numpy.ndarray or mi.TensorXf
        Real map of the same shape (detached: no gradient flows into it).

    Returns
    -------
    mi.Float
        The scalar loss (one entry, dimensionless).

    Raises
    ------
    InputValueError
        NaN / Inf, complex or mismatched shapes.
    """
    dr, mi = _drjit()
    where = "ra_loss_drjit"
    shape = _tensor_shape(ra_render, "ra_render", where)
    if len(shape) == 0 or int(np.prod(shape)) == 0:
        raise InputValueError(f"{where}: ra_render is empty")
    flat = ra_render.array
    xv = np.asarray(dr.detach(flat), dtype=np.float64)
    if not np.all(np.isfinite(xv)):
        raise InputValueError(f"{where}: ra_render holds NaN or Inf")
    y = _target_map(ra_target, shape, where)
    lo_t, hi_t = float(y.min()), float(y.max())
    yn = (y - lo_t) / (hi_t - lo_t) if hi_t - lo_t > 0 else np.zeros_like(y)
    yt = mi.Float(yn.astype(np.float32).ravel())
    n = xv.size
    i_lo, i_hi = int(np.argmin(xv)), int(np.argmax(xv))
    if xv[i_hi] - xv[i_lo] > 0:
        lo = dr.gather(mi.Float, flat, mi.UInt32(i_lo))
        hi = dr.gather(mi.Float, flat, mi.UInt32(i_hi))
        xt = (flat - lo) / (hi - lo)
    else:                      # constant map: zeros, kept in the graph with zero gradient
        xt = (flat - dr.detach(flat)) * dr.opaque(mi.Float, 0.0, 1)
    d = xt - yt
    return dr.sum(d * d) / n


def ra_loss_from_adc(adc, radar: RadarConfig, ra_target, **kwargs):
    """``ra_loss_drjit(range_azimuth_drjit(adc, radar, **kwargs), ra_target)``.

    Parameters
    ----------
    adc : DrAdc or tuple of mi.TensorXf
        :class:`~sionna_mmir.fmcw.synthesize.DrAdc` or ``(re, im)``
        ``mi.TensorXf`` ``[tx, rx, chirp, sample]``.
    radar : RadarConfig
        Waveform and layout.
    ra_target : numpy.ndarray or mi.TensorXf
        ``[n_range, n_azimuth]`` target map (NumPy or detached
        ``mi.TensorXf``), e.g. ``range_azimuth`` of a capture.
    **kwargs
        :func:`~.imaging.range_azimuth` options.

    Returns
    -------
    mi.Float
        The scalar loss (paper eq. 7), differentiable w.r.t. the ADC and
        whatever produced it.
    """
    return ra_loss_drjit(range_azimuth_drjit(adc, radar, **kwargs), ra_target)

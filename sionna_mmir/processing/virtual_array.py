"""TDM-MIMO virtual array: grid indices, azimuth row, scattering, TDM phase.

Every (tx, rx) pair is a virtual element at ``tx + rx``.  In units of
lambda/2 at ``radar.design_frequency`` (:meth:`RadarConfig.virtual_grid`) the
positions are shifted so that the smallest azimuth and elevation are 0 and
rounded to integers; a position further than ``tol`` (1e-3) from an integer
raises :class:`~sionna_mmir.errors.ConfigError` (half-integer layouts such as
the dense array's are fine: only differences matter).  The grid is
``[n_el, n_az]`` with ``el`` the row (elevation index, increasing upwards,
``+z``) and ``az`` the column (azimuth index, increasing to the left, ``+y``).

* Several pairs on the same cell (the cascade's 192 channels on 136 cells)
  are averaged; empty cells are zero.
* The *azimuth row* used for range-azimuth maps is the elevation row holding
  the most distinct azimuth positions (ties: the row nearest the middle of the
  elevation extent).  Cascade: row 0 with the 86 positions 0..85; AWR1843:
  row 0 with 8 positions; dense arrays: a middle row.
* TDM Doppler compensation: Tx ``i`` fires in slot ``s_i`` of each loop
  (``radar.tdm_order``), ``s_i T_chirp`` after the loop's first Tx.  A target
  of Doppler frequency ``f_D`` therefore adds the phase
  ``+2 pi f_D s_i T_chirp`` to every channel of Tx ``i`` (the forward model's
  phase grows with delay, :mod:`.doppler_fft`).  :meth:`VirtualArray.tdm_compensate`
  multiplies by ``exp(-j 2 pi f_D s_i T_chirp)`` per Doppler bin, before the
  angle FFT.
"""
from __future__ import annotations

import numpy as np

from ..errors import ConfigError, InputValueError
from ..radar.config import RadarConfig


class VirtualArray:
    """Virtual-array geometry of a :class:`~sionna_mmir.radar.RadarConfig`.

    Parameters
    ----------
    radar : RadarConfig
        The radar whose Tx x Rx pairs form the virtual array.
    tol : float, optional
        Tolerance [half-wavelengths] of the grid positions.

    Attributes
    ----------
    az_index : numpy.ndarray
        int ``[tx, rx]`` azimuth column of each pair.
    el_index : numpy.ndarray
        int ``[tx, rx]`` elevation row of each pair.
    n_az, n_el : int
        Grid size (columns, rows).
    counts : numpy.ndarray
        int ``[n_el, n_az]`` pairs per cell (0 = empty).
    azimuth_row : int
        Elevation row used for range-azimuth maps.
    row_support : tuple of int
        ``(first, last + 1)`` filled columns of that row.
    tx_slot : numpy.ndarray
        int ``[tx]`` TDM slot of each Tx within a loop.
    """

    def __init__(self, radar: RadarConfig, tol: float = 1e-3):
        self.radar = radar
        grid = np.asarray(radar.virtual_grid(), dtype=np.float64)       # [tx, rx, 2]
        rel = grid - grid.reshape(-1, 2).min(axis=0)
        idx = np.rint(rel)
        err = np.abs(rel - idx)
        if np.any(err > tol):
            t, r, c = np.unravel_index(int(np.argmax(err)), err.shape)
            raise ConfigError(
                f"VirtualArray ({radar.name}): virtual element (tx {t}, rx {r}) is at "
                f"{'azimuth' if c == 0 else 'elevation'} {grid[t, r, c]:.6f} lambda/2 "
                f"(design frequency {radar.design_frequency / 1e9:.3f} GHz), not on a "
                f"lambda/2 grid (tolerance {tol})")
        idx = idx.astype(np.int64)
        self.az_index = idx[..., 0]
        self.el_index = idx[..., 1]
        self.n_az = int(self.az_index.max()) + 1
        self.n_el = int(self.el_index.max()) + 1
        self.counts = np.zeros((self.n_el, self.n_az), dtype=np.int64)
        np.add.at(self.counts, (self.el_index.ravel(), self.az_index.ravel()), 1)
        distinct = (self.counts > 0).sum(axis=1)
        best = np.flatnonzero(distinct == distinct.max())
        mid = (self.n_el - 1) / 2.0
        self.azimuth_row = int(best[np.argmin(np.abs(best - mid))])
        cols = np.flatnonzero(self.counts[self.azimuth_row] > 0)
        self.row_support = (int(cols[0]), int(cols[-1]) + 1)
        self.tx_slot = np.empty(radar.num_tx, dtype=np.int64)
        self.tx_slot[list(radar.tdm_order)] = np.arange(radar.num_tx)
        self._cell = (self.el_index * self.n_az + self.az_index).ravel()     # [tx*rx]
        self._row_mask = (self.el_index == self.azimuth_row).ravel()

    # ------------------------------------------------------------ helpers
    @property
    def filled(self) -> np.ndarray:
        """bool ``[n_el, n_az]``: cells holding at least one pair."""
        return self.counts > 0

    @property
    def num_unique(self) -> int:
        """Number of distinct virtual positions (filled cells)."""
        return int(np.count_nonzero(self.counts))

    def _channels(self, x, name):
        x = np.asarray(x)
        r = self.radar
        if x.ndim < 2 or x.shape[:2] != (r.num_tx, r.num_rx):
            raise InputValueError(f"VirtualArray.{name}: channels must be [tx={r.num_tx}, "
                                  f"rx={r.num_rx}, ...], got shape {x.shape}")
        if not np.iscomplexobj(x):
            x = x.astype(np.complex64)
        return x.reshape((r.num_tx * r.num_rx,) + x.shape[2:])

    @staticmethod
    def _scatter(flat, cells, n_cells):
        """Average rows of ``flat [n, ...]`` onto ``n_cells`` cells (``cells [n]``)."""
        out = np.zeros((n_cells,) + flat.shape[1:], dtype=flat.dtype)
        cnt = np.bincount(cells, minlength=n_cells)
        if np.all(cnt <= 1):
            out[cells] = flat
            return out
        np.add.at(out, cells, flat)
        scale = np.where(cnt > 0, 1.0 / np.maximum(cnt, 1), 0.0).astype(flat.real.dtype)
        out *= scale.reshape((n_cells,) + (1,) * (flat.ndim - 1))
        return out

    def phase_centre(self, azimuth_row_only: bool = True) -> np.ndarray:
        """Mean two-way phase centre ``(tx + rx) / 2`` of the pairs used [m], ``[3]``.

        Angles of an FFT beamformer are directions seen from the aperture, not
        from the radar origin.  The cascade's azimuth row is centred about
        4.3 cm to the left of its origin, so a target at 3 m and 10 deg from
        the origin appears at ~9.2 deg (plus a near-field bias of a few tenths
        of a degree below ~14 m).  Place targets (or convert detections) about
        this point to compare angles.
        """
        v = 0.5 * self.radar.virtual_positions()
        if azimuth_row_only:
            v = v[self.el_index == self.azimuth_row]
        return v.reshape(-1, 3).mean(axis=0)

    # ----------------------------------------------------------- scatter
    def to_grid(self, channels) -> np.ndarray:
        """Scatter ``[tx, rx, ...]`` onto the grid ``[n_el, n_az, ...]``.

        Duplicated positions are averaged, empty cells are zero.
        """
        flat = self._channels(channels, "to_grid")
        out = self._scatter(flat, self._cell, self.n_el * self.n_az)
        return out.reshape((self.n_el, self.n_az) + flat.shape[1:])

    def azimuth_row_channels(self, channels) -> np.ndarray:
        """The azimuth row only: ``[tx, rx, ...]`` -> ``[n_az, ...]`` (averaged, zeros if empty)."""
        flat = self._channels(channels, "azimuth_row_channels")
        sel = flat[self._row_mask]
        cells = self.az_index.ravel()[self._row_mask]
        return self._scatter(sel, cells, self.n_az)

    # ---------------------------------------------------------------- TDM
    def tdm_phase(self, doppler_hz) -> np.ndarray:
        """Compensation phasors ``exp(-j 2 pi f_D s_i T_chirp)``, complex128 ``[tx, n_doppler]``."""
        f = np.asarray(doppler_hz, dtype=np.float64).reshape(-1)
        return np.exp(-2j * np.pi * self.tx_slot[:, None] * self.radar.chirp_period * f[None, :])

    def tdm_compensate(self, spectrum, doppler_hz, doppler_axis: int = 2) -> np.ndarray:
        """Remove the Tx-slot Doppler phase from a Doppler spectrum.

        Parameters
        ----------
        spectrum : numpy.ndarray
            Complex ``[tx, rx, ...]`` with the Doppler bins on ``doppler_axis``
            (default 2: ``[tx, rx, doppler, range]``).
        doppler_hz : array_like
            ``[n_doppler]`` Doppler frequency of each bin [Hz]
            (:func:`~.doppler_fft.doppler_bins_hz`).
        doppler_axis : int, optional
            Axis of the Doppler bins.

        Returns
        -------
        numpy.ndarray
            The spectrum multiplied by ``exp(-j 2 pi f_D s_i T_chirp)`` (same
            shape and dtype).
        """
        x = np.asarray(spectrum)
        r = self.radar
        ax = doppler_axis % x.ndim
        f = np.asarray(doppler_hz).reshape(-1)
        if x.shape[:2] != (r.num_tx, r.num_rx) or ax < 2 or x.shape[ax] != f.size:
            raise InputValueError(
                f"VirtualArray.tdm_compensate: spectrum {x.shape} must be [tx={r.num_tx}, "
                f"rx={r.num_rx}, ...] with {f.size} Doppler bins on axis {doppler_axis}")
        ph = self.tdm_phase(f).astype(x.dtype if np.iscomplexobj(x) else np.complex64)
        shape = [1] * x.ndim
        shape[0], shape[ax] = r.num_tx, f.size
        return x * ph.reshape(shape)

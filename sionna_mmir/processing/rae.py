"""Range-azimuth-elevation (RAE) power cubes for 3-D occupancy.

Two ways to fill a ``[range, azimuth, elevation]`` cube from one frame of ADC:

* :func:`rae_cube` -- a 2-D virtual array (e.g. :meth:`RadarConfig.dense`):
  windowed range FFT, then a 2-D angle FFT over the virtual array laid out on
  its ``(y, z)`` half-wavelength grid
  (:func:`~sionna_mmir.processing.imaging.range_azimuth_elevation`),
  squared magnitude.  Arrays whose elevation aperture is missing or sparse
  raise :class:`~sionna_mmir.errors.ConfigError` (:func:`check_elevation_aperture`).
* :func:`extruded_cube` -- a near-1-D array (the cascade): its range-azimuth
  map (:func:`~sionna_mmir.processing.imaging.range_azimuth`), squared,
  copied onto every elevation bin that a caller-given mask admits (the
  elevation beam); other cells are 0.

Angle axes (:mod:`.angle_fft`): the azimuth FFT measures the direction sine
``u_y = cos(el) sin(az)`` and the elevation FFT ``u_z = sin(el)`` of the
direction ``u = (u_x, u_y, u_z)`` seen from the aperture's phase centre.  The
bin centres are reported as ``azimuths_rad = arcsin(u_y)`` and
``elevations_rad = arcsin(u_z)``; a voxel's direction is
``(sqrt(1 - u_y^2 - u_z^2), u_y, u_z)`` and cells with ``u_y^2 + u_z^2 > 1``
(the invisible region) are set to 0 (:attr:`RAECube.visible`).  At zero
elevation the azimuth axis is the true azimuth.

The FFT beamformer assumes the far field.  The 100 x 100 dense array is
0.19 m across, so its Fraunhofer distance ``2 D^2 / lambda`` is ~19 m and
indoor scenes are imaged in its near field (wider, defocused peaks), as in
the paper's FFT pipeline.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ConfigError, InputValueError
from ..radar.config import RadarConfig
from .angle_fft import angles_from_spatial_frequency, spatial_frequencies
from .imaging import range_azimuth, range_azimuth_elevation
from .virtual_array import VirtualArray

#: Smallest fraction of the virtual grid's bounding box that must hold elements
#: for :func:`rae_cube` (the cascade: 136 of 7 x 86 cells = 0.23, rejected).
MIN_FILLED_FRACTION = 0.5


@dataclass
class RAECube:
    """A range-azimuth-elevation power cube and its axes.

    Attributes
    ----------
    power : ndarray of float32, shape (n_range, n_azimuth, n_elevation)
        Squared FFT magnitude; 0 in the invisible region.
    ranges_m : ndarray of float64, shape (n_range,)
        Range bin centres [m].
    azimuths_rad : ndarray of float64, shape (n_azimuth,)
        ``arcsin(u_y)`` of the azimuth bins [rad], increasing (+ = left).
    elevations_rad : ndarray of float64, shape (n_elevation,)
        ``arcsin(u_z)`` of the elevation bins [rad], increasing (+ = up).
    origin_m : ndarray of float64, shape (3,)
        Radar-frame point the ranges and angles are measured from (the
        aperture's phase centre) [m].
    kind : str
        ``"2d-fft"`` (:func:`rae_cube`) or ``"extruded"`` (:func:`extruded_cube`).
    """

    power: np.ndarray
    ranges_m: np.ndarray
    azimuths_rad: np.ndarray
    elevations_rad: np.ndarray
    origin_m: np.ndarray
    kind: str = "2d-fft"

    @property
    def shape(self) -> tuple:
        """``(n_range, n_azimuth, n_elevation)``."""
        return tuple(self.power.shape)

    @property
    def visible(self) -> np.ndarray:
        """ndarray of bool, shape (n_azimuth, n_elevation): ``u_y^2 + u_z^2 <= 1``."""
        uy, uz = np.sin(self.azimuths_rad), np.sin(self.elevations_rad)
        return uy[:, None] ** 2 + uz[None, :] ** 2 <= 1.0

    def directions(self) -> np.ndarray:
        """Radar-frame unit directions of the angle bins, shape (n_azimuth, n_elevation, 3).

        See :func:`bin_directions`; NaN in the invisible region.
        """
        return bin_directions(self.azimuths_rad, self.elevations_rad)

    def voxel_centres(self, index) -> np.ndarray:
        """Radar-frame positions of voxels.

        Parameters
        ----------
        index : tuple of three int arrays, each shape (n,)
            ``(i_range, i_azimuth, i_elevation)`` of the voxels.

        Returns
        -------
        ndarray of float64, shape (n, 3)
            ``origin_m + r u`` [m].
        """
        i_r, i_a, i_e = (np.asarray(i, dtype=np.int64).ravel() for i in index)
        u = self.directions()[i_a, i_e]
        return self.origin_m[None, :] + self.ranges_m[i_r, None] * u


def bin_directions(azimuths_rad, elevations_rad) -> np.ndarray:
    """Radar-frame unit directions of angle bins.

    Parameters
    ----------
    azimuths_rad : array_like, shape (n_azimuth,)
        ``arcsin(u_y)`` of the azimuth bins [rad].
    elevations_rad : array_like, shape (n_elevation,)
        ``arcsin(u_z)`` of the elevation bins [rad].

    Returns
    -------
    ndarray of float64, shape (n_azimuth, n_elevation, 3)
        ``(sqrt(1 - u_y^2 - u_z^2), u_y, u_z)``; NaN where ``u_y^2 + u_z^2 > 1``.
    """
    uy = np.sin(np.asarray(azimuths_rad, float))[:, None]
    uz = np.sin(np.asarray(elevations_rad, float))[None, :]
    ux2 = 1.0 - uy ** 2 - uz ** 2
    ux = np.where(ux2 >= 0, np.sqrt(np.maximum(ux2, 0.0)), np.nan)
    return np.stack(np.broadcast_arrays(ux, uy, uz), axis=-1)


def check_elevation_aperture(radar: RadarConfig, va: VirtualArray | None = None) -> VirtualArray:
    """The virtual array of ``radar`` if it resolves elevation.

    A radar resolves elevation here when its virtual grid has at least two
    elevation rows and elements on at least :data:`MIN_FILLED_FRACTION` of the
    grid's bounding box.

    Parameters
    ----------
    radar : RadarConfig
        The radar.
    va : VirtualArray, optional
        Its prebuilt virtual array.

    Returns
    -------
    VirtualArray

    Raises
    ------
    ConfigError
        For a 1-D array or a sparse elevation aperture (the cascade's 4 rows).
    """
    va = VirtualArray(radar) if va is None else va
    filled = va.num_unique / float(va.n_el * va.n_az)
    if va.n_el < 2 or filled < MIN_FILLED_FRACTION:
        raise ConfigError(
            f"radar '{radar.name}': no elevation aperture for a 3-D cube: its virtual "
            f"array spans {va.n_el} elevation row(s) x {va.n_az} columns with {va.num_unique} "
            f"elements ({filled:.0%} filled; need >= 2 rows and >= "
            f"{MIN_FILLED_FRACTION:.0%}); use a 2-D array such as RadarConfig.dense(n_tx, n_rx) "
            f"or extruded_cube() for a near-1-D array")
    return va


def _zero_invisible(cube: RAECube) -> RAECube:
    cube.power[:, ~cube.visible] = 0.0
    return cube


def rae_cube(adc, radar: RadarConfig, *, n_azimuth: int = 127, n_elevation: int = 127,
             n_range: int | None = None, window="hann") -> RAECube:
    """RAE power cube of one frame from a 2-D virtual array.

    Parameters
    ----------
    adc : ndarray of complex, shape (n_tx, n_rx, n_chirps, n_samples)
        Raw ADC of one frame (``radar.adc_shape``); chirps are averaged
        coherently (static scene).
    radar : RadarConfig
        Radar with a filled 2-D virtual aperture (:func:`check_elevation_aperture`).
    n_azimuth, n_elevation : int, optional
        Angle FFT lengths (127: bins symmetric about boresight).
    n_range : int, optional
        Range FFT length (default ``num_samples``).
    window : str, optional
        Window of the range, azimuth and elevation FFTs (unit coherent gain).

    Returns
    -------
    RAECube
        Shape (n_range, n_azimuth, n_elevation): the paper's 256 x 127 x 127
        for ``RadarConfig.dense(100, 100)``.

    Raises
    ------
    ConfigError
        ``radar`` does not resolve elevation.
    InputValueError
        Wrong ADC shape, NaN or Inf.
    """
    va = check_elevation_aperture(radar)
    mag, ranges, az, el = range_azimuth_elevation(
        adc, radar, range_window=window, azimuth_window=window, elevation_window=window,
        n_range=n_range, n_azimuth=n_azimuth, n_elevation=n_elevation, virtual_array=va)
    power = np.square(mag, dtype=np.float32)
    origin = va.phase_centre(azimuth_row_only=False)
    return _zero_invisible(RAECube(power, ranges, az, el, origin, "2d-fft"))


def elevation_bins(radar: RadarConfig, n_elevation: int = 127) -> np.ndarray:
    """Elevation bin centres ``arcsin(w f_d / f_c)`` [rad] of an FFT, shape (n_elevation,)."""
    return angles_from_spatial_frequency(spatial_frequencies(n_elevation), radar)


def extruded_cube(ra, ranges_m, azimuths_rad, elevations_rad, mask, origin_m) -> RAECube:
    """Extrude a range-azimuth map over elevation.

    Parameters
    ----------
    ra : array_like of float, shape (n_range, n_azimuth)
        RA magnitudes.
    ranges_m : array_like, shape (n_range,)
        Range bin centres [m].
    azimuths_rad : array_like, shape (n_azimuth,)
        ``arcsin(u_y)`` of the azimuth bins [rad].
    elevations_rad : array_like, shape (n_elevation,)
        ``arcsin(u_z)`` of the elevation bins to fill [rad].
    mask : array_like of bool, shape (n_azimuth, n_elevation)
        Cells the map is copied to (e.g. the elevation beam).
    origin_m : array_like, shape (3,)
        Phase centre of the azimuth row, radar frame [m].

    Returns
    -------
    RAECube
        ``power[r, a, e] = ra[r, a]^2`` where ``mask[a, e]`` and visible, else 0.
    """
    ra = np.asarray(ra, dtype=np.float64)
    az, el = np.asarray(azimuths_rad, float), np.asarray(elevations_rad, float)
    mask = np.asarray(mask, dtype=bool)
    if ra.shape != (len(ranges_m), az.size) or mask.shape != (az.size, el.size):
        raise InputValueError(f"extruded_cube: ra {ra.shape} must be [n_range={len(ranges_m)}, "
                              f"n_azimuth={az.size}] and mask {mask.shape} [n_azimuth, "
                              f"n_elevation={el.size}]")
    power = (np.square(ra)[:, :, None] * mask[None, :, :]).astype(np.float32)
    cube = RAECube(power, np.asarray(ranges_m, float), az, el,
                   np.asarray(origin_m, float).reshape(3), "extruded")
    return _zero_invisible(cube)


def range_azimuth_map(adc, radar: RadarConfig, *, n_azimuth: int = 127, window="hann"):
    """RA magnitude map of the azimuth row and its phase centre, for :func:`extruded_cube`.

    Parameters
    ----------
    adc : ndarray of complex, shape (n_tx, n_rx, n_chirps, n_samples)
        Raw ADC of one frame.
    radar : RadarConfig
        Any radar (the cascade: its 86-element azimuth row).
    n_azimuth : int, optional
        Azimuth FFT length (127).
    window : str, optional
        Range and azimuth window.

    Returns
    -------
    ra : ndarray of float, shape (n_range, n_azimuth)
    ranges_m : ndarray, shape (n_range,)
    azimuths_rad : ndarray, shape (n_azimuth,)
    origin_m : ndarray, shape (3,)
        Phase centre of the azimuth row, radar frame [m].
    """
    va = VirtualArray(radar)
    ra, ranges, az = range_azimuth(adc, radar, range_window=window, azimuth_window=window,
                                   n_azimuth=n_azimuth, virtual_array=va)
    return ra, ranges, az, va.phase_centre(azimuth_row_only=True)

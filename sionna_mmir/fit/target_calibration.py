"""Per-channel phase self-calibration of a range-azimuth fit target.

The range-azimuth (RA) fit of a scene compares magnitude maps, and a
magnitude map is formed by beamforming over the virtual array: it assumes the
array's channels are phase-calibrated.  An uncalibrated or mis-calibrated
array (per-channel delays of a few tens of picoseconds are several carrier
cycles at 77 GHz; unknown LO phases per chip) scrambles the capture's map,
and a scene fitted to a scrambled map starts the residual loop from a wrong
scene (materials and beams bent to explain smeared energy).

:func:`calibrate_target` estimates one phase per (Tx, Rx) channel against the
*initial* scene's render and corrects the capture *for the RA target only*:

``g_tr = <m_tr, y_tr> / <m_tr, m_tr>``,  ``phi_tr = arg(g_tr conj(g_ref))``

over the chirp- and frame-averaged fast-time samples (``y`` capture, ``m``
the initial scene's ADC), with ``g_ref`` the normalised sum of all ``g``.  It
is the classic strong-scatterer array self-calibration, with the scene's own
render as the reference instead of one point target.

Guards and limits:

* the correction is used only when it makes the capture's RA map correlate
  with the initial scene's clearly better (by :data:`MIN_RA_GAIN`); twelve
  free phases bend any map a little towards the reference (+0.01 on a clean
  capture of the independent suite's AWR1843 room, against +0.16 where
  its Tx and Rx are 10-45 ps late), so smaller gains leave the target raw;
* phases only: amplitudes of the reference are the initial materials', not
  the capture's;
* the capture and the residual loop's model are never corrected: per-channel
  errors stay in the residual, where the loop's sensor effects (channel gain,
  delay offset) can be found for them.  A radar rotation is a per-channel
  phase ramp as well; the loop's pose refinement, on the raw capture, finds
  it.
"""
from __future__ import annotations

import dataclasses

import numpy as np

#: the correction is applied when it raises the RA correlation of the capture
#: with the initial scene by at least this much
MIN_RA_GAIN = 0.05


@dataclasses.dataclass
class TargetCalibration:
    """What :func:`calibrate_target` estimated and whether it used it.

    Attributes
    ----------
    phases_rad : ndarray
        Float ``[T, R]``: the channels' phases relative to the array [rad]
        (the target is multiplied by ``exp(-j phases_rad)``).
    ra_corr_raw, ra_corr_calibrated : float
        RA correlation (Pearson, min-max normalised maps) of the initial
        scene's map with the raw and the corrected capture's.
    applied : bool
        Whether the target returned is the corrected one.
    """

    phases_rad: np.ndarray
    ra_corr_raw: float
    ra_corr_calibrated: float
    applied: bool

    def summary(self) -> dict:
        """JSON-ready figures (phases in degrees)."""
        return {"applied": bool(self.applied),
                "ra_corr_raw": round(float(self.ra_corr_raw), 4),
                "ra_corr_calibrated": round(float(self.ra_corr_calibrated), 4),
                "phases_deg": np.round(np.degrees(self.phases_rad), 1).tolist(),
                "min_ra_gain": MIN_RA_GAIN}


def channel_phases(frames, model_adc) -> np.ndarray:
    """Per-channel phase of the capture against a model render.

    Parameters
    ----------
    frames : array_like
        Complex capture ``[F, T, R, C, N]`` (or one frame ``[T, R, C, N]``).
    model_adc : array_like
        Complex model ADC ``[T, R, C, N]`` on the capture's radar.

    Returns
    -------
    ndarray
        Float ``[T, R]`` phases [rad] of the least-squares gain of each
        channel's model onto its capture, relative to their normalised sum;
        zero where a channel's model is empty.
    """
    from ..effects.library.channel_gain import channel_gains

    y = np.asarray(frames)
    y = y.reshape((-1,) + y.shape[-4:]).mean(axis=(0, 3))          # [T, R, N]
    m = np.asarray(model_adc).mean(axis=2)                          # [T, R, N]
    if m.shape != y.shape:
        raise ValueError(f"model ADC {np.asarray(model_adc).shape} does not match the "
                         f"capture's channels {np.asarray(frames).shape}")
    seen = np.any(m != 0, axis=-1)
    g = np.where(seen, channel_gains(m[None, :, :, None], y[None, :, :, None]), 0.0)
    ref = np.sum(g)
    if abs(ref) == 0:
        return np.zeros(g.shape)
    return np.where(seen, np.angle(g * np.conj(ref)), 0.0)


def calibrate_target(frames, model_adc, radar, *, min_gain: float = MIN_RA_GAIN):
    """The RA fit target of a capture, phase-calibrated against the initial scene
    where that clearly helps.

    Parameters
    ----------
    frames : array_like
        Complex capture ``[F, T, R, C, N]``.
    model_adc : array_like
        The initial scene's complex ADC ``[T, R, C, N]``.
    radar : RadarConfig
        The capture's radar.
    min_gain : float
        RA-correlation gain the correction must bring to be used.

    Returns
    -------
    (ndarray, TargetCalibration)
        The target RA map (:func:`~sionna_mmir.processing.imaging.mean_range_azimuth`)
        and what was estimated.
    """
    from ..metrics.ra import pearson
    from ..processing.imaging import mean_range_azimuth as target_ra

    frames = np.asarray(frames)
    phases = channel_phases(frames, model_adc)
    reference = target_ra(np.asarray(model_adc), radar)
    raw = target_ra(frames, radar)
    fixed = target_ra(frames * np.exp(-1j * phases)[..., None, None], radar)
    c_raw, c_fixed = float(pearson(reference, raw)), float(pearson(reference, fixed))
    applied = c_fixed - c_raw >= min_gain
    cal = TargetCalibration(phases_rad=phases, ra_corr_raw=c_raw, ra_corr_calibrated=c_fixed,
                            applied=bool(applied))
    return (fixed if applied else raw), cal


__all__ = ["MIN_RA_GAIN", "TargetCalibration", "calibrate_target", "channel_phases"]

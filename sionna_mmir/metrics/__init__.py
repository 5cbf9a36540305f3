"""The paper's Table 2 metrics on range-azimuth maps and raw ADC.

============================  ==================================================
``ra_correlation``            :func:`pearson` of min-max normalised RA maps (up)
``ra_psnr``                   :func:`psnr`, ``10 log10(1 / MSE)`` [dB] (up)
``ra_ssim``                   :func:`ssim`, Wang et al. 2004, sigma 1.5 (up)
``ra_rmse``                   :func:`rmse` of normalised maps (down)
``adc_log_mag_mse``           :func:`adc_log_magnitude_mse` [dB^2] (down)
``adc_minmax_mag_mse``        :func:`adc_minmax_magnitude_mse` (down)
============================  ==================================================

:func:`ra_loss` is the training loss (paper eq. 7), the MSE of min-max
normalised RA maps.  Only NumPy / SciPy are used.
"""
from __future__ import annotations

from .adc import LOG_EPS, adc_log_magnitude_mse, adc_minmax_magnitude_mse
from .ra import minmax_normalize, mse, pearson, psnr, ra_loss, rmse, ssim

__all__ = ["LOG_EPS", "adc_log_magnitude_mse", "adc_minmax_magnitude_mse", "all_metrics",
           "minmax_normalize", "mse", "pearson", "psnr", "ra_loss", "rmse", "ssim"]


def all_metrics(ra_a, ra_b, adc_a=None, adc_b=None) -> dict:
    """All Table 2 metrics as a dict of floats.

    ``ra_a``, ``ra_b``: real RA maps of equal shape (e.g. rendered vs
    measured; each min-max normalised internally).  ``adc_a``, ``adc_b``:
    optional complex ADC arrays of equal shape; when either is None the two
    ADC entries are NaN.

    Keys: ``ra_correlation``, ``ra_psnr``, ``ra_ssim``, ``ra_rmse``,
    ``adc_log_mag_mse``, ``adc_minmax_mag_mse``.
    """
    out = {
        "ra_correlation": pearson(ra_a, ra_b),
        "ra_psnr": psnr(ra_a, ra_b),
        "ra_ssim": ssim(ra_a, ra_b),
        "ra_rmse": rmse(ra_a, ra_b),
    }
    if adc_a is None or adc_b is None:
        out["adc_log_mag_mse"] = float("nan")
        out["adc_minmax_mag_mse"] = float("nan")
    else:
        out["adc_log_mag_mse"] = adc_log_magnitude_mse(adc_a, adc_b)
        out["adc_minmax_mag_mse"] = adc_minmax_magnitude_mse(adc_a, adc_b)
    return out

"""The base model a residual is taken against.

``base_model(spec, capture, frames)`` resolves what a user names as the base
model: an HDF5 render of a fitted model (its radar must match the
capture's), ``"static"`` (the capture's mean over frames: everything that
does not move) or ``"none"`` (effects explain everything).
"""
from __future__ import annotations

import os

import numpy as np

from ..captures.capture import Capture
from ..errors import InputValueError


def same_radar(a, b, rtol: float = 1e-6) -> bool:
    """Whether two radars record the same ADC layout and waveform."""
    return a.adc_shape == b.adc_shape and np.allclose(
        [a.start_frequency, a.slope, a.sample_rate], [b.start_frequency, b.slope, b.sample_rate],
        rtol=rtol)


def base_model(spec: str, cap: Capture, frames: slice):
    """The base-model ADC for ``spec`` and a description of it.

    Parameters
    ----------
    spec : str
        Path of an HDF5 render, ``"static"`` or ``"none"``.
    cap : Capture
        The measured capture.
    frames : slice
        Frames of ``cap`` the residual is taken on.

    Returns
    -------
    tuple
        ``(adc [F, T, R, C, N] complex, description)``.
    """
    y = cap.frames[frames]
    if spec == "none":
        return np.zeros_like(y), "none (effects only)"
    if spec == "static":
        if y.shape[0] < 2:
            raise InputValueError("the static base model needs a multi-frame capture "
                                  "(mean over frames)")
        return np.broadcast_to(y.mean(axis=0, keepdims=True), y.shape).copy(), \
            "static background (mean over frames)"
    if not os.path.isfile(spec):
        raise FileNotFoundError(f"{spec}: no such file (--model is an HDF5 render, 'static' "
                                "or 'none')")
    model = Capture.load(spec)
    if not same_radar(model.radar, cap.radar):
        raise InputValueError(
            f"{spec}: the model was rendered for a different radar than the capture's "
            f"(shape {model.radar.adc_shape} vs {cap.radar.adc_shape}, slope "
            f"{model.radar.slope:.6g} vs {cap.radar.slope:.6g} Hz/s); render the fit with "
            "the capture's radar (render --radar-from CAPTURE)")
    m = model.frames
    if m.shape[0] == 1 and y.shape[0] > 1:
        m = np.broadcast_to(m, y.shape)
    elif m.shape[0] != y.shape[0]:
        m = m[frames]
    if m.shape != y.shape:
        raise InputValueError(f"{spec}: model frames {m.shape[0]} do not match the capture's "
                              f"{y.shape[0]}")
    if not np.any(m):
        raise InputValueError(f"{spec}: the model ADC is all zeros (empty render)")
    return np.asarray(m), f"fitted render `{spec}`"

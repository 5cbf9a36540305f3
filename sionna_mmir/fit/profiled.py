"""A fit model with a frozen :class:`~sionna_mmir.effects.profile.SensorProfile`.

:class:`ProfiledModel` wraps any fit model (``latents() / render(z, seed)``,
e.g. :class:`~sionna_mmir.fit.MMIRModel` or the Sionna RT baseline) so that
its rendered ADC passes through the unit's calibrated channel gains, delays
and leakage before the loss (paper eq. 7 sees what the unit would have
captured)::

    y = s * H * x + L

``H`` and ``L`` come from the profile at the capture's waveform and stay
fixed; ``s`` is the scene scale, set once by least squares of the first
render against the capture (the capture's reflectivity and system gain, not
the unit's).  The data are never altered.
"""
from __future__ import annotations

import numpy as np


class ProfiledModel:
    """``model`` with ``profile`` applied frozen to its renders.

    Parameters
    ----------
    model : object
        A fit model (``latents``, ``lr_scales``, ``render``, ``apply``, ``radar``).
    profile : SensorProfile
        The unit's profile (checked against ``model.radar``).
    data : numpy.ndarray
        The capture's ADC ``[T, R, C, N]`` (sets the scene scale).
    seed : int
        Sample set of the render that sets the scale.
    arrival : numpy.ndarray, optional
        complex ``[T, R]`` factor of the capture's scene the meshes do not
        produce (the Rx-side arrival ramp of
        :func:`~sionna_mmir.effects.sensor_calibration.fit_scene`), held fixed.
    """

    def __init__(self, model, profile, data, seed: int = 12345, arrival=None):
        from ..paths.render import to_numpy

        profile.check_radar(model.radar, "sensor profile")
        self.model = model
        self.profile = profile
        self.arrival = None if arrival is None else np.asarray(arrival)
        x = to_numpy(model.render(model.latents(), seed=seed)[0])
        if arrival is not None:
            x = x * np.asarray(arrival)[:, :, None, None]
        self.scale = profile.scene_scale(x, data, model.radar)
        shape = x.shape
        g = self.scale * profile.channel_response(model.radar)[:, :, None, :]
        if arrival is not None:
            g = g * np.asarray(arrival)[:, :, None, None]
        leak = profile.leakage(model.radar)[:, :, None, :]
        self._g = np.broadcast_to(g, shape)
        self._leak = np.broadcast_to(leak, shape)

    def __getattr__(self, name):
        if name == "model":
            raise AttributeError(name)
        return getattr(self.model, name)

    def render(self, z: dict, seed: int):
        """``(DrAdc, handles)``: the inner render through the frozen profile."""
        import mitsuba as mi

        from ..fmcw.engine import DrAdc

        adc, handles = self.model.render(z, seed)

        def t(a):
            return mi.TensorXf(np.ascontiguousarray(a, dtype=np.float32))

        gr, gi, lr, li = t(self._g.real), t(self._g.imag), t(self._leak.real), t(self._leak.imag)
        re = gr * adc.real - gi * adc.imag + lr
        im = gr * adc.imag + gi * adc.real + li
        return DrAdc(re, im), handles

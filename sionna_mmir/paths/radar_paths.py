"""``RadarPaths``: per (tx, rx, path) complex amplitudes and delays.

The result of :class:`~sionna_mmir.paths.solver.RadarPathSolver`, the radar
counterpart of Sionna RT's ``Paths``.  Amplitudes are *voltage ratios*
(``|a|^2`` = received / transmitted power for unit transmit power); the
carrier phase is not in ``a`` but in the delay ``tau`` (paper eq. 4), which
:func:`~sionna_mmir.fmcw.synthesize_adc` applies per ADC sample.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..utils.backend import init_backend

init_backend()

import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402


@dataclass
class RadarPaths:
    """Paths of one radar frame (Dr.Jit arrays, inside the AD graph).

    ==============  =========================================================
    a_re, a_im      ``mi.Float`` [T*R*P], amplitude (``t`` slowest, ``p``
                    fastest), dimensionless voltage ratio
    tau             ``mi.Float`` [T*R*P], delay [s]
    tau_rate        ``mi.Float`` [T*R*P] ``d tau / dt`` [s/s] or ``None``
    shape           ``(T, R, P)``
    depth           ``np.ndarray`` [P] number of interactions of each path
    num_candidates  rays launched (the Monte Carlo ``N`` of eq. 3)
    ==============  =========================================================
    """

    a_re: object
    a_im: object
    tau: object
    tau_rate: object
    shape: tuple
    depth: np.ndarray
    num_candidates: int
    info: dict = field(default_factory=dict)
    #: recorded discrete decisions, pass as ``samples=`` to replay them
    samples: list | None = None

    @property
    def num_paths(self) -> int:
        return self.shape[2]

    def tensors(self):
        """``(a_re, a_im, tau, tau_rate)`` as ``mi.TensorXf`` ``[T, R, P]``."""
        def t(x):
            return None if x is None else mi.TensorXf(x, self.shape)
        return t(self.a_re), t(self.a_im), t(self.tau), t(self.tau_rate)

    def numpy(self):
        """``(a complex128 [T,R,P], tau float64 [T,R,P], tau_rate or None)``."""
        def n(x):
            return None if x is None else np.asarray(dr.detach(x), dtype=np.float64).reshape(self.shape)
        return n(self.a_re) + 1j * n(self.a_im), n(self.tau), n(self.tau_rate)

    def power(self):
        """``mi.Float`` total received power ``sum |a|^2`` over pairs and paths (AD)."""
        return dr.sum(dr.square(self.a_re) + dr.square(self.a_im))

    def adc(self, radar):
        """Raw ADC via :func:`~sionna_mmir.fmcw.synthesize_adc` (a ``DrAdc``, AD)."""
        from ..fmcw.synthesize import synthesize_adc

        a_re, a_im, tau, rate = self.tensors()
        return synthesize_adc(radar, (a_re, a_im), tau, rate)

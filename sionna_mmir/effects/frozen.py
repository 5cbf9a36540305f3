"""``FrozenPart``: a chirp-varying component held fixed on chirp-averaged data.

The residual loop scores chirp-static candidates on data averaged over chirp
loops (:meth:`~.model.EffectModel.chirp_averaged`), a fraction of the work.
A component that changes from chirp to chirp does not commute with that
average, but two kinds still have an exact (mean) or natural (variance)
chirp-averaged counterpart when their values are held fixed:

* an **additive scene effect** (``additive = True``: ``apply(x) = x + s``
  with ``s`` independent of ``x``, e.g. a moving scatterer's extra path):
  its average over chirps, ``mean_c s``, added at the same stage;
* a **variance effect** (a phase-noise skirt, a coloured floor) of noise
  that is independent from chirp to chirp: the average of ``C`` chirps
  carries ``mean_c v / C``;
* an effect that brings its own counterpart (``averaged_counterpart``), a
  ``FrozenPart`` subclass: ego motion at a fixed velocity is a linear map
  of the static scene, and so is its chirp average
  (:class:`~.library.ego_motion_average.AveragedEgoMotion`); ADC clipping
  behind a chirp-varying effect is the chirp mean of the clipped inputs,
  which differ from their mean by a fixed deviation at the held values
  (:class:`~.library.adc_clipping.AveragedClipping`).

``FrozenPart`` is that counterpart: no parameters, the source effect's name,
kind and stage, and the precomputed signal or variance ``[F, T, R, 1, N]``
(normalised units).  It exists only inside an averaged model used for
scoring; the full model keeps the source component.
"""
from __future__ import annotations

import numpy as np

from . import ops
from .base import Effect


def averageable(effect: Effect) -> bool:
    """Whether a component of ``effect`` has a chirp-averaged counterpart at fixed values
    (an additive or variance effect here, or an effect with its own
    ``averaged_counterpart(values, ctx, model_input)``, e.g. ego motion)."""
    return effect.chirp_static or effect.kind == "variance" or (
        effect.kind == "mean" and getattr(effect, "additive", False)) \
        or callable(getattr(effect, "averaged_counterpart", None))


class FrozenPart(Effect):
    """A fixed chirp-averaged signal (mean) or variance (see the module docstring).

    Parameters
    ----------
    source : Effect
        The chirp-varying effect it stands for.
    signal : numpy.ndarray, optional
        complex ``[F, T, R, 1, N]``: the averaged added signal (mean kind).
    variance : numpy.ndarray, optional
        real, broadcastable to ``[F, T, R, 1, N]``: the averaged added variance.
    """

    chirp_static = True

    def __init__(self, source: Effect, signal=None, variance=None):
        if (signal is None) == (variance is None):
            raise ValueError("FrozenPart: give exactly one of signal and variance")
        self._stand_for(source, "at fixed values")
        self._signal = None if signal is None else ops.tensor(signal)
        self._variance = None if variance is None else ops.tensor(np.asarray(variance, float))

    #: attributes rebuilt on first use (device tensors, kernels): not pickled
    _CACHED: tuple = ()

    def __getstate__(self):
        return {k: v for k, v in self.__dict__.items() if k not in self._CACHED}

    def __setstate__(self, state):
        self.__dict__.update(state)
        for k in self._CACHED:
            setattr(self, k, None)

    def _stand_for(self, source: Effect, how: str) -> None:
        """Take ``source``'s name, kind, stage and place in the chain."""
        self.source = source
        self.name, self.kind, self.stage = source.name, source.kind, source.stage
        self.chain_order = source.chain_key
        self.description = f"{source.name} {how}, averaged over chirps"

    def param_specs(self, ctx, model, residual) -> dict:
        return {}

    def apply(self, x, p, ctx):
        return ops.cadd(x, self._signal)

    def variance(self, x, X, p, ctx):
        return self._variance

"""The :class:`Effect` interface and its parameter description.

An effect is a small differentiable module with few parameters that the base
forward model lacks (paper: "sensor imperfections"; here also scene
additions).  Two kinds:

* ``kind = "mean"``: changes the expected ADC, ``x -> apply(x, p)``, on
  ``(re, im)`` tensors ``[F, T, R, C, N]`` (time domain);
* ``kind = "variance"``: adds noise power per range bin (unitary-DFT domain),
  ``variance(x, X, p) -> [.., N]`` broadcastable to ``[F, T, R, C, N]``.

A mean effect that sits in the receive chain after a noise source (an IF
filter after the mixer) also shapes that noise: it sets
``shapes_noise = True`` and implements :meth:`Effect.noise_gain`, the power
gain per range bin it applies to the white receiver floor.  A mean effect
that predicts each channel only on average (a leakage pattern shared by the
channels, from which each channel's own leakage deviates) sets
``has_spread = True`` and implements :meth:`Effect.spread`, the power of
that deviation per range bin, which adds to the variance.

Effects run in ``stage`` order: 0 scene (extra paths), 1 RF / per channel
(gains, delays, coupling), 2 IF (filter), 3 ADC (DC, IQ, clipping).
"""
from __future__ import annotations

import contextlib
import dataclasses

import numpy as np

from ..errors import ConfigError

STAGES = {0: "scene", 1: "rf", 2: "if", 3: "adc"}


@dataclasses.dataclass
class ParamSpec:
    """One named parameter block of an effect.

    Parameters
    ----------
    init : numpy.ndarray
        float64 initial value (its shape is the block's shape)
    lower : float or numpy.ndarray, optional
        lower bound (scalar or same shape), ``-inf`` for none
    upper : float or numpy.ndarray, optional
        upper bound, ``+inf`` for none
    unit : str, optional
        unit of the stored value, for reports
    """

    init: np.ndarray
    lower: object = -np.inf
    upper: object = np.inf
    unit: str = ""

    def __post_init__(self):
        self.init = np.atleast_1d(np.asarray(self.init, dtype=np.float64))
        if not np.all(np.isfinite(self.init)):
            raise ConfigError("ParamSpec: initial value holds NaN or Inf")
        lo = np.broadcast_to(np.asarray(self.lower, np.float64), self.init.shape)
        hi = np.broadcast_to(np.asarray(self.upper, np.float64), self.init.shape)
        self.init = np.clip(self.init, lo, hi)

    @property
    def size(self) -> int:
        return int(self.init.size)

    def bounds(self):
        lo = np.broadcast_to(np.asarray(self.lower, np.float64), self.init.shape).ravel()
        hi = np.broadcast_to(np.asarray(self.upper, np.float64), self.init.shape).ravel()
        return [(None if not np.isfinite(a) else float(a), None if not np.isfinite(b) else float(b))
                for a, b in zip(lo, hi)]


class Effect:
    """Base class.  Subclasses set the class attributes and implement
    :meth:`param_specs` and :meth:`apply` (mean) or :meth:`variance`.

    Attributes
    ----------
    name : str
        Registry key, e.g. ``"channel_gain"``.
    kind : {"mean", "variance"}
        What the effect changes: the mean or the variance of the capture.
    stage : int
        0 scene, 1 RF, 2 IF, 3 ADC (order in the chain).
    description : str
        One line for reports.
    """

    name = "effect"
    kind = "mean"
    stage = 1
    description = ""
    #: place in the chain where it differs from ``stage`` (None: ``stage``);
    #: effects are applied in ``(chain_order or stage)`` order
    chain_order = None
    #: names of effects this one may make redundant or re-explain (a mover
    #: beside ego motion, a leakage behind an IF filter): its data-driven
    #: start sees the model without them, and the residual loop refits them
    #: from silence beside it when it is scored and adopted
    may_replace = ()
    #: names of adopted effects refitted together with it when it is scored
    #: (held at their values otherwise): what already took part of its
    #: signature without making it redundant
    refit_beside = ()
    #: for a scene-side effect: the name of the sensor effect it is when one
    #: set of its parameters is shared by every object (per-object patterns
    #: and a per-channel gain); the residual loop asks a held-out object
    #: which of the two a residual is (:mod:`~sionna_mmir.residual.object_transfer`)
    shared_twin = None
    #: applying it commutes with averaging over chirp loops and its parameters
    #: mean the same on averaged data (a static, linear effect); the residual
    #: loop scores such candidates on chirp-averaged data
    chirp_static = True
    #: applied sample by sample to each chirp alone (a saturation): not linear,
    #: but it commutes with the chirp average when every mean effect before it
    #: in the chain is chirp-static, since its input is then the same in every
    #: chirp (:meth:`~sionna_mmir.effects.model.EffectModel.static_flags`)
    pointwise = False
    #: ``apply(x) = x + s(p)`` with ``s`` independent of ``x`` (an extra path):
    #: a chirp-varying additive effect can be held fixed on chirp-averaged data
    #: (:class:`~sionna_mmir.effects.frozen.FrozenPart`)
    additive = False
    #: acts on every path of the scene alike (a per-channel gain, IQ imbalance,
    #: a delay or frequency offset, the chirp's non-linearity): the residual it
    #: explains follows the signal's power across range, which the residual
    #: loop checks (:func:`~sionna_mmir.residual.ranking.outside_share`)
    every_path = False
    #: its parameters set each channel's phase (a per-channel gain, delay or
    #: frequency offset, the chirp's non-linearity): where the base
    #: refinement ran into its bounds bending to those phases
    #: (:func:`~sionna_mmir.effects.library.scene_mismatch.refinement_pinned`),
    #: the residual loop refits that refinement beside it
    channel_phase = False
    #: a property of the radar unit (same on every capture of it), not of the
    #: scene or the moment: calibrated once into a sensor profile
    #: (:mod:`sionna_mmir.effects.profile`), not cross-validated inside one frame
    per_unit = False
    #: the residual loop adopts it only while it explains at least this much
    #: (nats per held-out sample; :meth:`gain_floor`)
    min_gain_per_sample = 0.0

    #: keeps a linear predictor frozen on the mean model (the row extension
    #: of a spectral operator), renewed by :meth:`refreeze`
    frozen_on_model = False

    def refreeze(self, model: np.ndarray) -> None:
        """Renew what the effect froze on the mean model, on ``model`` (complex
        ``[F, T, R, C, N]``, normalised units, every component in): an
        effect added after it (a leakage's near-DC tones) brings tones that
        a row predictor frozen without them continues badly, and a filter's
        output at the window's edges goes wrong with it.  Nothing to renew
        by default."""

    def tone_gains(self, values: dict, ctx, freqs) -> np.ndarray | None:
        """Complex gain of the effect on steady tones at the beat frequencies
        ``freqs`` [Hz] (``[K]``), at parameter values ``values`` (NumPy): a
        linear filter's response as its operator applies it; None for an
        effect that is not such a filter (the default)."""
        return None

    def behind(self, values: dict, ctx, gains) -> dict | None:
        """``values`` of an additive effect moved behind a filter added after
        it: fitted to what the filter leaves, each of its tones is divided by
        ``gains(freqs)`` (:meth:`tone_gains` of the filter), so the filtered
        model starts where it was.  None where that has no meaning (the
        default)."""
        return None

    def held_state(self):
        """A context in which the effect keeps whatever it derives from its
        input (ego motion's geometry) fixed at what it first derives there,
        so that it is a fixed map of its input
        (:meth:`~sionna_mmir.effects.model.EffectModel.frozen_prefix`);
        nothing to hold by default."""
        return contextlib.nullcontext()

    def silenced(self, values: dict):
        """``values`` with this effect's contribution switched off (an additive
        effect's amplitude at zero), or None where that has no meaning; the
        start from which an effect that may replace it is scored
        (:attr:`may_replace`)."""
        return None

    @property
    def chain_key(self) -> float:
        """Sort key of the effect in the chain (``chain_order``, else ``stage``)."""
        return self.stage if self.chain_order is None else self.chain_order

    @property
    def scene_side(self) -> bool:
        """Whether a better scene explains it (stage 0), not the sensor."""
        return self.stage == 0

    def supports(self, ctx) -> bool:
        """Whether a capture of ``ctx``'s shape can identify the effect (default: any)."""
        return True

    def gain_floor(self, ctx) -> float:
        """Least held-out gain per sample [nats] for adoption on a capture of
        ``ctx``'s shape (default: :attr:`min_gain_per_sample`)."""
        return float(self.min_gain_per_sample)

    def fitted_gain_floor(self, model, values: dict) -> float:
        """:meth:`gain_floor` once the candidate is fitted: ``model`` is the
        fold's candidate model (an :class:`~sionna_mmir.effects.model.EffectModel`
        with this effect last), ``values`` its fitted parameters.  The
        default ignores both; an effect whose fit can show it to be
        something with a stricter floor (a mover moving exactly as the
        static scene does) overrides it."""
        return self.gain_floor(model.ctx)

    def param_specs(self, ctx, model: np.ndarray, residual: np.ndarray) -> dict:
        """Parameter blocks with data-driven initial values.

        ``model`` is the current mean model and ``residual`` the measured minus
        model, complex128 ``[F, T, R, C, N]`` (time domain, normalised units).
        Returns ``{name: ParamSpec}``; the initial values must leave the model
        unchanged or be a good first guess from the residual.
        """
        raise NotImplementedError

    def apply(self, x, p: dict, ctx):
        """Mean effect: ``(re, im)`` ``[F, T, R, C, N]`` -> ``(re, im)``; ``p`` name -> ``mi.TensorXf``."""
        raise NotImplementedError(f"{self.name} is not a mean effect")

    #: the effect also filters the white receiver floor (see :meth:`noise_gain`)
    shapes_noise = False

    def noise_gain(self, p: dict, ctx):
        """Power gain per range bin on the white floor ``sigma^2``, broadcastable to
        ``[F, T, R, C, N]`` (a mean effect with ``shapes_noise = True``)."""
        raise NotImplementedError(f"{self.name} does not shape the noise floor")

    #: the effect predicts each channel only on average (see :meth:`spread`)
    has_spread = False

    def spread(self, p: dict, ctx):
        """Power per range bin (unitary-DFT domain) by which a mean effect with
        ``has_spread = True`` is expected to miss a channel, broadcastable to
        ``[F, T, R, C, N]``; it adds to the variance, filtered by the noise
        shapers later in the chain."""
        raise NotImplementedError(f"{self.name} has no spread")

    def variance(self, x, X, p: dict, ctx):
        """Variance effect: added noise power per range bin, broadcastable to ``[F, T, R, C, N]``.

        ``x`` / ``X`` are the mean signal in the time / range (unitary DFT) domain.
        """
        raise NotImplementedError(f"{self.name} is not a variance effect")

    #: predicts part of each cell's chirp-to-chirp deviation from the other
    #: cells (a random effect shared across channels: the LO's frequency
    #: error); see :meth:`deviation_prediction`
    predicts_deviation = False

    def deviation_prediction(self, x, d, values: dict, ctx, v, use=None) -> np.ndarray:
        """The part of the chirp deviation ``d`` (time domain ``[F, T, R, C, N]``)
        that an effect with ``predicts_deviation`` explains in each cell from
        the other cells among ``use`` (bool ``[F, T, R, C]``; None: all); ``x``
        the mean model, ``v`` its per-bin variance, ``values`` NumPy."""
        raise NotImplementedError(f"{self.name} does not predict deviations")

    def fit_deviation(self, x, d, values: dict, ctx, v, use=None) -> dict:
        """``values`` with what :meth:`deviation_prediction` uses fitted to the
        deviation ``d`` on the cells ``use`` (outside the Dr.Jit likelihood)."""
        raise NotImplementedError(f"{self.name} does not predict deviations")

    def summary(self, p: dict, ctx) -> dict:
        """Physically meaningful, JSON-serialisable view of fitted values (NumPy ``p``)."""
        return {k: np.asarray(v).round(6).tolist() for k, v in p.items()}

    def __repr__(self):
        return f"<{type(self).__name__} {self.name}>"


def num_params(specs: dict) -> int:
    """Total number of real parameters of ``{name: ParamSpec}``."""
    return int(sum(s.size for s in specs.values()))

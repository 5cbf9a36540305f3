"""``EffectModel``: a base render plus a chain of effects, scored by a Gaussian NLL.

The measured ADC ``y`` is modelled, in the range (unitary DFT) domain, as::

    Y[f, t, r, c, k] ~ CN( X[f, t, r, c, k],  v[f, t, r, c, k] )
    x = effects_mean( g * b ),        X = DFT(x)
    v = sigma^2 s + sum of variance effects + spreads,   s = prod of noise gains

with ``b`` the base model's ADC (e.g. the fitted scene's render), ``g`` one
global complex gain and ``sigma^2`` a white noise floor (both nuisance
parameters, always fitted, never reported as effects); ``s`` is the power
gain of the mean effects that also filter the receiver noise
(:meth:`~.base.Effect.noise_gain`, e.g. the IF high-pass), 1 without
them; a spread is the power by which a mean effect that predicts each
channel only on average (:meth:`~.base.Effect.spread`, a leakage pattern
shared by the channels) is expected to miss one.  The loss is the mean
negative log-likelihood per complex sample over the cells of a mask
(``|Y - X|^2 / v + log v``), a proper score for both kinds of effect:
mean effects reduce ``|Y - X|^2``, variance effects shape ``v``.

Everything is normalised by the measured RMS, so parameters and losses are
O(1) whatever the capture's units.
"""
from __future__ import annotations

import contextlib
import copy
import dataclasses
import functools

import numpy as np
from scipy.optimize import minimize, minimize_scalar

from ..errors import InputValueError
from . import ops
from .base import Effect, ParamSpec, num_params
from .context import EffectContext

dr, mi = ops.dr, ops.mi

NUISANCE = "nuisance"

#: L-BFGS-B's relative-reduction stop: the loss is a float32 mean NLL per
#: sample, so 1e-9 of it is ~5e-9 nats per sample (0.004 nats over a
#: 12 x 16 x 16 x 256 capture); tighter stops spent a third of the
#: evaluations on changes below that
FIT_FTOL = 1e-9


@functools.lru_cache(maxsize=8)
def _broadcast_index(small: tuple, full: tuple):
    """Flat indices into a C-ordered ``small`` array that broadcast it to ``full``."""
    src = np.arange(int(np.prod(small)), dtype=np.uint32).reshape(small)
    return mi.UInt32(np.ascontiguousarray(np.broadcast_to(src, full)).ravel())


def _one_thread(fn):
    """Run ``fn`` under :func:`.ops.single_thread` (see there for the Dr.Jit race)."""
    @functools.wraps(fn)
    def wrapped(*args, **kwargs):
        with ops.single_thread():
            return fn(*args, **kwargs)
    return wrapped


@dataclasses.dataclass(eq=False)            # identity: values hold arrays
class Component:
    """An effect in the model with its parameter specs and current values."""

    effect: Effect
    specs: dict
    values: dict

    @property
    def n_params(self) -> int:
        return num_params(self.specs)

    def copy(self) -> "Component":
        """The same effect and specs with independent copies of the values."""
        return Component(effect=self.effect, specs=self.specs,
                         values={k: np.array(v, copy=True) for k, v in self.values.items()})


class EffectModel:
    """Base render + effects; see the module docstring.

    Parameters
    ----------
    ctx : EffectContext
        :class:`~.context.EffectContext`
    measured : numpy.ndarray
        complex ``[F, T, R, C, N]`` (or ``[T, R, C, N]``) capture ADC
    base : numpy.ndarray
        complex, same shape: the base model's ADC (may be all zero)
    """

    def __init__(self, ctx: EffectContext, measured, base=None):
        self.ctx = ctx
        y = ctx.check(measured, "measured ADC")
        if base is None:
            if ctx.basis is None:
                raise InputValueError("EffectModel: give a base model ADC or a scene basis")
            base = np.broadcast_to(ctx.basis.total()[None], ctx.shape)
        b = ctx.check(base, "model ADC")
        self.scale = float(np.sqrt(np.mean(np.abs(y) ** 2)))
        if not self.scale > 0:
            raise InputValueError("measured ADC: all samples are zero (empty capture)")
        y = y / self.scale
        b = b / self.scale
        eb = float(np.vdot(b, b).real)
        self.has_base = eb > 0
        self.base_gain = complex(np.vdot(b, y) / eb) if self.has_base else 1.0
        self.y = y
        self.b = b * self.base_gain
        self.Y_numpy = np.fft.fft(y, axis=-1, norm="ortho")
        self.Y = ops.tensor(self.Y_numpy)
        self.y_t = ops.tensor(y)
        self.b_t = ops.tensor(self.b)
        #: per-object base components (scaled like ``b``) when the context has a basis
        self.basis_t = self._basis_tensors()
        r = y - self.b
        self.nuisance = Component(
            effect=None,
            specs={"gain": ParamSpec([1.0, 0.0] if self.has_base else [0.0, 0.0]),
                   "log_noise": ParamSpec([np.log(max(np.mean(np.abs(r) ** 2), 1e-12))],
                                          lower=np.log(1e-12), upper=np.log(1e4))},
            values={})
        self.nuisance.values = {k: s.init.copy() for k, s in self.nuisance.specs.items()}
        self.components: list[Component] = []

    # ------------------------------------------------------------ building
    def add(self, effect: Effect, cells=None) -> Component:
        """Add ``effect`` with data-driven initial values; returns its component.

        With a boolean ``cells`` mask ``[F, T, R, C]`` the initial values see
        only those cells (the others are zeroed), so a cross-validation fold
        never initialises from its held-out data.
        """
        model, _ = self.mean_variance_numpy()
        full = model
        residual = self.y - model
        if effect.may_replace:
            model = self._without(effect.may_replace)
        keep = None if cells is None else np.asarray(cells, bool)[..., None]
        if keep is not None:
            model, residual = model * keep, residual * keep
        if effect.stage == 0:
            h = self.channel_response(keep, current=full)
            model, residual = model / h, residual / h
        if effect.kind == "basis" and self.ctx.basis is not None:
            self.ctx.basis.current_shares = self.component_shares()
        specs = effect.param_specs(self.ctx, model, residual)
        comp = Component(effect=effect, specs=specs,
                         values={k: s.init.copy() for k, s in specs.items()})
        self.components.append(comp)
        self._refreeze(comp)
        return comp

    def _refreeze(self, new: Component) -> None:
        """Renew the predictors frozen on the mean model
        (:meth:`~.base.Effect.refreeze`) on the model with ``new`` in, at
        its initial values: ``new``'s own (its start saw the model without
        the components it may replace) and the earlier components' (frozen
        before ``new``'s tones were there).  The model they are renewed on
        leaves the holders out: their operators keep the tones' frequencies,
        and their output at the window's edges is what a stale predictor
        spoils (a predictor fitted to it was unstable in the tests).  An
        earlier component's effect is copied first: copies of a model share
        their effects."""
        held = [c for c in self.components if c.effect.frozen_on_model]
        if not held:
            return
        model = self._without({c.effect.name for c in held})
        for c in held:
            if c is not new:
                c.effect = copy.deepcopy(c.effect)
            c.effect.refreeze(model)

    def _without(self, names) -> np.ndarray:
        """The current mean model with the components named ``names`` left out."""
        kept = [c for c in self.components if c.effect.name not in set(names)]
        if len(kept) == len(self.components):
            return self.mean_variance_numpy()[0]
        every, self.components = self.components, kept
        try:
            return self.mean_variance_numpy()[0]
        finally:
            self.components = every

    def channel_response(self, keep=None, current=None) -> np.ndarray:
        """Per-channel complex response of the current sensor chain, ``[1, T, R, 1, 1]``.

        ``h[t, r] = sum conj(p) m / sum |p|^2`` over frames, chirps and samples
        (the cells in ``keep``), with ``p = g b`` the base render before any
        effect and ``m`` the current mean model.  A scene effect (stage 0) adds
        paths *before* the sensor chain, so its data-driven initial value is
        computed on the residual referred back through the chain, ``r / h``:
        per-channel gains and delays adopted earlier would otherwise scramble
        the phases its angle search relies on.  All ones without a base or
        without sensor-stage mean effects, and where ``|h|`` is under a tenth
        of its median (a channel the base does not reach).  ``current``: the
        mean model when the caller already has it (normalised units).
        """
        T, R = self.ctx.shape[1:3]
        ones = np.ones((1, T, R, 1, 1), complex)
        if not self.has_base or not any(c.effect.kind == "mean" and c.effect.stage > 0
                                        for c in self.components):
            return ones
        gain = self.nuisance.values["gain"]
        pre = self.base_numpy() * complex(gain[0], gain[1])
        post = self.mean_variance_numpy()[0] if current is None else current
        if keep is not None:
            pre, post = pre * keep, post * keep
        num = np.sum(np.conj(pre) * post, axis=(0, 3, 4), keepdims=True)
        den = np.sum(np.abs(pre) ** 2, axis=(0, 3, 4), keepdims=True)
        h = num / np.where(den > 0, den, 1.0)
        mag = np.abs(h)
        ok = (den > 0) & (mag > 0.1 * np.median(mag[den > 0])) if np.any(den > 0) else den > 0
        return np.where(ok, h, ones)

    @_one_thread
    def base_numpy(self) -> np.ndarray:
        """The base before the sensor chain (after scene-side effects), normalised units."""
        if self.basis_t is None or not any(c.effect.kind == "basis" for c in self.components):
            return self.b
        with dr.suspend_grad():
            return ops.to_numpy(self._base(self._tensors(), self._order()))

    def chirp_averaged(self, freeze: bool = False) -> "EffectModel":
        """This model on the data averaged over chirp loops (``C = 1``).

        Every component must commute with the average (:meth:`static_flags`),
        so its values carry over unchanged; the normalisation (``scale``,
        ``base_gain``) is kept, so values fitted on the averaged model mean
        the same on this one.  The white floor is
        re-estimated (averaging divides it by ``C``).  With ``freeze``, a
        chirp-varying component that is an additive scene effect or a
        variance effect enters as a :class:`~.frozen.FrozenPart` at its
        current values instead (the model is then for scoring other
        components, not for fitting that one).  Returns ``self`` when
        ``C == 1``.
        """
        from .frozen import averageable

        C = self.ctx.shape[3]
        if C == 1:
            return self
        moving = [c.effect.name for c, s in zip(self.components, self.static_flags())
                  if not s and not (freeze and averageable(c.effect))]
        if moving:
            raise InputValueError(f"chirp_averaged: {moving} change from chirp to chirp")
        parts = self._frozen_parts() if freeze else {}
        basis = self.ctx.basis
        if basis is not None:
            basis = dataclasses.replace(basis, adc=basis.adc.mean(axis=3, keepdims=True))
            basis.current_shares = getattr(self.ctx.basis, "current_shares", None)
        ctx = dataclasses.replace(self.ctx, radar=self.ctx.radar.replace(num_chirps=1),
                                  basis=basis)
        new = object.__new__(EffectModel)
        new.__dict__.update(self.__dict__)
        new.ctx = ctx
        new.y = self.y.mean(axis=3, keepdims=True)
        new.b = self.b.mean(axis=3, keepdims=True)
        new.Y_numpy = np.fft.fft(new.y, axis=-1, norm="ortho")
        new.Y = ops.tensor(new.Y_numpy)
        new.y_t = ops.tensor(new.y)
        new.b_t = ops.tensor(new.b)
        new.basis_t = new._basis_tensors()
        new.nuisance = self.nuisance.copy()
        new.components = [parts.get(id(c)) or c.copy() for c in self.components]
        r = new.y - new.mean_variance_numpy()[0]
        new.nuisance.values["log_noise"] = np.array([np.log(max(np.mean(np.abs(r) ** 2),
                                                                 1e-12))])
        return new

    def can_average(self) -> bool:
        """Whether :meth:`chirp_averaged` with ``freeze=True`` can represent this model."""
        from .frozen import averageable

        return all(s or averageable(c.effect)
                   for c, s in zip(self.components, self.static_flags()))

    def static_flags(self, extra=None) -> list:
        """Per component (and for ``extra``, an effect to be added, last):
        whether applying it commutes with the chirp average here.

        A :attr:`~.base.Effect.chirp_static` effect always does; a
        :attr:`~.base.Effect.pointwise` one (ADC clipping) when every mean
        effect before it in the chain does, so that its input is the same
        in every chirp.  Variance effects do not change the mean."""
        effects = [c.effect for c in self.components] + ([extra] if extra is not None else [])
        flags, upstream = [False] * len(effects), True
        for key in sorted({e.chain_key for e in effects}):
            group = [i for i, e in enumerate(effects) if e.chain_key == key]
            for i in group:
                flags[i] = effects[i].chirp_static or (effects[i].pointwise and upstream)
            upstream = upstream and all(flags[i] or effects[i].kind == "variance"
                                        for i in group)
        return flags

    @_one_thread
    def _frozen_parts(self) -> dict:
        """``{id(component): Component(FrozenPart)}`` for the chirp-varying components."""
        from .frozen import FrozenPart

        C = self.ctx.shape[3]
        out = {}
        with dr.suspend_grad():
            tens = self._tensors()
            x, X, _ = self._forward(tens)
            for i, (c, static) in enumerate(zip(self.components, self.static_flags())):
                if static:
                    continue
                blk = _block(tens, i, c)
                counterpart = getattr(c.effect, "averaged_counterpart", None)
                if callable(counterpart):
                    part = counterpart(c.values, self.ctx, lambda i=i: self._input_of(i))
                elif c.effect.kind == "variance":
                    v = ops.to_numpy(c.effect.variance(x, X, blk, self.ctx)
                                     + dr.zeros(mi.TensorXf, X[0].shape))
                    part = FrozenPart(c.effect, variance=v.mean(axis=3, keepdims=True) / C)
                else:
                    s = ops.to_numpy(c.effect.apply(ops.zeros_like(self.b_t), blk, self.ctx))
                    part = FrozenPart(c.effect, signal=s.mean(axis=3, keepdims=True))
                out[id(c)] = Component(effect=part, specs={}, values={})
        return out

    def _input_of(self, i: int) -> np.ndarray:
        """The mean model as component ``i`` receives it: the components before
        it in the chain order, ``[F, T, R, C, N]`` (normalised units)."""
        order = self._order()
        before = order[:order.index(i)]
        every = self.components
        self.components = [every[j] for j in sorted(before)]
        try:
            return self.mean_variance_numpy()[0]
        finally:
            self.components = every

    def remove(self, comp: Component):
        self.components.remove(comp)

    #: attributes rebuilt from their NumPy sources when a model is unpickled
    _TENSORS = ("Y", "y_t", "b_t", "basis_t")
    #: on a :meth:`split_averaged` model: ``(S, S_t, C)``, the data's
    #: chirp-to-chirp deviation power ``sum_c |Y_c - mean_c Y|^2``
    #: ``[F, T, R, 1, N]`` (NumPy and device copies) and the chirp loops ``C``
    #: behind each averaged sample
    _deviation = None
    #: ``(Y_numpy, S)``: the data's deviation power of this (full) model,
    #: computed once for that data array (copies share it)
    _deviation_power = None
    #: ``(noise_bins array, device tensor [1, 1, 1, 1, N])`` (:meth:`_keep`)
    _keep_t = None

    def __getstate__(self):
        """Pickle without the Dr.Jit tensors (rebuilt from ``Y_numpy``, ``b``
        and the context's basis): half the bytes for worker processes."""
        return {k: v for k, v in self.__dict__.items()
                if k not in self._TENSORS and k != "_keep_t"}

    def __setstate__(self, state):
        self.__dict__.update(state)
        self.Y = ops.tensor(self.Y_numpy)
        self.y_t = ops.tensor(self.y)
        self.b_t = ops.tensor(self.b)
        self.basis_t = self._basis_tensors()

    def _basis_tensors(self):
        """Per-object base components (scaled like ``b``), or None without a
        basis: ``[1, T, R, 1, N]`` when the basis is the same in every chirp
        loop (a static scene), else ``[1, T, R, C, N]``; :meth:`_base`
        broadcasts their sum to the model's shape.  The scene-side effects
        then run on ``1 / (F C)`` of the samples: on a 16-chirp cascade
        capture a loss-and-gradient evaluation beside ego motion takes 0.35
        instead of 0.80 s, to the same value."""
        if self.ctx.basis is None:
            return None
        k = self.base_gain / self.scale
        adc = self.ctx.basis.adc                                      # [K, T, R, C, N]
        if adc.shape[3] > 1 and np.array_equal(adc, np.broadcast_to(adc[:, :, :, :1], adc.shape)):
            adc = adc[:, :, :, :1]
        return [ops.tensor(B[None] * k) for B in adc]

    def on_chirp_deviation(self, cells=None) -> "EffectModel":
        """A copy measuring the current mean model plus the residual's
        deviation from its chirp mean, ``x + (r - mean_c r) sqrt(C / (C - 1))``
        (:func:`~.library._sensor_common.chirp_deviation`): the chirp-to-chirp
        scatter a stationary noise model must predict (:meth:`nll_profiled`
        with ``deviation``), without the chirp-mean misfit that is the mean
        model's to explain, and without what :meth:`predict_deviation`
        predicts from the other cells among ``cells`` (None: all).  ``self``
        with one chirp loop."""
        if self.ctx.shape[3] < 2:
            return self
        x, v, d = self._deviation_state()
        if self.deviation_predictors():
            d = d - self.predict_deviation(x, d, v, cells)
        new = self.copy()
        new.y = x + d
        new.Y_numpy = np.fft.fft(new.y, axis=-1, norm="ortho")
        new.Y = ops.tensor(new.Y_numpy)
        new.y_t = ops.tensor(new.y)
        return new

    def fit_to_scatter(self, trainable, cells=None, maxiter: int = 200) -> None:
        """Fit ``trainable`` components and the nuisance on
        :meth:`on_chirp_deviation` and keep the values (a noise model fitted
        where it is scored: to the whole residual it would widen its variance
        at the scene misfit and overpredict the scatter)."""
        self._fit_deviation_predictors(trainable, cells)
        dev = self.on_chirp_deviation(cells)
        if dev is self:
            self.fit(trainable=trainable, cells=cells, maxiter=maxiter)
            return
        dev.fit(trainable=trainable, cells=cells, maxiter=maxiter)
        self.restore(dev.snapshot())

    def deviation_predictors(self) -> list:
        """Components that predict a cell's chirp deviation from the other cells."""
        return [c for c in self.components if c.effect.predicts_deviation]

    def _deviation_state(self) -> tuple:
        """``(x, v, d)``: the current mean (time domain), its per-bin variance
        and the residual's chirp deviation (None with one chirp loop)."""
        from .library._sensor_common import chirp_deviation

        x, v = self.mean_variance_numpy()
        return x, v, chirp_deviation(self.y - x)

    def predict_deviation(self, x, d, v, cells=None) -> np.ndarray:
        """What the components that predict deviations
        (``effect.predicts_deviation``: the LO's common frequency error,
        :class:`~.library.phase_noise.PhaseNoise`) explain of the chirp
        deviation ``d`` (time domain ``[F, T, R, C, N]``) of each cell from the
        other cells among ``cells`` (boolean ``[F, T, R, C]``; None: all);
        ``x`` and ``v`` the current mean (time domain) and per-bin variance."""
        out = np.zeros_like(d)
        for c in self.deviation_predictors():
            out = out + c.effect.deviation_prediction(x, d, c.values, self.ctx, v, cells)
        return out

    def _fit_deviation_predictors(self, trainable, cells=None) -> None:
        """Fit what the ``trainable`` components that predict deviations
        predict with (``effect.fit_deviation``) on the residual's chirp
        deviation over ``cells``: outside the Dr.Jit likelihood, which holds
        their variance only."""
        picked = [self.components[i] for i in (trainable or [])
                  if self.components[i].effect.predicts_deviation]
        if not picked or self.ctx.shape[3] < 2:
            return
        x, v, d = self._deviation_state()
        for c in picked:
            c.values = c.effect.fit_deviation(x, d, c.values, self.ctx, v, cells)

    def copy(self) -> "EffectModel":
        """Shallow copy with independent component values (tensors are shared)."""
        new = object.__new__(EffectModel)
        new.__dict__.update(self.__dict__)
        new.nuisance = self.nuisance.copy()
        new.components = [c.copy() for c in self.components]
        return new

    def snapshot(self) -> tuple:
        """``(nuisance values, [component values])``, copied: what
        :meth:`restore` gives back to this model or to one with the same
        components (a copy, its chirp average)."""
        def copied(values):
            return {k: np.array(v, copy=True) for k, v in values.items()}
        return copied(self.nuisance.values), [copied(c.values) for c in self.components]

    def restore(self, snapshot) -> None:
        """Take the values of a :meth:`snapshot` (component objects kept)."""
        nuisance, values = snapshot
        self.nuisance.values = nuisance
        for c, v in zip(self.components, values):
            c.values = v

    # ------------------------------------------------------------- forward
    def _components(self, tens: dict, order):
        """Per-object base components after the scene-side effects (list of pairs)."""
        B = list(self.basis_t)
        for i in order:
            if self.components[i].effect.kind == "basis":
                B = self.components[i].effect.apply_basis(
                    B, _block(tens, i, self.components[i]), self.ctx)
        return B

    def _base(self, tens: dict, order, frozen=None):
        """The base before the sensor chain: ``b``, or the sum of the per-object
        components after the scene-side (``kind = "basis"``) effects; ``frozen``
        a precomputed value (the scene-side effects are not being fitted)."""
        if frozen is not None:
            return frozen
        if self.basis_t is None or not any(self.components[i].effect.kind == "basis"
                                           for i in order):
            return self.b_t
        B = self._components(tens, order)
        out = B[0]
        for b in B[1:]:
            out = ops.cadd(out, b)
        return self._broadcast(out)

    def _broadcast(self, z):
        """A complex pair of a (broadcastable) smaller shape evaluated once and
        spread to the model's ``[F, T, R, C, N]`` (the per-object basis is
        kept per chirp loop only where it differs between them) by one
        gather (its adjoint a scatter-add); Dr.Jit's implicit tensor
        broadcasting cost 3x more than the full-size basis on an AWR1843
        capture."""
        shape = tuple(self.ctx.shape)
        if tuple(z[0].shape) == shape:
            return z
        dr.eval(z[0], z[1])
        idx = _broadcast_index(tuple(z[0].shape), shape)
        return tuple(mi.TensorXf(dr.gather(mi.Float, a.array, idx), shape) for a in z)

    def _order(self):
        """Component indices in chain order (:attr:`~.base.Effect.chain_key`)."""
        return sorted(range(len(self.components)),
                      key=lambda i: self.components[i].effect.chain_key)

    def frozen_base(self):
        """The base after the scene-side effects at their current values, evaluated
        once (detached) for fits that leave them fixed; ``None`` without any."""
        if self.basis_t is None or not any(c.effect.kind == "basis" for c in self.components):
            return None
        with dr.suspend_grad():
            b = self._base(self._tensors(), self._order())
            dr.eval(b[0], b[1])
        return b

    @_one_thread
    def component_shares(self) -> np.ndarray:
        """Energy fraction of each per-object base component in the current model."""
        with dr.suspend_grad():
            B = self._components(self._tensors(), self._order())
            e = np.array([float(np.sum(np.abs(ops.to_numpy(b)) ** 2)) for b in B])
        return e / max(e.sum(), 1e-300)

    def _mean(self, tens: dict, order, frozen=None):
        """The mean ADC ``x`` (time domain) from tensors ``tens[(i, name)]``;
        ``frozen`` the base after the scene-side effects
        (:meth:`frozen_base`) or the model up to the first fitted component
        (:class:`_Prefix`), evaluated once for a fit that holds it."""
        g = tens[(-1, "gain")]
        one = (1, 1, 1, 1, 1)
        gain = (ops.column(ops.view(g, (1, 2)), 0, one), ops.column(ops.view(g, (1, 2)), 1, one))
        if isinstance(frozen, _Prefix):
            x = ops.cadd(frozen.p0, ops.cmul(frozen.d, gain))
            order = [i for i in order if i not in frozen.skip]
        else:
            b = self._base(tens, order, frozen)
            x = ops.cmul(b, gain) if self.has_base else ops.zeros_like(self.b_t)
        for i in order:
            c = self.components[i]
            if c.effect.kind == "mean":
                x = c.effect.apply(x, _block(tens, i, c), self.ctx)
        return x

    #: relative error allowed where :meth:`frozen_prefix` checks that the
    #: held chain is affine in the nuisance gain (float32 evaluations)
    PREFIX_TOL = 1e-4

    @_one_thread
    def frozen_prefix(self, trainable) -> "_Prefix | None":
        """The mean model up to the first of the ``trainable`` components in
        chain order, for a fit that holds everything before it: ``x(g) = p0
        + g d`` in the nuisance gain ``g``, evaluated once instead of at
        every step (a candidate fitted beside an adopted ego motion does not
        move the scene through it again).

        Valid where the held chain is affine in the base (linear maps such as
        ego motion or per-channel gains, added paths such as a mover), which
        is checked at the current and a third gain; what the held effects
        derive from their input (ego motion's geometry) is held at what the
        current gain gives (:meth:`~.base.Effect.held_state`).  None where
        the chain is not affine (IQ imbalance), where no mean effect is
        held, or where a scene-side component sits after the first trainable
        one."""
        if not self.has_base:
            return None
        order = self._order()
        pos = min((order.index(i) for i in trainable), default=len(order))
        held = order[:pos]
        if not any(self.components[i].effect.kind == "mean" for i in held) \
                or any(self.components[i].effect.kind == "basis" for i in order[pos:]):
            return None
        g = self.nuisance.values["gain"]
        with dr.suspend_grad(), contextlib.ExitStack() as stack:
            for i in held:
                stack.enter_context(self.components[i].effect.held_state())
            tens = self._tensors()

            def at(re, im):
                tens[(-1, "gain")] = mi.TensorXf(np.array([re, im], np.float32))
                return ops.to_numpy(self._mean(tens, held))
            now = at(float(g[0]), float(g[1]))      # what the held effects derive: from here
            p0, p1, pt = at(0.0, 0.0), at(1.0, 0.0), at(0.6, -0.7)
        d = p1 - p0
        for gain, x in ((complex(g[0], g[1]), now), (0.6 - 0.7j, pt)):
            err = np.sum(np.abs(p0 + gain * d - x) ** 2)
            if not err <= self.PREFIX_TOL ** 2 * max(np.sum(np.abs(x) ** 2), 1e-300):
                return None
        p0t, dt = ops.tensor(p0), ops.tensor(d)
        dr.eval(p0t[0], p0t[1], dt[0], dt[1])
        return _Prefix(p0=p0t, d=dt, skip=frozenset(held))

    def _white(self) -> bool:
        """Whether the variance is the white floor alone (no noise shaper, spread
        or variance effect): the NLL is then the same in the time domain."""
        return not any(c.effect.kind == "variance" or c.effect.has_spread
                       or getattr(c.effect, "shapes_noise", False) for c in self.components)

    def _forward(self, tens: dict, frozen=None):
        """``(x, X, v)`` from tensors ``tens[(i, name)]`` (``i = -1`` nuisance)."""
        order = self._order()
        x = self._mean(tens, order, frozen)
        X = ops.dft(x)
        gains = {i: self.components[i].effect.noise_gain(_block(tens, i, self.components[i]),
                                                         self.ctx)
                 for i in self._noise_shapers(order)}
        v = dr.exp(ops.view(tens[(-1, "log_noise")], (1, 1, 1, 1, 1)))
        for g in gains.values():
            v = v * g
        for i in order:
            c = self.components[i]
            if c.effect.kind == "mean" and c.effect.has_spread:
                w = c.effect.spread(_block(tens, i, c), self.ctx)
                for j, g in gains.items():           # filtered by the shapers after it
                    if self.components[j].effect.chain_key > c.effect.chain_key:
                        w = w * g
                v = v + w
            elif c.effect.kind == "variance":
                v = v + c.effect.variance(x, X, _block(tens, i, c), self.ctx)
        return x, X, v

    def _noise_shapers(self, order=None) -> list:
        """Indices of the mean components that filter the white floor."""
        order = self._order() if order is None else order
        return [i for i in order if self.components[i].effect.kind == "mean"
                and getattr(self.components[i].effect, "shapes_noise", False)]

    @_one_thread
    def white_shape_numpy(self) -> np.ndarray:
        """``s``: the power gain on the white floor, broadcast to ``[F, T, R, C, N]``."""
        s = np.ones(self.ctx.shape)
        shapers = self._noise_shapers()
        if shapers:
            with dr.suspend_grad():
                tens = self._tensors()
                for i in shapers:
                    g = self.components[i].effect.noise_gain(_block(tens, i, self.components[i]),
                                                             self.ctx)
                    s = s * np.asarray(ops.to_numpy(g), np.float64)
        return s

    def _tensors(self, grad_keys=()):
        tens = {}
        for i, c in self._all():
            for k, val in c.values.items():
                t = mi.TensorXf(np.ascontiguousarray(val, np.float32))
                if (i, k) in grad_keys:
                    dr.enable_grad(t)
                tens[(i, k)] = t
        return tens

    def _all(self):
        yield -1, self.nuisance
        yield from enumerate(self.components)

    @_one_thread
    def mean_variance_numpy(self):
        """Current model: mean ADC ``[F, T, R, C, N]`` (time domain, normalised units)
        and noise variance per range bin (broadcast to the same shape)."""
        with dr.suspend_grad():
            x, X, v = self._forward(self._tensors())
            v = v + dr.zeros(mi.TensorXf, X[0].shape)
        return ops.to_numpy(x), ops.to_numpy(v)

    def mean_adc(self) -> np.ndarray:
        """Mean model ADC in the capture's units, complex128 ``[F, T, R, C, N]``."""
        return self.mean_variance_numpy()[0] * self.scale

    def residual(self) -> np.ndarray:
        """Measured minus mean model, capture units, ``[F, T, R, C, N]``."""
        return (self.y - self.mean_variance_numpy()[0]) * self.scale

    def residual_energy(self, cells=None) -> float:
        """``sum |y - x|^2`` over ``cells`` (boolean ``[F, T, R, C]``, None: all),
        normalised units: the mean model's squared error, whatever its
        variance model."""
        r = self.y - self.mean_variance_numpy()[0]
        return float(np.sum(np.abs(r if cells is None else r[np.asarray(cells, bool)]) ** 2))

    def shaped_energy(self, cells=None, shape=None) -> float:
        """``sum |Y - X|^2 / s`` over ``cells`` (None: all), normalised units:
        the mean model's squared error in units of the receiver noise the
        adopted noise shapers leave in each range bin, ``s`` their power gain
        on the white floor (:meth:`white_shape_numpy`, or ``shape`` given, e.g.
        the model's before a candidate was added).  Without a shaper ``s = 1``
        and it is :meth:`residual_energy` (Parseval)."""
        return self.energy_by_bin(cells, shape)[2]

    def energy_by_bin(self, cells=None, shape=None) -> tuple:
        """``(residual, model, shaped)``: ``sum |Y - X|^2`` and ``sum |X|^2`` per
        range bin (unitary DFT) over ``cells`` (None: all), ``[N]`` each,
        normalised units: where in range the mean model misses and where its
        power is; and the residual's :meth:`shaped_energy` (``shape`` as there),
        from the same evaluation of the model."""
        x = self.mean_variance_numpy()[0]
        s = self.white_shape_numpy() if shape is None else np.asarray(shape)
        keep = (slice(None),) * 4 if cells is None else np.asarray(cells, bool)
        X = np.fft.fft(x[keep], axis=-1, norm="ortho")
        r2 = np.abs(self.Y_numpy[keep] - X) ** 2
        cellwise = tuple(range(X.ndim - 1))
        shaped = np.sum(r2 / np.maximum(np.broadcast_to(s, self.ctx.shape)[keep], 1e-12))
        return np.sum(r2, axis=cellwise), np.sum(np.abs(X) ** 2, axis=cellwise), float(shaped)

    # ---------------------------------------------------------------- loss
    def mask_tensor(self, cells=None):
        """0/1 weights ``[F, T, R, C, N]`` from a boolean ``[F, T, R, C]`` cell mask (None: all)."""
        F, T, R, C, N = self.ctx.shape
        if cells is None:
            cells = np.ones((F, T, R, C), bool)
        cells = np.asarray(cells, bool)
        if cells.shape != (F, T, R, C):
            raise InputValueError(f"mask: shape {cells.shape} != cells {(F, T, R, C)}")
        if not cells.any():
            raise InputValueError("mask: selects no cells")
        m = np.broadcast_to(cells[..., None], (F, T, R, C, N)).astype(np.float32)
        return mi.TensorXf(np.ascontiguousarray(m)), float(m.sum())

    @_one_thread
    def nll(self, cells=None) -> float:
        """Mean NLL per complex sample over ``cells`` (nats), current values."""
        mask, n = self.mask_tensor(cells)
        with dr.suspend_grad():
            return ops.item(self.loss(self._tensors(), mask, n))

    def nll_profiled(self, cells=None, per_cell: bool = False, by_slot: bool = False,
                     deviation: bool = False, split=None):
        """Mean NLL per complex sample over ``cells`` with the white floor
        ``sigma^2`` re-estimated on those cells (the NLL minimised over
        ``sigma^2`` alone, every other parameter as is).

        The held-out score of the diagnosis: a ``sigma^2`` fitted on training
        cells carries whatever residual those cells cannot explain, so a
        candidate that shrinks it there (by absorbing a disturbance confined
        to the training cells) would otherwise be credited on every held-out
        cell through ``log sigma^2``.  Profiling the one scale parameter on the
        scored cells, for the base and the candidate alike, credits only what
        a candidate predicts there.  Without variance effects it is
        ``log(mean |Y - X|^2 / s) + 1 + mean log s``.

        With ``per_cell`` it returns ``(mean, per-cell mean NLL over the
        selected cells [n_cells])`` at the profiled floor; with ``by_slot``
        the floor is profiled per transmit slot (frame, Tx, chirp: in TDM-MIMO
        every Tx fires in its own slot) instead, so a disturbance confined to
        a few slots raises only their floor.

        With ``deviation`` (two or more chirp loops) the residual is replaced
        by its deviation from its own mean over the chirp loops, scaled by
        ``C / (C - 1)`` (the expected power of a deviation of independent
        chirps): the chirp-to-chirp scatter a stationary noise model must
        predict, without the chirp-mean misfit that is the mean model's to
        explain.  With ``deviation="median"`` it is the deviation from the
        median over the chirp loops (per range bin, real and imaginary parts),
        which a disturbance in a few chirps does not move: it stays in those
        chirps instead of leaking ``1 / C`` of itself into every other one (for
        judging where a noise model helps, ``by_slot``; the scale is not
        corrected, which the profiled floors absorb).  The cells must hold
        every chirp loop of their channels.

        With ``deviation``, what the components that predict a cell's
        deviation from the other cells (:meth:`predict_deviation`: the LO's
        common frequency error) explain is taken out first.

        ``split`` (None: :meth:`split_likelihood`): without ``deviation``, the
        NLL of :meth:`_split_loss`, the chirp mean with its own profiled white
        floor (each cell carries ``1 / C`` of its channel's) and the deviation
        under the profiled shaped floor on :meth:`noise_bins`; ``True`` scores
        a model without a noise shaper on the scale of one with it.
        """
        x, v = self.mean_variance_numpy()
        cells = np.ones(self.ctx.shape[:4], bool) if cells is None else np.asarray(cells, bool)
        if cells.shape != self.ctx.shape[:4] or not cells.any():
            raise InputValueError(f"mask: shape {cells.shape} != cells {self.ctx.shape[:4]} "
                                  "or selects no cells")
        r = self.Y_numpy - np.fft.fft(x, axis=-1, norm="ortho")
        C = self.ctx.shape[3]
        split = self.split_likelihood() if split is None else bool(split)
        mean_cell = 0.0
        if split and not deviation and C > 1:
            rm = r.mean(axis=3, keepdims=True)
            em = np.abs(np.broadcast_to(rm, r.shape)[cells]) ** 2
            wm = max(float(np.mean(em)), 1e-30)
            mean_cell = np.mean(em / wm + np.log(wm), axis=-1) / C
            r = (r - rm) * np.sqrt(C / (C - 1))
        if deviation == "median" and C > 1:
            r = r - (np.median(r.real, axis=3, keepdims=True)
                     + 1j * np.median(r.imag, axis=3, keepdims=True))
        elif deviation and C > 1:
            r = (r - r.mean(axis=3, keepdims=True)) * np.sqrt(C / (C - 1))
        if deviation and C > 1 and self.deviation_predictors():
            d = np.fft.ifft(r, axis=-1, norm="ortho")
            r = np.fft.fft(d - self.predict_deviation(x, d, v), axis=-1, norm="ortho")
        r2 = np.abs(r[cells]) ** 2
        s = np.broadcast_to(self.white_shape_numpy(), v.shape)
        extra = (v - float(np.exp(self.nuisance.values["log_noise"][0])) * s)[cells]
        s = s[cells]
        kept = 1.0
        if split and not deviation and C > 1:
            keep = self.noise_bins()
            r2, s, extra, kept = r2[:, keep], s[:, keep], extra[:, keep], keep.mean()
        if not by_slot:
            cell_nll = _profiled_cells(r2, s, extra)
        else:
            f, t, _, c = np.nonzero(cells)
            slot = (f * self.ctx.shape[1] + t) * self.ctx.shape[3] + c
            cell_nll = np.empty(len(slot))
            for k in np.unique(slot):
                sel = slot == k
                cell_nll[sel] = _profiled_cells(r2[sel], s[sel], extra[sel])
        if split and not deviation and C > 1:
            cell_nll = mean_cell + cell_nll * ((C - 1) / C * kept)
        return (float(np.mean(cell_nll)), cell_nll) if per_cell else float(np.mean(cell_nll))

    def loss(self, tens, mask, n, frozen=None):
        """Masked mean NLL ``sum mask (|Y - X|^2 / v + log v) / n`` as a Dr.Jit value (AD).

        With a white floor alone (:meth:`_white`) it is computed in the time
        domain, ``sum mask (|y - x|^2 / sigma^2 + log sigma^2) / n``, equal by
        Parseval (the mask holds whole rows): no DFT and its gradient."""
        if self.split_likelihood():
            return self._split_loss(tens, mask, n, frozen)
        if self._white():
            x = self._mean(tens, self._order(), frozen)
            dr.eval(x[0], x[1])          # once, as the DFT's input would be
            r2 = ops.abs2((self.y_t[0] - x[0], self.y_t[1] - x[1]))
            ln_v = ops.view(tens[(-1, "log_noise")], (1, 1, 1, 1, 1))
            return dr.sum((r2 * dr.exp(-ln_v) + ln_v) * mask, axis=None) / n
        _, X, v = self._forward(tens, frozen)
        r2 = ops.abs2((self.Y[0] - X[0], self.Y[1] - X[1]))
        return dr.sum((r2 / v + dr.log(v)) * mask, axis=None) / n

    def split_likelihood(self) -> bool:
        """Whether the NLL is split into the chirp mean and the chirp-to-chirp
        deviation (:meth:`_split_loss`): with two or more chirp loops and a
        component that shapes the receiver noise (an IF filter)."""
        return (self.ctx.shape[3] > 1 or self._deviation is not None) \
            and bool(self._noise_shapers())

    def _keep(self):
        """:meth:`noise_bins` as a 0/1 device tensor ``[1, 1, 1, 1, N]``, made once
        per bins array (the split losses read it at every evaluation)."""
        bins = self.noise_bins()
        if self._keep_t is None or self._keep_t[0] is not bins:
            N = self.ctx.shape[4]
            self._keep_t = (bins, ops.tensor(bins.astype(np.float64).reshape(1, 1, 1, 1, N)))
        return self._keep_t[1]

    def noise_bins(self) -> np.ndarray:
        """``[N]`` bool: the range bins whose chirp-to-chirp scatter in the
        data is receiver noise alone (:func:`~.library._sensor_common.noise_bins`;
        all with one chirp loop).  The split likelihood's deviation term is
        taken over these: a mover's or a drooping target's bins would
        otherwise inflate the floor a noise shape is judged against."""
        if getattr(self, "_noise_bins", None) is None:
            from .library._sensor_common import bin_power, chirp_deviation, noise_bins

            dev = chirp_deviation(self.y)
            self._noise_bins = (np.ones(self.ctx.shape[-1], bool) if dev is None
                                else noise_bins(bin_power(dev)))
        return self._noise_bins

    def _split_loss(self, tens, mask, n, frozen=None):
        """The NLL of a model whose static misfit is not receiver noise.

        The residual ``R_c = Y_c - X_c`` of chirp loop ``c`` splits into its
        chirp mean ``Rm`` and the deviation ``D_c = R_c - Rm``.  The receiver
        noise (variance ``v``: the shaped floor and the variance effects) is
        all there is in the deviation (``C - 1`` degrees of freedom in ``C``
        samples); the chirp mean also carries what the mean model leaves
        unexplained, the same in every chirp (a leakage the separable
        coupling cannot fit, diffuse clutter the mesh lacks), which is not
        noise and has no noise shape.  So the mean is scored with its own
        white variance, profiled (``n_m (log mean |Rm|^2 + 1)``), and the
        deviation under ``v``::

            nll = [n_m (log mean |Rm|^2 + 1) + sum (|D_c|^2 / v + (C - 1) / C log v)] / n

        (``n_m = n / C`` chirp-mean samples; cells hold every chirp loop of
        their channels; the deviation summed over :meth:`noise_bins`).  Under
        the plain likelihood a noise notch at near-DC bins makes any static
        misfit there cost tens of dB more, and a filter's fit drops the notch
        it is seen by."""
        if self._deviation is not None:
            return self._split_loss_averaged(tens, mask, n, frozen)
        C, N = self.ctx.shape[3], self.ctx.shape[4]
        shape = self.ctx.shape[:3] + (1, N)
        _, X, v = self._forward(tens, frozen)
        R = (self.Y[0] - X[0], self.Y[1] - X[1])
        Rm = tuple(ops.view(dr.sum(r, axis=3), shape) * (1.0 / C) for r in R)
        w = ops.view(dr.sum(mask, axis=3), shape) * (1.0 / C)       # the channels' 0/1
        n_m = n / C
        e_m = dr.sum(ops.abs2(Rm) * w, axis=None) / n_m
        mean_term = n_m * (dr.log(e_m + 1e-30) + 1.0)
        D2 = ops.abs2((R[0] - Rm[0], R[1] - Rm[1]))
        keep = self._keep()
        dev_term = dr.sum((D2 / v + ((C - 1) / C) * dr.log(v)) * mask * keep, axis=None)
        return (mean_term + dev_term) / n

    def _split_loss_averaged(self, tens, mask, n, frozen=None):
        """:meth:`_split_loss` of the full model on its :meth:`split_averaged`
        counterpart (``mask`` and ``n`` over the averaged cells): with a
        chirp-static mean the deviation ``D_c`` is the data's own, so its
        term is ``sum (S / v + (C - 1) log v)`` over the averaged cells."""
        _, S, C = self._deviation
        N = self.ctx.shape[4]
        _, X, v = self._forward(tens, frozen)
        R = (self.Y[0] - X[0], self.Y[1] - X[1])
        e_m = dr.sum(ops.abs2(R) * mask, axis=None) / n
        mean_term = n * (dr.log(e_m + 1e-30) + 1.0)
        keep = self._keep()
        dev_term = dr.sum((S / v + (C - 1) * dr.log(v)) * mask * keep, axis=None)
        return (mean_term + dev_term) / (n * C)

    def split_averaged(self, cells=None) -> "EffectModel | None":
        """This model on the chirp average, scoring exactly its split NLL
        (:meth:`_split_loss`), or None where that is not exact.

        With a noise shaper (an IF filter) the NLL splits into the chirp
        mean and the chirp-to-chirp deviation; where every component is the
        same in every chirp (:meth:`static_flags`, noise models included)
        the residual's deviation is the data's own, so the deviation term
        needs only its power per averaged sample, computed once.  A fit
        there sees the same objective at ``1 / C`` of the work.  Needs two or
        more chirp loops and ``cells`` (boolean ``[F, T, R, C]``) holding
        every chirp of their channels; the white floor keeps its value (it
        is the single chirp's, as in the deviation term)."""
        C = self.ctx.shape[3]
        if C < 2 or not self.split_likelihood() or not all(self.static_flags()):
            return None
        if cells is not None:
            cells = np.asarray(cells, bool)
            if not np.array_equal(cells, np.broadcast_to(cells[..., :1], cells.shape)):
                return None
        bins = self.noise_bins()
        cached = self._deviation_power          # the data's: once per data array
        if cached is None or cached[0] is not self.Y_numpy:
            D = self.Y_numpy - self.Y_numpy.mean(axis=3, keepdims=True)
            self._deviation_power = cached = (self.Y_numpy,
                                              np.sum(np.abs(D) ** 2, axis=3, keepdims=True))
        S = cached[1]
        new = self.chirp_averaged()
        new.nuisance.values["log_noise"] = np.array(self.nuisance.values["log_noise"], copy=True)
        new._deviation = (S, ops.tensor(S), C)
        new._noise_bins = bins
        return new

    # ----------------------------------------------------------------- fit
    def _rescale_gain(self, cells=None) -> None:
        """Start the global gain at the least-squares scale of the current model.

        An effect added to a fitted model can change its level by orders of
        magnitude (an IF filter that removes most of a strong near-DC tone the
        base gain had been fitted to); L-BFGS-B started from the old gain may
        then settle far from the data.  The gain is multiplied by
        ``<x, y> / <x, x>`` over ``cells`` (exact where the model is linear in
        it) and kept only if the NLL drops.
        """
        if not self.has_base:
            return
        mask = np.ones(self.ctx.shape[:4], bool) if cells is None else np.asarray(cells, bool)
        x = self.mean_variance_numpy()[0][mask]
        e = float(np.vdot(x, x).real)
        if not e > 0:
            return
        k = complex(np.vdot(x, self.y[mask]) / e)
        if abs(k - 1.0) < 1e-3:
            return
        old = np.array(self.nuisance.values["gain"], np.float64)
        before = self.nll(cells)
        g = complex(old[0], old[1]) * k
        self.nuisance.values["gain"] = np.array([g.real, g.imag])
        if not self.nll(cells) < before:
            self.nuisance.values["gain"] = old

    def _rescale_noise(self, cells=None) -> None:
        """Start the white floor at its closed-form optimum on ``cells``.

        A component initialised by least squares can shrink the residual by
        orders of magnitude; with the floor left at the old level L-BFGS-B
        sees a badly scaled problem and stops early.  The profiled floor
        (mean ``|Y - X|^2``) is kept only if it lowers the NLL (variance
        effects add to the floor).
        """
        mask = np.ones(self.ctx.shape[:4], bool) if cells is None else np.asarray(cells, bool)
        r2 = np.abs(self.y - self.mean_variance_numpy()[0]) ** 2
        level = float(np.mean(r2[mask]))
        if self._deviation is not None:     # every chirp's: mean |y_c - x|^2 = |mean y - x|^2 + S / C
            S, _, C = self._deviation
            level += float(np.mean(S[mask])) / C
        old = np.array(self.nuisance.values["log_noise"], np.float64)
        before = self.nll(cells)
        self.nuisance.values["log_noise"] = np.array([np.log(max(level, 1e-12))])
        if not self.nll(cells) < before:
            self.nuisance.values["log_noise"] = old

    @_one_thread
    def fit(self, trainable=None, cells=None, maxiter: int = 200, nuisance: bool = True) -> dict:
        """Fit parameters by L-BFGS-B with Dr.Jit gradients of the masked NLL.

        ``trainable``: component indices (None: all); the nuisance gain and
        noise floor are fitted too unless ``nuisance=False``.  Returns
        ``{"nll", "iterations", "success"}``.
        """
        work = self.split_averaged(cells)
        if work is not None:                   # the same objective at 1 / C of the work
            out = work.fit(trainable, None if cells is None else np.asarray(cells)[..., :1],
                           maxiter, nuisance)
            self.restore(work.snapshot())
            return out
        idx = list(range(len(self.components))) if trainable is None else list(trainable)
        keys = []
        if nuisance:
            keys += [(-1, k) for k in self.nuisance.specs
                     if not (k == "gain" and not self.has_base)]
        for i in idx:
            keys += [(i, k) for k in self.components[i].specs]
        if not keys:
            return {"nll": self.nll(cells), "iterations": 0, "success": True}
        if (-1, "gain") in keys:
            self._rescale_gain(cells)
        if (-1, "log_noise") in keys:
            self._rescale_noise(cells)
        comps = dict(self._all())
        specs = [comps[i].specs[k] for i, k in keys]
        x0 = np.concatenate([np.asarray(comps[i].values[k], np.float64).ravel() for i, k in keys])
        bounds = sum((s.bounds() for s in specs), [])
        mask, n = self.mask_tensor(cells)
        with self.held():
            frozen = self.frozen_prefix(idx)
            if frozen is None and not any(i >= 0 and self.components[i].effect.kind == "basis"
                                          for i, _ in keys):
                frozen = self.frozen_base()
            res = self._minimize(keys, specs, x0, bounds, mask, n, frozen, maxiter)
        for (i, k), val in _unpack(res.x, keys, specs).items():
            comps[i].values[k] = val
        return {"nll": float(res.fun), "iterations": int(res.nit), "success": bool(res.success)}

    def held(self) -> contextlib.ExitStack:
        """A context holding what every component derives from its input
        (:meth:`~.base.Effect.held_state`: ego motion's geometry) at what it
        first derives inside: one fit sees one smooth objective, and the
        geometry follows the scene from one fit to the next."""
        stack = contextlib.ExitStack()
        for c in self.components:
            stack.enter_context(c.effect.held_state())
        return stack

    def _minimize(self, keys, specs, x0, bounds, mask, n, frozen, maxiter):
        """L-BFGS-B over the flattened values of ``keys`` (:meth:`fit`)."""
        key_set = set(keys)
        comps = dict(self._all())

        def fun(vec):
            for (i, k), val in _unpack(vec, keys, specs).items():
                comps[i].values[k] = val
            tens = self._tensors(grad_keys=key_set)
            loss = self.loss(tens, mask, n, frozen)
            dr.backward(loss)
            grads = [dr.grad(tens[key]) for key in keys]
            dr.eval(loss, *grads)                    # one kernel for the loss and every gradient
            grad = np.concatenate([np.asarray(g, np.float64).ravel() for g in grads])
            val = ops.item(loss)
            if not np.isfinite(val):
                return 1e30, np.zeros_like(vec)
            return val, np.nan_to_num(grad)

        return minimize(fun, x0, jac=True, method="L-BFGS-B", bounds=bounds,
                        options={"maxiter": int(maxiter), "ftol": FIT_FTOL, "gtol": 1e-9,
                                 "maxcor": 20})


def _unpack(vec, keys, specs) -> dict:
    """``{key: value}`` from the flat parameter vector of :meth:`EffectModel.fit`."""
    out, o = {}, 0
    for key, s in zip(keys, specs):
        out[key] = vec[o:o + s.size].reshape(s.init.shape)
        o += s.size
    return out


@dataclasses.dataclass(frozen=True)
class _Prefix:
    """The held part of the chain (:meth:`EffectModel.frozen_prefix`):
    ``x = p0 + g d`` (complex pairs ``[F, T, R, C, N]``) replaces the base
    and the components in ``skip``."""

    p0: tuple
    d: tuple
    skip: frozenset


def _profiled_cells(r2, s, extra) -> np.ndarray:
    """Per-cell mean NLL ``mean_k (r2 / tot + log tot)``, ``tot = sigma^2 s + extra``,
    at the ``sigma^2`` that minimises the total over these cells; 1e30 where a
    model that overflowed left non-finite residuals (the candidate then
    scores far below zero instead of stopping the loop)."""
    if not (np.all(np.isfinite(r2)) and np.all(np.isfinite(extra))):
        return np.full(r2.shape[:-1], 1e30)
    extra = np.maximum(extra, 0.0)
    if not np.any(extra > 0):
        ls = np.log(max(np.mean(r2 / s), 1e-30))
    else:
        def f(ls):
            tot = np.exp(ls) * s + extra
            return float(np.mean(r2 / tot + np.log(tot)))

        hi = np.log(max(np.mean(r2 / s), 1e-30)) + 1.0
        ls = float(minimize_scalar(f, bounds=(hi - 40.0, hi), method="bounded",
                                   options={"xatol": 1e-6}).x)
    tot = np.exp(ls) * s + extra
    return np.mean(r2 / tot + np.log(tot), axis=-1)


def _block(tens, i, comp):
    return {k: tens[(i, k)] for k in comp.specs}

"""Residual diagnosis: rank candidate effects by held-out likelihood gain, adopt, repeat.

For every candidate effect not yet adopted, and every cross-validation fold:

1. the current model (adopted effects frozen, nuisance gain and noise floor
   refitted) is fitted on the fold's training cells and scored on its
   held-out cells: ``NLL_0``;
2. the candidate is added on top (initialised from the training cells only),
   fitted on the training cells, and scored on the held-out cells: ``NLL_1``.

Both scores profile the white noise floor on the held-out cells
(:meth:`~sionna_mmir.effects.model.EffectModel.nll_profiled`): a floor
fitted on training cells carries their unexplained residual, and a
candidate that absorbs a disturbance confined to training cells would be
credited on every held-out cell through it.

Its held-out gain is ``sum over folds (NLL_0 - NLL_1)`` in nats (total over
held-out complex samples); its score subtracts ``penalty`` nats per real
parameter: by default ``ln(n) / 2`` with ``n`` the held-out complex samples
the candidate was scored on (the BIC's weight, :func:`~.ranking.penalty_per_param`), or
a fixed number.  The held-out gain alone already charges a candidate for
fitting noise, but not for fitting the structured misfit that every real
scene leaves (clutter the mesh lacks): a 28-number per-channel delay bends to
that misfit and predicts held-out channels by a few nats per parameter, on a
clean capture as on any other, while a sensor effect that is really there
gains hundreds to thousands of nats per parameter.  A penalty that grows with
the data keeps those few nats from adding up to an adoption.

Folds hold out whole virtual channels (a Tx-Rx pair, all its frames and
chirps), keeping every Tx and every Rx in every training set, so an effect
is only credited for what it predicts on channels it never saw: a per-Tx x
per-Rx structure generalises, a disturbance confined to one channel does
not.  Where the array is too small for that (fewer virtual channels than
``2 folds``, or a Tx / Rx would drop out), whole (frame, Tx, Rx, chirp)
cells are held out instead.

Mean before variance.  A variance effect (phase-noise skirt, coloured noise
floor) can raise the likelihood of *any* structured residual by widening
the noise where the residual is large; a mean effect explains it.  Each
round therefore ranks the mean-kind candidates first and adopts the best
one when its score is positive; the variance-kind candidates are scored
(and may be adopted) only in a round where no mean candidate helps,
fitted and scored with several chirp loops on the residual's chirp-to-chirp
deviation alone (the scatter a stationary noise model predicts; the
chirp-mean misfit is the mean model's to explain: a noise model fitted to
it would widen its variance there and overpredict the scatter), and
only when they help in most transmit slots (frame, Tx, chirp; in TDM-MIMO
every Tx fires in its own slot) (:func:`~.ranking.required_slot_share`):
a stationary noise model that gains in a few chirps only is absorbing a
localised disturbance (interference, a burst), which is reported as
unexplained instead; and only when the scatter they claim is new in every
chirp loop (:func:`~.ranking.chirp_memory`): a disturbance that drifts over
the frame (a power amplifier's droop) repeats from one chirp to the next,
noise does not.  Of two sensor effects that explain nearly the same,
the one with fewer parameters is adopted while the richer one's surplus is
scene misfit a scene-side candidate could take (:func:`~.ranking._parsimonious`), and
a sensor effect must beat every scene-side candidate by a margin
(:func:`~.ranking._scene_first`).  An effect that may make adopted ones redundant
(ego motion beside movers) is scored from a start without them
(:func:`~.ranking._fit_candidate`).
The adopted effect is then refitted jointly with all adopted effects on all
cells, and the next round starts.  It stops when nothing helps, and reports
what stays unexplained.
"""
from __future__ import annotations

import dataclasses
import time

import numpy as np

from ..errors import ConfigError, InputValueError
from ..effects.model import EffectModel
from ..effects.library.scene_mismatch import refinement_pinned
from .adoption import _adopt, _mean_worse
from .analysis import json_view, residual_domains
from .ranking import BIC, CandidateScore, _folds, _rank_round, _Tiers, check_penalty
from .scoring import score
from .workers import FitPool, one_blas_thread


@dataclasses.dataclass
class Adoption:
    """One adopted effect: its ranking round, parameters and errors before / after."""

    name: str
    round: int
    candidates: list
    before: dict
    after: dict
    params: dict
    residual_before: np.ndarray = None
    residual_after: np.ndarray = None
    #: wall seconds of the round: ``{"rank": ..., "adopt": ...}``
    seconds: dict = None
    #: fits of the adoption: 2 where the first was undone and a second start
    #: kept (:meth:`DiagnosisRun._adopt_or_undo`)
    starts: int = 1


@dataclasses.dataclass
class Diagnosis:
    """Result of :func:`diagnose`."""

    model: EffectModel
    first: dict                 # metrics of the base model (nuisance fitted)
    final: dict                 # metrics after all adoptions
    adoptions: list
    last_candidates: list       # the ranking that stopped the loop
    unexplained: dict           # residual domains of the final model
    settings: dict
    first_mean: np.ndarray = None   # base model ADC (nuisance fitted), capture units
    first_variance: np.ndarray = None

    @property
    def adopted(self) -> list:
        return [a.name for a in self.adoptions]


def _current_metrics(model: EffectModel) -> dict:
    mean, var = model.mean_variance_numpy()
    s = model.scale
    return score(model.ctx, model.y * s, mean * s, var * s ** 2)


#: rounds after which a diagnosis stops even while candidates still help
ROUND_CAP = 24


class DiagnosisRun:
    """The adopt-until-nothing-helps loop, one round at a time (resumable).

    Parameters
    ----------
    model : EffectModel
        Base model and adopted effects (modified in place).
    candidates : list of Effect
        Candidate effects.
    folds, penalty, min_gain, seed, maxiter, groups, workers
        As :func:`diagnose`.
    progress : callable, optional
        ``progress(event, name)`` with ``event`` ``"scored"`` (a candidate)
        or ``"adopted"``.
    """

    def __init__(self, model: EffectModel, candidates, folds: int = 3, penalty=BIC,
                 min_gain: float = 1e-3, seed: int = 0, maxiter: int = 150, groups: str = "auto",
                 progress=None, workers=1):
        from .screening import screen

        candidates = _check_candidates(candidates, model)
        self.model, self.pool, self.names = model, list(candidates), [c.name for c in candidates]
        self.folds, self.penalty, self.min_gain = folds, check_penalty(penalty), min_gain
        self.seed, self.maxiter, self.groups, self.progress = seed, maxiter, groups, progress
        self.fits = FitPool(workers)
        self.fold_groups = _folds(model.ctx.shape[:4], folds, seed, groups)[1]
        self.screened = screen(model.y, model.scale, candidates, model.ctx)
        self.adoptions, self.ranking, self.stop_reason = [], [], None
        #: adoptions undone because the joint refit made the mean model worse
        self.vetoes = []
        model.fit(trainable=[], maxiter=maxiter)
        r = model.residual()
        if not np.sum(np.abs(r) ** 2) > 1e-12 * np.sum(np.abs(model.y * model.scale) ** 2):
            raise InputValueError("diagnose: empty residual: the model already reproduces the "
                                  "capture exactly (is the model the capture itself?)")
        self.first = self.current = _current_metrics(model)
        self.first_mean, self.first_var = model.mean_variance_numpy()

    @property
    def done(self) -> bool:
        return self.stop_reason is not None

    def step(self) -> Adoption | None:
        """Rank, adopt the best and refit everything; ``None`` (and
        :attr:`stop_reason` set) when nothing helps any more."""
        limiter = one_blas_thread()
        try:
            return self._step()
        finally:
            limiter.restore_original_limits()

    def _step(self) -> Adoption | None:
        if not self.pool:
            self.stop_reason = "no candidate left"
            return None
        if len(self.adoptions) >= ROUND_CAP:
            self.stop_reason = f"round cap ({ROUND_CAP}) reached while candidates still helped"
            return None
        tiers = _Tiers(self.model, self.folds, self.seed, self.groups, self.fits)
        scored = None if self.progress is None else (lambda n: self.progress("scored", n))
        vetoed = set()
        secs = {"rank": 0.0, "adopt": 0.0}
        while True:
            t0 = time.perf_counter()
            ranking, best = _rank_round(tiers, self.pool, self.penalty, self.maxiter, scored,
                                        self.min_gain, self.screened, vetoed)
            secs["rank"] += time.perf_counter() - t0
            self.ranking = ranking
            if best is None:
                self.stop_reason = _stop_reason(vetoed)
                return None
            eff = next(c for c in self.pool if c.name == best.name)
            before, res_before = self.current, self.model.residual()
            t0 = time.perf_counter()
            comp, starts = self._adopt_or_undo(eff, best, secs)
            secs["adopt"] += time.perf_counter() - t0
            if comp is not None:
                break
            vetoed.add(eff.name)
        a = Adoption(name=eff.name, round=len(self.adoptions), candidates=ranking, before=before,
                     after=self.current, params=comp.effect.summary(comp.values, self.model.ctx),
                     residual_before=res_before.astype(np.complex64),
                     residual_after=self.model.residual().astype(np.complex64),
                     seconds={k: round(v, 2) for k, v in secs.items()}, starts=starts)
        self.adoptions.append(a)
        if not getattr(eff, "repeatable", False):
            self.pool = [c for c in self.pool if c is not eff]
        if self.progress is not None:
            self.progress("adopted", eff.name)
        return a

    def _adopt_or_undo(self, eff, score, clock=None):
        """Adopt ``eff`` (:func:`~.adoption._adopt`); undo it (no component) when the
        joint refit made the mean model worse (:func:`~.adoption._mean_worse`)
        or showed it to need a higher gain floor than its held-out gain per
        sample (``score``, its :class:`~.ranking.CandidateScore`): a mover
        whose fold fits moved but whose refit comes to rest beside the static
        scene is a scatterer, held to a scatterer's floor
        (:meth:`~sionna_mmir.effects.base.Effect.fitted_gain_floor`).

        A per-channel phase effect fitted beside a pinned base refinement
        (:func:`~.ranking._fit_candidate`) has a second start, with the
        refinement held, when the first made the mean model worse: freeing
        the pose on its bounds beside 28 delays is a larger, less settled fit:
        on the suite's cascade delay run one of five refits after the same
        first adoption ended 1.3 dB above its start (the others 2.4 dB below).
        ``clock`` collects the adoption's stage seconds (``adopt_joint``, ...).
        Returns ``(component or None, starts made)``."""
        before, saved = self.current, self.model.copy()
        shape = self.model.white_shape_numpy()
        ref = (shape, self.model.shaped_energy(shape=shape))
        starts = [False]
        if eff.channel_phase and refinement_pinned(self.model):
            starts.append(True)
        for k, hold in enumerate(starts):
            comp, why = self._adopt_once(eff, score, ref, clock, hold)
            if why is None:
                return comp, k + 1
            why = {"residual_energy_db": [before["residual_energy_db"],
                                          self.current["residual_energy_db"]], **why}
            self.model.components, self.model.nuisance = saved.components, saved.nuisance
            saved = self.model.copy()
            self.current = before
            if "gain_floor" in why:                 # a second start does not lower it
                break
        self.vetoes.append({"round": len(self.adoptions), "name": eff.name, **why})
        if self.progress is not None:
            self.progress("vetoed", eff.name)
        return None, len(starts)

    def _adopt_once(self, eff, score, ref, clock, hold):
        """One start of :meth:`_adopt_or_undo`: ``(component, None)``, or
        ``(component, why)`` when the adoption is to be undone.  ``ref``: the
        noise shape and shaped residual energy before the adoption
        (:meth:`~sionna_mmir.effects.model.EffectModel.shaped_energy`), which
        the mean model's rise is measured in."""
        stages = {}
        comp = _adopt(self.model, eff, self.maxiter, self.fits, stages, hold_refinement=hold)
        if clock is not None:
            for k, v in stages.items():
                clock["adopt_" + k] = clock.get("adopt_" + k, 0.0) + v
        self.current = _current_metrics(self.model)
        floor = float(comp.effect.fitted_gain_floor(self.model, comp.values))
        rise = 10.0 * np.log10(self.model.shaped_energy(shape=ref[0]) / ref[1])
        if _mean_worse(eff, rise):
            return comp, {"shaped_rise_db": rise, "starts": 2 if hold else 1}
        if score.gain_per_sample < floor:
            return comp, {"gain_floor": [score.gain_per_sample, floor]}
        return comp, None

    def result(self) -> Diagnosis:
        """The :class:`Diagnosis` so far."""
        model = self.model
        unexplained = json_view(residual_domains(model.ctx, model.y * model.scale,
                                                 model.mean_adc()))
        settings = {"folds": self.folds, "fold_groups": self.fold_groups,
                    "round_cap": ROUND_CAP, "penalty_nats_per_param": (
                        "ln(n)/2" if self.penalty == BIC else self.penalty),
                    "min_gain_nats_per_sample": self.min_gain, "seed": self.seed,
                    "candidates": self.names, "screened": self.screened,
                    "vetoed": list(self.vetoes),
                    "stop_reason": self.stop_reason}
        return Diagnosis(model=model, first=self.first, final=self.current,
                         adoptions=self.adoptions,
                         last_candidates=self.ranking if self.done else [],
                         unexplained=unexplained, settings=settings,
                         first_mean=self.first_mean * model.scale,
                         first_variance=self.first_var * model.scale ** 2)


def _stop_reason(vetoed) -> str:
    why = "no candidate improves the held-out likelihood and the held-out residual energy"
    if vetoed:
        why += f" (vetoed after their joint refit: {', '.join(sorted(vetoed))})"
    return why


def _check_candidates(candidates, model) -> list:
    """Validated candidates that the capture can support (frames)."""
    candidates = list(candidates)
    if not candidates:
        raise ConfigError("diagnose: no candidate effects given")
    names = [c.name for c in candidates]
    if len(set(names)) != len(names):
        raise ConfigError(f"diagnose: candidate names repeat: {names}")
    # effects the capture's shape cannot identify (a mover on one chirp of one
    # frame is a static scatterer with a free velocity) are not candidates
    return [c for c in candidates if c.supports(model.ctx)]


def diagnose(model: EffectModel, candidates, folds: int = 3, max_rounds: int | None = None,
             penalty=BIC, min_gain: float = 1e-3, seed: int = 0,
             maxiter: int = 150, progress=None, groups: str = "auto", workers=1) -> Diagnosis:
    """The adopt-until-nothing-helps loop; see the module docstring.

    Parameters
    ----------
    model : EffectModel
        Base model (modified in place).
    candidates : list of Effect
        E.g. :func:`~sionna_mmir.effects.library.default_library`; an effect
        with ``repeatable = True`` stays a candidate after adoption.
    folds : int
        Cross-validation folds.
    max_rounds : int, optional
        Most adoptions (default: until nothing helps, at most :data:`ROUND_CAP`).
    penalty : "bic" or float
        Nats per real parameter (``"bic"``: ``ln(n) / 2``, see :func:`~.ranking.penalty_per_param`).
    progress : callable, optional
        ``progress(name)`` after each candidate is scored.
    groups : {"auto", "channel", "cell"}
        The cross-validation hold-out unit (see :func:`~.ranking.cv_folds`).
    workers : int or "auto"
        Processes for the independent fits of a round (:class:`~.workers.FitPool`;
        1: all in this process).  The result does not depend on it.

    Returns
    -------
    Diagnosis
    """
    run = DiagnosisRun(model, candidates, folds=folds, penalty=penalty, min_gain=min_gain,
                       seed=seed, maxiter=maxiter, groups=groups, workers=workers,
                       progress=None if progress is None else
                       (lambda event, name: progress(name) if event == "scored" else None))
    while not run.done:
        if max_rounds is not None and len(run.adoptions) >= max_rounds:
            run.stop_reason = f"max_rounds ({max_rounds}) reached"
            break
        run.step()
    return run.result()


__all__ = ["Adoption", "CandidateScore", "Diagnosis", "DiagnosisRun", "ROUND_CAP", "diagnose"]

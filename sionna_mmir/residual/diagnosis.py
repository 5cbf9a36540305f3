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
parameter (AIC-like, default 1).

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
(and may be adopted) only in a round where no mean candidate helps.  The
adopted effect is then refitted jointly with all adopted effects on all
cells, and the next round starts.  It stops when nothing helps, and reports
what stays unexplained.
"""
from __future__ import annotations

import copy
import dataclasses

import numpy as np

from ..errors import ConfigError, InputValueError
from ..effects.model import EffectModel
from .analysis import json_view, residual_domains
from .scoring import score


@dataclasses.dataclass
class CandidateScore:
    """Held-out result of one candidate in one round."""

    name: str
    n_params: int
    gain: float                 # total held-out NLL reduction [nats]
    gain_per_sample: float      # per held-out complex sample [nats]
    score: float                # gain - penalty * n_params
    fold_gains: list

    def to_dict(self) -> dict:
        return {k: (round(v, 6) if isinstance(v, float) else v)
                for k, v in dataclasses.asdict(self).items()}


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


def cv_folds(shape, k: int = 3, seed: int = 0, groups: str = "auto") -> list:
    """``k`` boolean training masks over cells ``shape = (F, T, R, C)``.

    ``groups``: ``"channel"`` deals whole virtual channels (Tx-Rx pairs, all
    frames and chirps) to folds, ``"cell"`` single (frame, Tx, Rx, chirp)
    cells, ``"auto"`` channels where possible, else cells.  Every training
    mask keeps every Tx and every Rx (re-dealt otherwise), so per-Tx /
    per-Rx effects are estimable in every fold.
    """
    return _folds(shape, k, seed, groups)[0]


def _folds(shape, k, seed, groups):
    """``(training masks, "channel" | "cell")``; see :func:`cv_folds`."""
    F, T, R, C = shape
    if groups not in ("auto", "channel", "cell"):
        raise ConfigError(f"cv_folds: groups must be 'auto', 'channel' or 'cell', got {groups!r}")
    n = F * T * R * C
    if k < 2 or n < k:
        raise ConfigError(f"cv_folds: need 2 <= folds <= cells ({n}), got {k}")
    rng = np.random.default_rng(seed)

    def deal(group_shape, expand):
        m = int(np.prod(group_shape))
        for _ in range(200):
            fold = expand(rng.permutation(np.arange(m) % k).reshape(group_shape))
            trains = [fold != i for i in range(k)]
            if all(t.any(axis=(0, 2, 3)).all() and t.any(axis=(0, 1, 3)).all() for t in trains):
                return trains
        return None

    if groups != "cell" and T * R >= 2 * k:
        trains = deal((T, R), lambda f: np.broadcast_to(f[None, :, :, None], shape))
        if trains is not None:
            return trains, "channel"
        if groups == "channel":
            raise ConfigError(f"cv_folds: cannot hold out whole channels of a {T} Tx x {R} Rx "
                              f"array in {k} folds and keep every Tx and Rx in training")
    elif groups == "channel":
        raise ConfigError(f"cv_folds: {T * R} virtual channels are too few for {k} "
                          "channel folds (need 2 per fold)")
    trains = deal(shape, lambda f: f)
    if trains is None:                       # tiny arrays: accept the last deal
        fold = rng.permutation(np.arange(n) % k).reshape(shape)
        trains = [fold != i for i in range(k)]
    return trains, "cell"


def _current_metrics(model: EffectModel) -> dict:
    mean, var = model.mean_variance_numpy()
    s = model.scale
    return score(model.ctx, model.y * s, mean * s, var * s ** 2)


def _fold_bases(model: EffectModel, folds, maxiter) -> list:
    """Per fold: the current model refitted (nuisance only) on the training cells,
    with its held-out NLL total and the number of held-out samples."""
    out = []
    for train in folds:
        test = ~train
        n_test = float(test.sum()) * model.ctx.shape[-1]
        base = model.copy()
        base.fit(trainable=[], cells=train, maxiter=maxiter)
        out.append((train, base, base.nll_profiled(test) * n_test, n_test))
    return out


def rank_candidates(model: EffectModel, candidates, folds, penalty: float = 1.0,
                    maxiter: int = 150, progress=None) -> list:
    """Held-out scores of ``candidates`` on top of ``model``, best first."""
    bases = _fold_bases(model, folds, maxiter)
    out = []
    for eff in candidates:
        gains, n_tot = [], 0.0
        for train, base, nll0, n_test in bases:
            cand = base.copy()
            cand.add(copy.deepcopy(eff), cells=train)      # fresh state per fold
            cand.fit(trainable=[len(cand.components) - 1], cells=train, maxiter=maxiter)
            gains.append(nll0 - cand.nll_profiled(~train) * n_test)
            n_tot += n_test
        n_params = cand.components[-1].n_params
        gain = float(np.sum(gains))
        out.append(CandidateScore(name=eff.name, n_params=int(n_params), gain=gain,
                                  gain_per_sample=gain / max(n_tot, 1.0),
                                  score=gain - penalty * n_params,
                                  fold_gains=[float(g) for g in gains]))
        if progress is not None:
            progress(eff.name)
    return sorted(out, key=lambda c: c.score, reverse=True)


def _backfit(model: EffectModel, newest, maxiter: int):
    """Re-initialise every earlier adopted effect against the current model
    without it, refit all jointly, and keep the change when the NLL drops.

    An effect adopted while another one was still missing is initialised
    (and fitted) to absorb part of that one's signature: per-channel delays
    adopted before a missing scatterer bend to its phases, and the scatterer
    proposed afterwards lands off its true position.  Once the newer effect
    is in, the earlier one's data-driven initialisation from the cleaner
    residual usually finds the right basin (backfitting).  Returns the
    newest component (the same object unless a trial replaced the list).
    """
    best = model.nll()
    for i in range(len(model.components)):
        if model.components[i] is newest:
            continue
        trial = model.copy()
        old = trial.components[i]
        trial.remove(old)
        trial.add(copy.deepcopy(old.effect))
        trial.fit(maxiter=2 * maxiter)
        nll = trial.nll()
        if nll < best - 1e-6:
            k = model.components.index(newest)
            model.components, model.nuisance = trial.components, trial.nuisance
            newest = model.components[k if k < i else k - 1]
            best = nll
    return newest


def _rank_round(model, pool, trains, penalty, maxiter, progress, min_gain):
    """One round's ranking, mean candidates first (see the module docstring):
    ``(ranking, best)`` with ``best`` None when nothing should be adopted."""
    def ok(c):
        return c.score > 0 and c.gain_per_sample >= min_gain

    ranking = []
    for kinds in (("basis", "mean"), ("variance",)):
        group = [c for c in pool if c.kind in kinds]
        if not group:
            continue
        ranking = sorted(ranking + rank_candidates(model, group, trains, penalty, maxiter,
                                                   progress),
                         key=lambda c: c.score, reverse=True)
        best = next((c for c in ranking if ok(c)), None)
        if best is not None:
            return ranking, best
    return ranking, None


def diagnose(model: EffectModel, candidates, folds: int = 3, max_rounds: int = 6,
             penalty: float = 1.0, min_gain: float = 1e-3, seed: int = 0,
             maxiter: int = 150, progress=None, groups: str = "auto") -> Diagnosis:
    """The adopt-until-nothing-helps loop; see the module docstring.

    ``candidates``: effect instances (e.g. :func:`~sionna_mmir.effects.library.default_library`).
    An effect with ``repeatable = True`` stays a candidate after adoption
    (e.g. a second missing scatterer).  ``progress(name)`` is called after
    each candidate is scored.  ``groups``: the cross-validation hold-out unit
    (see :func:`cv_folds`).
    """
    candidates = list(candidates)
    if not candidates:
        raise ConfigError("diagnose: no candidate effects given")
    names = [c.name for c in candidates]
    if len(set(names)) != len(names):
        raise ConfigError(f"diagnose: candidate names repeat: {names}")
    # effects that need more frames than the capture has (e.g. a per-frame mover
    # on one frame is a static scatterer with a free velocity) are not candidates
    candidates = [c for c in candidates
                  if getattr(c, "min_frames", 1) <= model.ctx.num_frames]
    model.fit(trainable=[], maxiter=maxiter)
    r = model.residual()
    if not np.sum(np.abs(r) ** 2) > 1e-12 * np.sum(np.abs(model.y * model.scale) ** 2):
        raise InputValueError("diagnose: empty residual: the model already reproduces the "
                              "capture exactly (is the model the capture itself?)")
    first = current = _current_metrics(model)
    first_mean, first_var = model.mean_variance_numpy()
    trains, fold_groups = _folds(model.ctx.shape[:4], folds, seed, groups)
    adoptions, ranking = [], []
    pool = list(candidates)
    for rnd in range(max_rounds):
        if not pool:
            break
        ranking, best = _rank_round(model, pool, trains, penalty, maxiter, progress, min_gain)
        if best is None:
            break
        eff = next(c for c in pool if c.name == best.name)
        before = current
        res_before = model.residual()
        comp = model.add(copy.deepcopy(eff))
        model.fit(maxiter=2 * maxiter)
        comp = _backfit(model, comp, maxiter)
        after = current = _current_metrics(model)
        adoptions.append(Adoption(name=eff.name, round=rnd, candidates=ranking, before=before,
                                  after=after, params=eff.summary(comp.values, model.ctx),
                                  residual_before=res_before, residual_after=model.residual()))
        if not getattr(eff, "repeatable", False):
            pool = [c for c in pool if c is not eff]
        ranking = []
    final = current
    mean = model.mean_adc()
    unexplained = json_view(residual_domains(model.ctx, model.y * model.scale, mean))
    settings = {"folds": folds, "fold_groups": fold_groups, "max_rounds": max_rounds, "penalty_nats_per_param": penalty,
                "min_gain_nats_per_sample": min_gain, "seed": seed, "candidates": names}
    return Diagnosis(model=model, first=first, final=final, adoptions=adoptions,
                     last_candidates=ranking, unexplained=unexplained, settings=settings,
                     first_mean=first_mean * model.scale,
                     first_variance=first_var * model.scale ** 2)

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
the candidate was scored on (the BIC's weight, :func:`penalty_per_param`), or
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
scored with several chirp loops on the residual's chirp-to-chirp deviation
alone (the scatter a stationary noise model predicts; the chirp-mean misfit
is the mean model's to explain), and
only when they help in most transmit slots (frame, Tx, chirp; in TDM-MIMO
every Tx fires in its own slot) (:data:`MIN_SLOT_SHARE`):
a stationary noise model that gains in a few chirps only is absorbing a
localised disturbance (interference, a burst), which is reported as
unexplained instead.  Of two sensor effects that explain nearly the same,
the one with fewer parameters is adopted while the richer one's surplus is
scene misfit a scene-side candidate could take (:func:`_parsimonious`), and
a sensor effect must beat every scene-side candidate by a margin
(:func:`_scene_first`).  An effect that may make adopted ones redundant
(ego motion beside movers) is scored from a start without them
(:func:`_fit_candidate`).
The adopted effect is then refitted jointly with all adopted effects on all
cells, and the next round starts.  It stops when nothing helps, and reports
what stays unexplained.
"""
from __future__ import annotations

import copy
import dataclasses

import numpy as np

from ..errors import ConfigError, InputValueError
from ..effects.model import Component as _Component, EffectModel
from .analysis import _db, json_view, residual_domains
from .scoring import score
from .workers import SERIAL, FitPool, one_blas_thread


@dataclasses.dataclass
class CandidateScore:
    """Held-out result of one candidate in one round."""

    name: str
    n_params: int
    gain: float                 # total held-out NLL reduction [nats]
    gain_per_sample: float      # per held-out complex sample [nats]
    score: float                # gain - penalty per parameter * n_params
    fold_gains: list
    #: share of the transmit slots (frame, Tx, chirp) whose held-out NLL the candidate lowers
    slot_share: float = 1.0
    #: change of the held-out residual energy ``sum |Y - X|^2`` [dB] (mean-kind
    #: candidates; 0 for variance effects, which do not predict the mean); a
    #: mean-only candidate (:func:`_mean_only`) is acceptable only when it is <= 0
    energy_change_db: float = 0.0

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


def _fold_base_task(shared, k: int, maxiter: int) -> dict:
    """Worker task: the nuisance values of ``model`` refitted on fold ``k``'s training cells."""
    model, folds = shared
    base = model.copy()
    base.fit(trainable=[], cells=folds[k], maxiter=maxiter)
    return base.nuisance.values


def _fold_bases(model: EffectModel, folds, maxiter, pool=SERIAL) -> list:
    """Per fold: the current model refitted (nuisance only) on the training cells,
    with its held-out NLL total and the number of held-out samples."""
    out = []
    fitted = pool.map(_fold_base_task, (model, folds), [(k, maxiter) for k in range(len(folds))])
    for train, values in zip(folds, fitted):
        test = ~train
        n_test = float(test.sum()) * model.ctx.shape[-1]
        base = model.copy()
        base.nuisance.values = values
        out.append((train, base, base.nll_profiled(test) * n_test, n_test))
    return out


def slot_share(gains: list, tests: list) -> float:
    """Share of the transmit slots (frame, Tx, chirp) with a positive held-out gain.

    ``gains[i]`` holds the per-cell NLL reductions on the held-out cells of
    fold ``i`` (boolean mask ``tests[i]`` ``[F, T, R, C]``, in its order),
    each model's white floor profiled per slot
    (:meth:`~sionna_mmir.effects.model.EffectModel.nll_profiled` with
    ``by_slot``), so that a floor raised by a few slots does not make every
    slot look noisier than it is.  In TDM-MIMO every Tx fires in its own
    time slot, so a slot is a (frame, Tx, chirp) transmission: a burst of
    interference hits some transmissions of a chirp loop and not others.  A
    stationary effect (a noise floor, a phase-noise skirt) claims the same
    statistics in every slot, so it should help in most; a gain from a few
    slots is a localised disturbance the effect only absorbs.  1.0 when there
    are fewer than 4 slots.
    """
    F, T, _, C = tests[0].shape
    if F * T * C < 4:
        return 1.0
    per_slot = np.zeros((F, T, C))
    for g, test in zip(gains, tests):
        f, t, _, c = np.nonzero(test)
        np.add.at(per_slot, (f, t, c), g)
    return float(np.mean(per_slot > 0))


def _fit_candidate(cand: EffectModel, eff, train, maxiter: int) -> None:
    """Fit the candidate ``eff`` (the last component of ``cand``) on ``train``.

    An effect that may make adopted ones redundant (``eff.may_replace``, e.g.
    ego motion beside movers: a mover adopted first may be a static object
    seen from the moving radar, and ego motion scored with it held fixed
    would show that object twice) is fitted alone with those silenced
    (:meth:`~sionna_mmir.effects.base.Effect.silenced`), then with every
    component, so the object's amplitude can move back from the mover to
    the scene."""
    new = len(cand.components) - 1
    names = set(eff.may_replace)
    replaced = [c for c in cand.components[:new] if c.effect.name in names]
    if not replaced:
        cand.fit(trainable=[new], cells=train, maxiter=maxiter)
        return
    for c in replaced:
        c.values = c.effect.silenced(c.values) or c.values
    cand.fit(trainable=[new], cells=train, maxiter=maxiter)
    cand.fit(cells=train, maxiter=maxiter)


#: the default penalty: the BIC's ``ln(n) / 2`` nats per real parameter
BIC = "bic"


def check_penalty(penalty):
    """``penalty`` validated: ``"bic"`` or a finite number of nats >= 0."""
    if isinstance(penalty, str):
        if penalty.strip().lower() == BIC:
            return BIC
        try:
            penalty = float(penalty)
        except ValueError:
            raise ConfigError(f"--penalty must be 'bic' or a number of nats >= 0, "
                              f"got {penalty!r}") from None
    if isinstance(penalty, bool) or not isinstance(penalty, (int, float, np.floating)) \
            or not np.isfinite(penalty) or penalty < 0:
        raise ConfigError(f"--penalty must be 'bic' or a finite number of nats >= 0, "
                          f"got {penalty!r}")
    return float(penalty)


def penalty_per_param(penalty, n_samples: float) -> float:
    """Nats charged per real parameter of a candidate scored on ``n_samples``
    held-out complex samples: ``ln(n) / 2`` for ``"bic"``, else ``penalty``."""
    if penalty == BIC:
        return 0.5 * float(np.log(max(n_samples, 1.0)))
    return float(penalty)


def _candidate_task(shared, k: int, eff, maxiter: int, deviation: bool) -> dict:
    """Worker task: candidate ``eff`` added to fold ``k``'s base, fitted on its
    training cells, and what the ranking needs from its held-out cells."""
    train, base = shared[k]
    cand = base.copy()
    cand.add(copy.deepcopy(eff), cells=train)          # fresh state per fold
    _fit_candidate(cand, eff, train, maxiter)
    out = {"nll": cand.nll_profiled(~train, deviation=deviation),
           "n_params": int(cand.components[-1].n_params)}
    if eff.kind == "variance":
        out["slots"] = cand.nll_profiled(~train, True, by_slot=True)[1]
    else:
        out["energy"] = cand.residual_energy(~train)
    return out


def rank_candidates(model: EffectModel, candidates, folds, penalty=BIC,
                    maxiter: int = 150, progress=None, pool=SERIAL) -> list:
    """Held-out scores of ``candidates`` on top of ``model``, best first.

    The (candidate, fold) fits are independent and run on ``pool``
    (:class:`~.workers.FitPool`); ``progress(name)`` follows each candidate
    whose folds are all fitted."""
    bases = _fold_bases(model, folds, maxiter, pool)
    K = len(bases)
    devs = [eff.kind == "variance" and model.ctx.shape[3] > 1 for eff in candidates]
    tasks = [(k, eff, maxiter, dev) for eff, dev in zip(candidates, devs) for k in range(K)]
    left = {i: K for i in range(len(candidates))}

    def done(t):
        i = t // K
        left[i] -= 1
        if left[i] == 0 and progress is not None:
            progress(candidates[i].name)

    fits = pool.map(_candidate_task, [(b[0], b[1]) for b in bases], tasks, done=done)
    base_dev, base_energy, base_slots = {}, {}, {}      # per fold, computed once
    out = []
    for i, (eff, dev) in enumerate(zip(candidates, devs)):
        gains, n_tot, cell_gains, energy = [], 0.0, [], [0.0, 0.0]
        for k, (train, base, nll0, n_test) in enumerate(bases):
            fit = fits[i * K + k]
            if dev:
                if k not in base_dev:
                    base_dev[k] = base.nll_profiled(~train, deviation=True) * n_test
                nll0 = base_dev[k]
            gains.append(nll0 - fit["nll"] * n_test)
            if eff.kind == "variance":
                if k not in base_slots:
                    base_slots[k] = base.nll_profiled(~train, True, by_slot=True)[1]
                cell_gains.append(base_slots[k] - fit["slots"])
            else:
                if k not in base_energy:
                    base_energy[k] = base.residual_energy(~train)
                energy[0] += base_energy[k]
                energy[1] += fit["energy"]
            n_tot += n_test
        n_params = fits[i * K]["n_params"]
        gain = float(np.sum(gains))
        out.append(CandidateScore(name=eff.name, n_params=n_params, gain=gain,
                                  gain_per_sample=gain / max(n_tot, 1.0),
                                  score=gain - penalty_per_param(penalty, n_tot) * n_params,
                                  fold_gains=[float(g) for g in gains],
                                  slot_share=(slot_share(cell_gains, [~b[0] for b in bases])
                                              if cell_gains else 1.0),
                                  energy_change_db=(_db(energy[1] / energy[0])
                                                    if energy[0] > 0 else 0.0)))
    return sorted(out, key=lambda c: c.score, reverse=True)


def _trial_values(trial: EffectModel) -> tuple:
    """What a trial model's fit changed: its NLL, nuisance and component values."""
    return (trial.nll(), trial.nuisance.values, [c.values for c in trial.components])


def _take_values(model: EffectModel, nuisance, values) -> None:
    model.nuisance.values = nuisance
    for c, v in zip(model.components, values):
        c.values = v


def _restart_task(model, i: int, maxiter: int) -> tuple:
    """Worker task: ``model`` with component ``i`` refitted from its initial values."""
    trial = model.copy()
    c = trial.components[i]
    c.values = {k: np.array(s.init, copy=True) for k, s in c.specs.items()}
    trial.fit(maxiter=2 * maxiter)
    return _trial_values(trial)


def _backfit_task(model, i: int, maxiter: int) -> tuple:
    """Worker task: ``model`` with component ``i`` re-initialised against the
    model without it (moved to the end) and everything refitted; returns the
    re-added effect and specs too (its initialisation may set its state)."""
    trial = model.copy()
    old = trial.components[i]
    trial.remove(old)
    new = trial.add(copy.deepcopy(old.effect))
    trial.fit(maxiter=2 * maxiter)
    return _trial_values(trial) + (new.effect, new.specs)


def _in_order(model: EffectModel, task, eligible, best: float, maxiter: int, pool, keep) -> float:
    """The trials ``task(model, i)`` for the ``eligible(model, i)`` components,
    in index order, each kept (``keep(i, result)``) when it lowers the NLL
    below ``best`` -- the next trial then starts from the kept model.

    The trials are run speculatively on ``pool``, as many at once as it has
    workers: the next few start from the current model together, the first
    one that helps is kept, and the ones after it run again from the new
    model.  The outcome is that of trying them one by one; a trial is wasted
    only when an earlier one in its batch is kept.  Returns the model's NLL."""
    start = 0
    while True:
        idx = [i for i in range(start, len(model.components)) if eligible(model, i)]
        if not idx:
            return best
        idx = idx[:max(pool.workers, 1)]
        results = pool.map(task, model, [(i, maxiter) for i in idx])
        hit = next(((i, r) for i, r in zip(idx, results) if r[0] < best - 1e-6), None)
        if hit is None:
            start = idx[-1] + 1
            continue
        i, r = hit
        keep(i, r)
        best, start = r[0], i + 1


def _restart(model: EffectModel, best: float, maxiter: int, pool=SERIAL) -> float:
    """Refit from a fresh start (zero values) the components that allow it
    (e.g. a pose offset fitted before a sensor effect bent it); keep the
    restart when the NLL drops.  Returns the model's NLL."""
    def keep(i, r):
        trial = model.copy()
        _take_values(trial, r[1], r[2])
        model.components, model.nuisance = trial.components, trial.nuisance

    return _in_order(model, _restart_task,
                     lambda m, i: getattr(m.components[i].effect, "restartable", False),
                     best, maxiter, pool, keep)


def _backfit(model: EffectModel, newest, maxiter: int, pool=SERIAL):
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
    k = [_position(model, newest)]
    best = _restart(model, model.nll(), maxiter, pool)

    def eligible(m, i):
        c = m.components[i]
        return i != k[0] and c.effect.kind != "basis" and not _frozen(c)

    def keep(i, r):
        trial = model.copy()
        trial.remove(trial.components[i])
        trial.components.append(_Component(effect=r[3], specs=r[4], values={}))
        _take_values(trial, r[1], r[2])
        model.components, model.nuisance = trial.components, trial.nuisance
        k[0] = k[0] if k[0] < i else k[0] - 1        # the re-added effect moved to the end

    _in_order(model, _backfit_task, eligible, best, maxiter, pool, keep)
    return model.components[k[0]]


def _position(model: EffectModel, comp) -> int:
    """Index of ``comp`` (by identity) in ``model.components``."""
    return next(i for i, c in enumerate(model.components) if c is comp)


class _Tiers:
    """The models candidates are scored on: the chirp-averaged model for the
    chirp-static candidates (as many nats from a fraction of the data;
    :func:`_averaged_scoring`), the full model for the rest; with their
    cross-validation folds.  Adopted chirp-varying components enter the
    averaged model at their current values
    (:class:`~sionna_mmir.effects.frozen.FrozenPart`: a mover's averaged
    path, a noise effect's averaged variance); the full model is used for
    every candidate only when one of them has no averaged counterpart
    (ego-motion, clipping)."""

    def __init__(self, model, folds, seed, groups, pool=SERIAL):
        self.model, self.pool = model, pool
        self.avg = model.chirp_averaged(freeze=True) if model.can_average() else model
        self.folds = _folds(model.ctx.shape[:4], folds, seed, groups)[0]
        self.avg_folds = (self.folds if self.avg is model
                          else _folds(self.avg.ctx.shape[:4], folds, seed, groups)[0])
        self.scores = {}

    def rank(self, candidates, penalty, maxiter, progress):
        """Scores of ``candidates``, best first (each scored once per round)."""
        todo = [c for c in candidates if c.name not in self.scores]
        fast = [c for c in todo if _averaged_scoring(c)]
        slow = [c for c in todo if not _averaged_scoring(c)]
        if fast:
            out = rank_candidates(self.avg, fast, self.avg_folds, penalty, maxiter, progress,
                                  self.pool)
            self.scores.update((c.name, c) for c in out)
        if slow:
            out = rank_candidates(self.model, slow, self.folds, penalty, maxiter, progress,
                                  self.pool)
            self.scores.update((c.name, c) for c in out)
        return sorted((self.scores[c.name] for c in candidates), key=lambda c: c.score,
                      reverse=True)

    def on_one_scale(self, ranking, best, pool, ok, penalty, maxiter, progress):
        """``(ranking, best)`` with scores comparable across the tiers.

        A held-out gain on every chirp is not on the chirp average's scale (a
        misfit well above the noise gains up to ``C`` times more nats on the
        full data).  When the best acceptable candidate was scored on the full
        data and an acceptable chirp-averaged one ranks below it, that one is
        scored again on the full data and the two are compared there."""
        effects = {c.name: c for c in pool}
        if self.avg is self.model or _averaged_scoring(effects[best.name]):
            return ranking, best
        rival = next((c for c in ranking if ok(c) and _averaged_scoring(effects[c.name])), None)
        if rival is None:
            return ranking, best
        (again,) = rank_candidates(self.model, [effects[rival.name]], self.folds, penalty,
                                   maxiter, progress, self.pool)
        # its gain floor stays judged on the chirp average, where it is set
        again = dataclasses.replace(again, gain_per_sample=rival.gain_per_sample)
        ranking = sorted([again if c is rival else c for c in ranking],
                         key=lambda c: c.score, reverse=True)
        return ranking, next((c for c in ranking if ok(c)), None)


def _averaged_scoring(eff) -> bool:
    """Whether ``eff`` is scored and fitted on chirp-averaged data: a
    chirp-static effect, unless it also shapes the receiver noise (an IF
    filter): averaging over chirps buries the noise shape, its most robust
    signature, under what the scene leaves unexplained."""
    return eff.chirp_static and not getattr(eff, "shapes_noise", False)


def _mean_only(eff) -> bool:
    """Whether ``eff`` changes the mean model only (no variance, no noise
    shape): such an effect must lower the mean model's squared error
    (:func:`_mean_worse`, :attr:`CandidateScore.energy_change_db`)."""
    return eff.kind != "variance" and not getattr(eff, "shapes_noise", False)


#: a variance effect must lower the held-out NLL in at least this share of the
#: transmit slots (:func:`slot_share`): it models stationary noise
MIN_SLOT_SHARE = 0.5

#: a sensor effect is adopted only when its held-out gain exceeds every
#: acceptable scene-side candidate's by more than this share (:func:`_scene_first`)
SCENE_MARGIN = 0.1


def _scene_first(ranking, best, ok, scene_side):
    """The best acceptable scene-side candidate in place of a sensor-side
    ``best`` whose held-out gain it reaches to within :data:`SCENE_MARGIN`;
    ``best`` otherwise.

    Scene mismatch before sensor effects: the scene-side candidates only
    approximate how a real scene differs from its mesh (object patterns,
    points, shifts), while a per-channel sensor effect mimics much of that
    difference (a per-Tx gain mends a scatterer the mesh puts at a slightly
    wrong height on a radar whose Tx sit at two heights).  A sensor effect
    that beats them narrowly has not shown that the sensor, not the scene,
    is wrong; if it is really there it keeps its gain after the scene is
    mended and is adopted in a later round."""
    if scene_side.get(best.name, True):
        return best
    scene = [c for c in ranking if ok(c) and scene_side.get(c.name, True)
             and c.gain >= (1.0 - SCENE_MARGIN) * best.gain]
    return max(scene, key=lambda c: c.score) if scene else best


#: two sensor effects explain "the same residual" when the simpler one's
#: held-out gain is at least this share of the richer one's (:func:`_parsimonious`)
PARSIMONY_SHARE = 0.9


def _parsimonious(ranking, best, ok, scene_side):
    """The sensor effect adopted in place of ``best``: the one with the fewest
    parameters among the acceptable sensor-side candidates that explain
    nearly what ``best`` explains (held-out gain at least
    :data:`PARSIMONY_SHARE` of ``best``'s) while ``best``'s surplus over them
    is less than a scene-side candidate explains in the same round; ``best``
    itself when there is none, or when ``best`` is scene-side.

    Two sensor effects that explain nearly the same residual differ by what
    the richer one also mimics: per-Tx and per-Rx delays are a separable
    phase screen across the array, which steers a scatterer the scene places
    a little off, so a per-chip beat offset (4 numbers) loses to them (28)
    by the scene misfit they absorb.  While a scene-side candidate explains
    more than that surplus, the surplus is left to the scene (scene mismatch
    before sensor effects); a richer effect that is really there keeps its
    gain after the simpler one and is adopted in a later round."""
    if scene_side.get(best.name, True):
        return best
    scene = max((c.gain for c in ranking if ok(c) and scene_side.get(c.name, True)), default=0.0)
    close = [c for c in ranking if ok(c) and not scene_side.get(c.name, True)
             and c.n_params < best.n_params and c.gain >= PARSIMONY_SHARE * best.gain
             and best.gain - c.gain < scene]
    return min(close, key=lambda c: (c.n_params, -c.score)) if close else best


def _rank_round(tiers, pool, penalty, maxiter, progress, min_gain, screened, vetoed=()):
    """One round's ranking, mean (and scene) candidates first (see the module
    docstring): ``(ranking, best)`` with ``best`` None when nothing should be
    adopted.  Screened candidates are left out; ``vetoed`` ones are ranked
    but not chosen (their adoption made the mean model worse,
    :data:`MEAN_GUARD_DB`)."""
    floor = {c.name: max(min_gain, c.gain_floor(tiers.model.ctx)) for c in pool}
    kinds_of = {c.name: c.kind for c in pool}
    scene_side = {c.name: c.scene_side for c in pool}
    mean_only = {c.name for c in pool if _mean_only(c)}

    def ok(c):
        variance = kinds_of.get(c.name) == "variance"
        stationary = not variance or c.slot_share >= MIN_SLOT_SHARE
        predicts_mean = c.name not in mean_only or c.energy_change_db <= 0.0
        return (c.score > 0 and c.gain_per_sample >= floor.get(c.name, min_gain) and stationary
                and predicts_mean and c.name not in vetoed)

    ranking = []
    for kinds in (("basis", "mean"), ("variance",)):
        group = [c for c in pool if c.kind in kinds and c.name not in screened]
        if not group:
            continue
        ranking = sorted(ranking + tiers.rank(group, penalty, maxiter, progress),
                         key=lambda c: c.score, reverse=True)
        best = next((c for c in ranking if ok(c)), None)
        if best is not None:
            ranking, best = tiers.on_one_scale(ranking, best, pool, ok, penalty, maxiter, progress)
        if best is not None:
            best = _scene_first(ranking, best, ok, scene_side)
            return ranking, _parsimonious(ranking, best, ok, scene_side)
    return ranking, None


def _adopt(model, eff, maxiter, pool=SERIAL):
    """Add ``eff`` and refit everything jointly (backfitting earlier effects
    after a mean effect); on chirp-averaged data when every component allows
    it (then the full model takes the values and refits its noise floor;
    chirp-varying components held fixed there are refitted jointly with the
    rest on the full data).  An effect fitted on every chirp for its noise
    shape (an IF filter) is backfitted on the chirp average: the earlier
    effects' signatures are in the mean, at ``1 / C`` of the cost.  A mover
    is backfitted on every chirp: on the average it would be held fixed, so
    its own refit would wait for a kept trial and leave part of a
    chirp-varying residual to the next mover.  Returns the new component."""
    static = _averaged_scoring(eff) and model.can_average()
    work = model.chirp_averaged(freeze=True) if static else model
    comp = work.add(copy.deepcopy(eff))
    work.fit(maxiter=2 * maxiter)
    if eff.kind != "variance":      # a noise model only reweights the mean fit
        if work is model and getattr(eff, "shapes_noise", False) and model.can_average() \
                and model.ctx.shape[3] > 1:
            return _backfit_on_average(model, comp, maxiter, pool)
        comp = _backfit(work, comp, maxiter, pool)
    if work is not model:                   # the values carry over
        comp = _carry_back(model, work, comp, maxiter)
    return comp


def _backfit_on_average(model, comp, maxiter, pool=SERIAL):
    """:func:`_backfit` on the chirp average of ``model`` (``comp`` fitted on
    every chirp); when a trial is kept, ``model`` takes its values and is
    refitted jointly on every chirp.  Returns ``comp``'s current counterpart."""
    avg = model.chirp_averaged(freeze=True)
    listed = avg.components
    new = _backfit(avg, avg.components[_position(model, comp)], maxiter, pool)
    if avg.components is listed:                     # no trial was kept
        return comp
    return _carry_back(model, avg, new, maxiter, joint=True)


def _carry_back(model, work, comp, maxiter, joint=False):
    """Give ``model`` the component values fitted on its chirp-averaged
    ``work`` model and refit it on the full data: the nuisance only, or
    everything when ``work`` held chirp-varying components fixed or with
    ``joint``.  Returns ``comp``'s counterpart in ``model``."""
    k = _position(work, comp)
    source = {id(c.effect): c for c in model.components}
    model.components = [source[id(c.effect.source)] if _frozen(c) else c.copy()
                        for c in work.components]
    model.nuisance.values["gain"] = np.array(work.nuisance.values["gain"], copy=True)
    full = joint or any(_frozen(c) for c in work.components)
    model.fit(trainable=None if full else [], maxiter=2 * maxiter if full else maxiter)
    return model.components[k]


def _frozen(comp) -> bool:
    """Whether ``comp`` stands in, fixed, for a chirp-varying component."""
    from ..effects.frozen import FrozenPart

    return isinstance(comp.effect, FrozenPart)


#: a mean-kind adoption is undone when its joint refit raises the residual
#: energy ``|y - x|^2`` of all cells by more than this [dB] (:func:`_mean_worse`)
MEAN_GUARD_DB = 0.1


def _mean_worse(eff, before: dict, after: dict) -> bool:
    """Whether adopting the mean-kind ``eff`` made the mean model worse.

    The held-out likelihood is the adoption test, but beside adopted variance
    effects (a phase-noise skirt, a coloured floor) a mean effect can gain
    likelihood by raising the predicted variance where the residual is large
    instead of explaining it (a Tx->Rx leakage fitted beside phase noise on a
    measured capture can gain thousands of held-out nats while its tones
    overshoot the capture's leakage).  A mean effect that is
    really there lowers the squared error of the mean model, on held-out
    channels (:attr:`CandidateScore.energy_change_db`, required <= 0 in the
    ranking) and after the joint refit on all cells (checked here).  Variance
    effects only reweight the mean fit and are not held to it, nor are mean
    effects that also shape the receiver noise (an IF filter: most of its
    signature is the noise notch, and its fit trades a little mean misfit
    for it)."""
    if not _mean_only(eff):
        return False
    return after["residual_energy_db"] > before["residual_energy_db"] + MEAN_GUARD_DB


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
        self.screened = screen(model.y, model.scale, candidates)
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
        while True:
            ranking, best = _rank_round(tiers, self.pool, self.penalty, self.maxiter, scored,
                                        self.min_gain, self.screened, vetoed)
            self.ranking = ranking
            if best is None:
                self.stop_reason = _stop_reason(vetoed)
                return None
            eff = next(c for c in self.pool if c.name == best.name)
            before, res_before = self.current, self.model.residual()
            comp = self._adopt_or_undo(eff)
            if comp is not None:
                break
            vetoed.add(eff.name)
        a = Adoption(name=eff.name, round=len(self.adoptions), candidates=ranking, before=before,
                     after=self.current, params=comp.effect.summary(comp.values, self.model.ctx),
                     residual_before=res_before.astype(np.complex64),
                     residual_after=self.model.residual().astype(np.complex64))
        self.adoptions.append(a)
        if not getattr(eff, "repeatable", False):
            self.pool = [c for c in self.pool if c is not eff]
        if self.progress is not None:
            self.progress("adopted", eff.name)
        return a

    def _adopt_or_undo(self, eff):
        """Adopt ``eff`` (:func:`_adopt`); undo it and return None when the
        joint refit made the mean model worse (:func:`_mean_worse`)."""
        before, saved = self.current, self.model.copy()
        comp = _adopt(self.model, eff, self.maxiter, self.fits)
        self.current = _current_metrics(self.model)
        if not _mean_worse(eff, before, self.current):
            return comp
        self.vetoes.append({"round": len(self.adoptions), "name": eff.name,
                            "residual_energy_db": [before["residual_energy_db"],
                                                   self.current["residual_energy_db"]]})
        self.model.components, self.model.nuisance = saved.components, saved.nuisance
        self.current = before
        if self.progress is not None:
            self.progress("vetoed", eff.name)
        return None

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
        why += f" (vetoed after a worse joint refit: {', '.join(sorted(vetoed))})"
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
        Nats per real parameter (``"bic"``: ``ln(n) / 2``, see :func:`penalty_per_param`).
    progress : callable, optional
        ``progress(name)`` after each candidate is scored.
    groups : {"auto", "channel", "cell"}
        The cross-validation hold-out unit (see :func:`cv_folds`).
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

"""Scoring candidate effects: cross-validation folds, held-out gains, the
two data tiers and the rules that choose a round's best.

The method is described in :mod:`~sionna_mmir.residual.diagnosis`; this
module holds its first half: every candidate is fitted per fold on the
training cells (:func:`rank_candidates`, on worker processes) and scored by
its held-out likelihood gain, chirp-static candidates on the chirp average
and the rest on every chirp (:class:`_Tiers`), and :func:`_rank_round`
applies the acceptance rules (gain floors, stationarity of noise models,
the mean guard, an effect on every path following the signal across range,
scene mismatch before sensor effects, parsimony).
"""
from __future__ import annotations

import copy
import dataclasses
import time

import numpy as np

from ..errors import ConfigError
from ..effects.blockwise import fit_joint
from ..effects.library._sensor_common import chirp_deviation
from ..effects.library.scene_mismatch import BASE_REFINEMENT_NAMES, refinement_pinned
from ..effects.model import EffectModel
from .analysis import _db
from .workers import SERIAL


@dataclasses.dataclass
class CandidateScore:
    """Held-out result of one candidate in one round."""

    name: str
    n_params: int
    gain: float                 # total held-out NLL reduction [nats]
    gain_per_sample: float      # per held-out complex sample [nats]
    score: float                # gain - penalty per parameter * n_params
    fold_gains: list
    #: share of the transmit slots (frame, Tx, chirp) whose held-out NLL the
    #: candidate lowers (variance effects; a noise shaper's on the
    #: chirp-to-chirp scatter alone; 1.0 for other mean effects)
    slot_share: float = 1.0
    #: change of the held-out residual energy ``sum |Y - X|^2 / s`` [dB], ``s``
    #: the noise shape of the model without the candidate (1 without an adopted
    #: IF filter: :meth:`~sionna_mmir.effects.model.EffectModel.shaped_energy`;
    #: mean-kind candidates; 0 for variance effects, which do not predict the
    #: mean); a mean-only candidate (:func:`_mean_only`) is acceptable only
    #: when it is <= 0
    energy_change_db: float = 0.0
    #: lag-1 chirp correlation of the held-out scatter a variance effect
    #: claims, and the most an acceptable one may show (:func:`chirp_memory`;
    #: 0 and inf for mean effects and short frames)
    chirp_memory: float = 0.0
    memory_limit: float = float("inf")
    #: held-out residual energy a mean candidate removes outside the range
    #: bins of the strongest objects, as a share of what it removes at them
    #: (:func:`outside_share`; 0 for variance effects)
    outside_share: float = 0.0
    #: seconds its fold fits took (summed over folds, each timed where it ran)
    fit_s: float = 0.0
    #: least gain per sample its fits call for (the median over folds of
    #: :meth:`~sionna_mmir.effects.base.Effect.fitted_gain_floor`); the
    #: ranking takes the larger of it and the effect's own floor
    gain_floor: float = 0.0
    #: held-out NLL reduction [nats] on the chirp-to-chirp scatter alone, less
    #: the penalty of one parameter (the filtered share of the floor), for a
    #: noise shaper scored with the split likelihood (None otherwise): the
    #: part of its gain that a frequency-dependent gain on the mean cannot
    #: make (:func:`_shapes_held_out_noise`)
    noise_gain: float | None = None
    #: for a scene-side pattern whose shared form is a sensor effect
    #: (``shared_twin``): what the pattern fitted on the strongest object
    #: gains on the second strongest (``shared``), what that object's own
    #: pattern gains (``own``) and the sensor effect's parameter penalty
    #: [nats] (:func:`_objects_agree`; None where not measured)
    object_test: dict | None = None

    def to_dict(self) -> dict:
        """JSON-ready: floats rounded, an unbounded limit as None."""
        return {k: ((round(v, 6) if np.isfinite(v) else None) if isinstance(v, float) else v)
                for k, v in dataclasses.asdict(self).items()}


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


def _fold_base_task(shared, g: int, k: int, maxiter: int, needs: tuple) -> tuple:
    """Worker task: group ``g``'s model with its nuisance values refitted on
    fold ``k``'s training cells, and the base scores of the held-out cells
    that the group's candidates are compared with: ``(nuisance values,
    {"nll", "dev", "slots", "energy"})`` (``needs`` names the optional ones)."""
    model, folds = shared[g]
    base = model.copy()
    base.fit(trainable=[], cells=folds[k], maxiter=maxiter)
    return base.nuisance.values, _base_scores(base, ~folds[k], needs)


def _base_scores(base, test, needs: tuple) -> dict:
    """What a fold base is compared with on its held-out cells ``test``
    (``needs`` names the optional parts; see :func:`_fold_base_task`)."""
    n_test = float(test.sum()) * base.ctx.shape[-1]
    out = {"nll": base.nll_profiled(test) * n_test}
    if "dev" in needs:
        out["dev"] = base.nll_profiled(test, deviation=True) * n_test
    if "slots" in needs:
        out["slots"] = base.nll_profiled(test, True, by_slot=True,
                                         deviation=_slot_deviation(base.ctx.shape[3] > 1))[1]
    if "energy" in needs:
        out["bins"], out["power"], out["energy"] = base.energy_by_bin(test)
    if "split" in needs:
        out["split"] = base.nll_profiled(test, split=True) * n_test
    return out


def _slot_deviation(deviation: bool):
    """How a noise model's per-slot gains are judged when it is scored on the
    chirp-to-chirp scatter: on the deviation from the chirp *median*, where a
    burst in a few chirps stays in those chirps (the deviation from the mean
    would leave ``1 / C`` of it in every other chirp, and a noise model would
    seem to help in every slot)."""
    return "median" if deviation else False


def _base_needs(model, candidates) -> tuple:
    """What :func:`_fold_base_task` must score for ``candidates``."""
    needs = []
    if any(e.kind == "variance" and model.ctx.shape[3] > 1 for e in candidates):
        needs.append("dev")
    if any(e.kind == "variance" or _split_scored(e, model) for e in candidates):
        needs.append("slots")
    if any(e.kind != "variance" for e in candidates):
        needs.append("energy")
    if any(_split_scored(e, model) for e in candidates):
        needs.append("split")
        if "dev" not in needs:
            needs.append("dev")
    return tuple(needs)


def _split_scored(eff, model) -> bool:
    """Whether ``eff`` added to ``model`` is scored with the split likelihood
    (:meth:`~sionna_mmir.effects.model.EffectModel.split_likelihood`): a
    noise-shaping mean effect on two or more chirp loops.  Its base is scored
    the same way, and its gain is on the chirp average's scale for what it
    explains in the mean."""
    return (eff.kind == "mean" and getattr(eff, "shapes_noise", False)
            and model.ctx.shape[3] > 1)


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


#: least chirp loops for :func:`chirp_memory` (with fewer the deviation from
#: the chirp mean is too constrained to show a correlation)
MEMORY_MIN_CHIRPS = 4


def memory_stats(residual: np.ndarray, excess: np.ndarray, cells):
    """What :func:`chirp_memory` pools over the folds from one fold's held-out
    ``cells`` (boolean ``[F, T, R, C]``): per range bin (unitary DFT of
    ``residual``, complex ``[F, T, R, C, N]``, time domain) the sum of the lag-1
    products ``D_{c+1} conj(D_c)`` and of ``|D_c|^2`` of the deviation from the
    chirp mean (:func:`~sionna_mmir.effects.library._sensor_common.chirp_deviation`,
    whose scale cancels in :func:`chirp_memory`) over the series (frame, Tx,
    Rx) whose chirps are all held out, the candidate's predicted variance
    over the white floor (``excess``, broadcastable to ``residual``) summed
    there, and the number of series;
    None with fewer than :data:`MEMORY_MIN_CHIRPS` loops or no such series."""
    C = residual.shape[3]
    full = np.all(np.asarray(cells, bool), axis=3)                  # [F, T, R]
    if C < MEMORY_MIN_CHIRPS or not full.any():
        return None
    D = np.fft.fft(chirp_deviation(residual)[full], axis=-1, norm="ortho")   # [S, C, N]
    return {"lag": np.sum(D[:, 1:] * np.conj(D[:, :-1]), axis=(0, 1)),
            "power": np.sum(np.abs(D) ** 2, axis=(0, 1)),
            "excess": np.clip(np.broadcast_to(excess, residual.shape)[full].sum(axis=(0, 1)),
                              0, None),
            "series": int(full.sum()), "chirps": C}


def chirp_memory(stats: list) -> tuple:
    """How much of the chirp-to-chirp scatter a noise model claims repeats
    from one chirp loop to the next: ``(memory, limit)``.

    Noise (thermal, a phase-noise skirt, a coloured floor) is independent
    from chirp to chirp; a disturbance that drifts over the frame (a power
    amplifier's droop, a target's motion) is not, even where a stationary
    noise model fits its power.  Per range bin ``k``, pooled over the folds'
    :func:`memory_stats` (``S`` series of ``C`` loops), the lag-1
    correlation of the deviation from the chirp mean is
    ``rho_k = (A_k / (S (C - 1))) / (P_k / (S C)) + 1 / (C - 1)``
    (``A_k``, ``P_k`` the summed lag products and powers): removing the mean
    makes white deviations correlate by exactly ``-1 / (C - 1)``
    (``E[D_{c+1} conj(D_c)] = -s^2 / C``, ``E|D_c|^2 = s^2 (C - 1) / C``),
    which the second term takes out, so white noise gives ``|rho_k| ~ 1 / sqrt(n)``
    (``n = S (C - 1)`` pairs) and a drift up to 1.  ``memory`` is the mean
    of ``|rho_k|`` weighted by the candidate's predicted excess variance;
    ``limit`` = :data:`MAX_CHIRP_MEMORY` ``+ 3 / sqrt(n)``.  ``(0, inf)``
    when no fold had a statistic.
    """
    stats = [s for s in stats if s is not None]
    if not stats:
        return 0.0, float("inf")
    C, S = stats[0]["chirps"], sum(s["series"] for s in stats)
    lag = sum(s["lag"] for s in stats) / (S * (C - 1))
    power = sum(s["power"] for s in stats) / (S * C)
    rho = np.abs(lag / np.maximum(power, 1e-300) + 1.0 / (C - 1))
    w = sum(s["excess"] for s in stats)
    memory = float(w @ rho / w.sum()) if w.sum() > 0 else 0.0
    return memory, MAX_CHIRP_MEMORY + 3.0 / np.sqrt(S * (C - 1))


def _fit_candidate(cand: EffectModel, eff, train, maxiter: int, hold_refinement: bool = False) -> None:
    """Fit the candidate ``eff`` (the last component of ``cand``) on ``train``.

    An effect that may make adopted ones redundant (``eff.may_replace``, e.g.
    ego motion beside movers: a mover adopted first may be a static object
    seen from the moving radar, and ego motion scored with it held fixed
    would show that object twice; an IF filter beside an adopted leakage,
    which was fitted to what the filter leaves of it) is fitted alone with
    those silenced (:meth:`~sionna_mmir.effects.base.Effect.silenced`), then
    with every component, so the object's amplitude can move back from the
    mover to the scene and the leakage regrow behind the filter.  Unless
    the candidate has a state of rest (:func:`_has_rest`) and the silenced
    components, restored at their fitted values beside it as fitted alone,
    explain the training cells better: then they are not what it replaces
    (a real walker, beside which ego motion finds the radar nearly at rest),
    and only the candidate and they are refitted (a fit of every component
    on the training channels of every chirp took 90-200 s a round beside the
    suite's walker and lost 11 000-74 000 held-out nats the components had
    fitted on all channels; requiring the candidate to be exactly at rest
    let a float32 NLL's rounding decide).  Where the candidate is real the
    restored components count its objects twice and the silenced start is
    better.  An IF filter has no rest: beside it the leakage regrows in a
    joint fit of every component (restored as fitted, a run's filter was
    lost), from silence or, where that explains the training cells better,
    moved behind the fitted filter (:func:`_start_behind`).
    Components named in ``eff.refit_beside`` are fitted together with it
    throughout (an IF filter's attenuation of the nearest targets is what
    the base fit's object gains took), and so is the base refinement beside
    a per-channel phase effect while the refinement's pose is pinned at its
    bounds (:func:`~sionna_mmir.effects.library.scene_mismatch.refinement_pinned`),
    unless ``hold_refinement``: fitted beside the held refinement first,
    then with it freed from there (on corner_4m7 the delays' freed fit from
    their initial values left one fold of three in a basin 20 000 held-out
    nats short, in two loops of two; from the held fit none).  The
    adoption fits it the same way.  Returns whether its fold base is to be
    refitted the same way (:func:`_refit_base`): for a candidate without a
    rest, which refits the components it may replace on ``train``."""
    new = len(cand.components) - 1
    names = set(eff.may_replace)
    replaced = [c for c in cand.components[:new] if c.effect.name in names]
    beside = set(eff.refit_beside)
    own = [new] + [i for i, c in enumerate(cand.components[:new]) if c.effect.name in beside]
    if eff.channel_phase and not hold_refinement and refinement_pinned(cand):
        cand.fit(trainable=own, cells=train, maxiter=maxiter)       # the refinement held,
        own = own + [i for i, c in enumerate(cand.components[:new])  # then freed from there
                     if c.effect.name in BASE_REFINEMENT_NAMES]
    if not replaced:
        cand.fit(trainable=own, cells=train, maxiter=maxiter)
        return False
    fitted = [c.values for c in replaced]
    for c in replaced:
        c.values = c.effect.silenced(c.values) or c.values
    cand.fit(trainable=own, cells=train, maxiter=maxiter)
    silenced = [c.values for c in replaced]
    quiet = cand.nll(train)
    for c, v in zip(replaced, fitted):
        c.values = v
    if _has_rest(cand) and cand.nll(train) < quiet:
        ids = {id(c) for c in replaced}
        cand.fit(trainable=own + [i for i, c in enumerate(cand.components) if id(c) in ids],
                 cells=train, maxiter=maxiter)
        return False
    for c, v in zip(replaced, silenced):
        c.values = v
    _start_behind(cand, replaced, fitted, train, quiet)
    fit_joint(cand, train, maxiter)
    return not _has_rest(cand)


def _start_behind(cand: EffectModel, replaced: list, fitted: list, train, quiet: float) -> None:
    """Start the ``replaced`` components (silenced in ``cand``) behind the
    candidate filter, the last component, where that explains the training
    cells better than their silence (training NLL under ``quiet``): their
    ``fitted`` values, fitted to what the filter leaves, with each tone
    divided by the filter's gain there (:meth:`~sionna_mmir.effects.base.Effect.behind`).
    A leakage regrown from silence in the joint fit ended in a basin where
    it sat behind the filter's notch about 30 times too strong, its delay
    on a bound, and predicted held-out channels worse than nothing."""
    filt = cand.components[-1]
    def gains(f):
        return filt.effect.tone_gains(filt.values, cand.ctx, f)
    starts = [c.effect.behind(v, cand.ctx, gains) for c, v in zip(replaced, fitted)]
    if all(s is None for s in starts):
        return
    silenced = [c.values for c in replaced]
    for c, s in zip(replaced, starts):
        if s is not None:
            c.values = s
    if not cand.nll(train) < quiet:
        for c, v in zip(replaced, silenced):
            c.values = v


def _has_rest(cand: EffectModel) -> bool:
    """Whether the last component of ``cand`` has a state that explains
    nothing (:meth:`~sionna_mmir.effects.base.Effect.silenced`: ego motion
    at rest), so that fitted alone it is compared with the components it may
    replace on equal terms; an IF filter has none (it reshapes everything
    behind it)."""
    own = cand.components[-1]
    return own.effect.silenced(own.values) is not None


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


def _claimed(model, x, v, excess):
    """The scatter a noise model claims per cell and bin: its variance over
    the white floor ``excess`` plus the power of the deviation it predicts
    from other cells (:meth:`~sionna_mmir.effects.model.EffectModel.predict_deviation`;
    ``x``, ``v`` the model's current mean and variance), which
    :func:`memory_stats` weighs the chirp memory by."""
    d = chirp_deviation(model.y - x)
    if d is None or not model.deviation_predictors():
        return excess
    pred = model.predict_deviation(x, d, v)
    return excess + np.abs(np.fft.fft(pred, axis=-1, norm="ortho")) ** 2


def _candidate_task(shared, g: int, k: int, eff, maxiter: int, deviation: bool,
                    i: int = 0, start: dict | None = None) -> dict:
    """Worker task: candidate ``eff`` (number ``i`` of group ``g``) added to
    the group's fold ``k`` base, fitted on its training cells, and what the
    ranking needs from its held-out cells (``"key"``: ``(g, k, i)``).
    ``start``: the candidate's values to start from instead of its own
    initial guess (a restart, :func:`_restarts`); the result then carries
    ``"restart": True``.  A mean candidate's result carries its fitted
    ``"values"`` and its training NLL (``"train_nll"``)."""
    t0 = time.perf_counter()
    train, base = shared[g][k]
    shape = None if eff.kind == "variance" else base.white_shape_numpy()
    cand = base.copy()
    cand.add(copy.deepcopy(eff), cells=train)          # fresh state per fold
    if start is not None and _same_layout(cand.components[-1].values, start):
        cand.components[-1].values = {n: np.array(v, copy=True) for n, v in start.items()}
    refit = False
    if deviation:              # a noise model, fitted to the scatter it is scored on
        cand.fit_to_scatter([len(cand.components) - 1], cells=train, maxiter=maxiter)
    else:
        refit = _fit_candidate(cand, eff, train, maxiter)
    last = cand.components[-1]
    out = {"key": (g, k, i), "nll": cand.nll_profiled(~train, deviation=deviation),
           "n_params": int(last.n_params), "dev": deviation,
           "split": not deviation and cand.split_likelihood(),
           "floor": float(last.effect.fitted_gain_floor(cand, last.values))}
    if eff.kind == "variance":
        out["slots"] = cand.nll_profiled(~train, True, by_slot=True,
                                         deviation=_slot_deviation(deviation))[1]
        x, v = cand.mean_variance_numpy()
        white = float(np.exp(cand.nuisance.values["log_noise"][0]))
        out["memory"] = memory_stats(cand.y - x, _claimed(cand, x, v, v - white), ~train)
    else:
        out["bins"], _, out["energy"] = cand.energy_by_bin(~train, shape)  # base's noise units
    if out["split"]:
        out["noise_nll"] = cand.nll_profiled(~train, deviation=True)
        out["noise_slots"] = cand.nll_profiled(~train, True, by_slot=True,
                                               deviation=_slot_deviation(True))[1]
    if not deviation:
        out["values"] = {n: np.array(v, copy=True) for n, v in last.values.items()}
        out["train_nll"] = float(cand.nll(train))
    if start is not None:
        out["restart"] = True
    if refit:
        out["base"] = _refit_base(base, eff, train, maxiter)
    out["s"] = time.perf_counter() - t0
    return out


def _same_layout(values: dict, start: dict) -> bool:
    """Whether ``start`` has the names and shapes of ``values`` (a candidate
    whose initial guess sets its own layout on the fold's data, such as the
    number of atoms, keeps its own start where another fold's differs)."""
    return values.keys() == start.keys() and all(
        np.shape(values[n]) == np.shape(start[n]) for n in values)


def _restarts(fits: dict, bases: list) -> list:
    """Folds of one candidate to fit again, as ``(fold, start values)``: a
    fold whose held-out gain is negative and larger in size than the best
    fold's positive gain starts again from the best fold's fitted values.

    The candidate fits are not convex (a leakage's delays, a filter's
    corners), and one fold's fit can end in a basin the others avoid: on
    the suite's AWR1843 halls the leakage beside an adopted IF filter
    gained 523 and 629 held-out nats in two folds and lost 1 713 in the
    other, and was not adopted.  Which of the two fits of a fold counts is
    decided by the training NLL alone (:func:`_pick_fit`), so the held-out
    cells choose nothing; only the starting point comes from a fit that saw
    them.  ``fits``: ``{fold: result}`` of :func:`_candidate_task`, every
    fold fitted; ``bases``: the group's fold bases."""
    if len(fits) < 2 or any("values" not in f for f in fits.values()):
        return []
    gains = {k: _fold_gain(bases[k], f) for k, f in fits.items()}
    best = max(gains, key=gains.get)
    if gains[best] <= 0:
        return []
    return [(k, fits[best]["values"]) for k, g in gains.items() if g < -gains[best]]


def _pick_fit(old: dict | None, new: dict) -> dict:
    """Of two fits of one (candidate, fold), the one with the lower training
    NLL (a restart replaces the first fit only when it fits the training
    cells better)."""
    if old is None:
        return new
    first, again = (old, new) if new.get("restart") else (new, old)
    if not again.get("restart"):                 # the same fit twice (a worker died)
        return new
    return again if again["train_nll"] < first["train_nll"] else first


def _refit_base(base, eff, train, maxiter: int) -> dict:
    """The fold ``base``'s held-out scores (:func:`_base_scores`) with the
    adopted components ``eff`` may replace refitted on the training cells
    ``train``, as the candidate refits them beside it: fitted on every cell
    when they were adopted, they would predict the held-out cells from
    those cells themselves and the candidate would be judged against a
    base that has seen its test (the suite's AWR1843 room of seed 2: an IF
    filter with the leakage refitted behind it on the training channels lost
    353-556 held-out nats a fold against the adopted leakage, and gained
    179-256 against the same leakage refitted there).  Not for a candidate
    with a state of rest (ego motion beside movers): against movers
    refitted like it, ego motion beside a real walker gained 6.8 held-out
    nats for its one parameter (test 16b, NOTES.md)."""
    own = base.copy()
    names = set(eff.may_replace)
    own.fit(trainable=[i for i, c in enumerate(own.components) if c.effect.name in names],
            cells=train, maxiter=maxiter)
    return _base_scores(own, ~train, _base_needs(own, [eff]))


def rank_candidates(model: EffectModel, candidates, folds, penalty=BIC,
                    maxiter: int = 150, progress=None, pool=SERIAL, race: bool = True) -> list:
    """Held-out scores of ``candidates`` on top of ``model``, best first.

    The (candidate, fold) fits are independent and run on ``pool``
    (:class:`~.workers.FitPool`); ``progress(name)`` follows each candidate
    whose folds are all fitted; ``race`` as in :func:`rank_groups`."""
    return rank_groups([(model, candidates, folds)], penalty, maxiter, progress, pool,
                       race)[0]


def rank_groups(groups, penalty=BIC, maxiter: int = 150, progress=None, pool=SERIAL,
                race: bool = True) -> list:
    """:func:`rank_candidates` for several ``(model, candidates, folds)``
    groups at once (the data tiers of a round), one list per group.

    The fold bases of every group are fitted in one call on ``pool``, then
    every (candidate, fold) fit in another, the last group's first: the
    groups' fits share the worker processes instead of waiting for each
    other, and the longest (full-data) fits start first.  With ``race``, a
    candidate fitted on every chirp of several chirp loops (the costly
    ones) is fitted on its first fold first, and on the others only when its
    held-out gain there is positive (:func:`_races`)."""
    groups = [(m, list(c), f) for m, c, f in groups]
    base_tasks = [(g, k, maxiter, _base_needs(m, c))
                  for g, (m, c, f) in enumerate(groups) for k in range(len(f))]
    fitted = iter(pool.map(_fold_base_task, [(m, f) for m, _, f in groups], base_tasks))
    bases = []                 # per group, per fold: (train, base model, base scores, n_test)
    for m, _, folds in groups:
        per = []
        for train in folds:
            values, scores = next(fitted)
            base = m.copy()
            base.nuisance.values = values
            per.append((train, base, scores, float((~train).sum()) * m.ctx.shape[-1]))
        bases.append(per)
    tasks, left, racing = [], {}, set()
    for g in reversed(range(len(groups))):
        m, cands, folds = groups[g]
        first = 1 if race and _races(m, len(folds)) else len(folds)
        for i, eff in enumerate(cands):
            left[(g, i)] = first
            if first < len(folds):
                racing.add((g, i))
            dev = eff.kind == "variance" and m.ctx.shape[3] > 1
            tasks += [(g, k, eff, maxiter, dev, i) for k in range(first)]

    done, restarted = {}, set()

    def follow(_, fit):
        """Count ``fit`` as done; its other folds when it raced and won the
        first; a fold in a basin the others avoided again from their best
        (:func:`_restarts`, once per candidate)."""
        g, k, i = fit["key"]
        done.setdefault((g, i), {})[k] = fit
        more = []
        if k == 0 and (g, i) in racing and _fold_gain(bases[g][0], fit) > 0:
            more = [(g, j, groups[g][1][i], maxiter, fit["dev"], i)
                    for j in range(1, len(groups[g][2]))]
        left[(g, i)] += len(more) - 1
        if left[(g, i)] == 0 and (g, i) not in restarted:
            restarted.add((g, i))
            more = [(g, j, groups[g][1][i], maxiter, fit["dev"], i, start)
                    for j, start in _restarts(done[(g, i)], bases[g])]
            left[(g, i)] += len(more)
        if left[(g, i)] == 0 and progress is not None:
            progress(groups[g][1][i].name)
        return more

    shared = [[(b[0], b[1]) for b in per] for per in bases]
    fits = pool.map(_candidate_task, shared, tasks, follow=follow)
    by_key = {}                                        # ((group, cand), fold) -> fit
    for f in fits:
        key = ((f["key"][0], f["key"][2]), f["key"][1])
        by_key[key] = _pick_fit(by_key.get(key), f)
    return [_scores(g, cands, bases[g], by_key, penalty)
            for g, (_, cands, _) in enumerate(groups)]


def _races(model, n_folds: int) -> bool:
    """Whether candidates on ``model`` are raced (:func:`rank_groups`): fitted
    on every chirp of several chirp loops, where one fold fit costs ``C``
    times a fit on the chirp average (ego motion, an IF filter or a second
    mover beside an adopted mover: 15-60 s of a round's fits each).  A
    candidate whose held-out gain is not positive on a third of the channels
    is not adopted in that round; in the suite's reports a candidate raced
    out that way was never a planted effect that round's ranking chose."""
    return model.ctx.shape[3] > 1 and n_folds > 1


def _fold_gain(base, fit) -> float:
    """Held-out NLL reduction [nats] of one (candidate, fold) ``fit`` against
    its fold ``base`` (an entry of :func:`rank_groups`'s bases)."""
    return _base_nll(fit.get("base", base[2]), fit) - fit["nll"] * base[3]


def _base_nll(base: dict, fit: dict) -> float:
    """The fold base's held-out NLL a candidate's is compared with: on the
    chirp-to-chirp deviation for a noise model, with the split likelihood
    for a candidate scored with it (a noise shaper added to a model without
    one: ``base["split"]``; a base with a noise shaper is split already),
    else the plain one."""
    if fit["dev"]:
        return base["dev"]
    if fit["split"] and "split" in base:
        return base["split"]
    return base["nll"]


def _memory_fields(stats: list) -> dict:
    """``chirp_memory`` and ``memory_limit`` of a :class:`CandidateScore`."""
    memory, limit = chirp_memory(stats)
    return {"chirp_memory": memory, "memory_limit": limit}


def _scores(g, candidates, bases, fits, penalty) -> list:
    """The :class:`CandidateScore` of every candidate of group ``g``, best first."""
    out = []
    for i, eff in enumerate(candidates):
        gains, n_tot, cell_gains, energy, secs = [], 0.0, [], [0.0, 0.0], 0.0
        floors, memory, bins, noise = [], [], [0.0, 0.0, 0.0], []
        for k, (train, _, base, n_test) in enumerate(bases):
            fit = fits.get(((g, i), k))
            if fit is None:                     # raced out after its first fold
                continue
            base = fit.get("base", base)        # refitted beside a replacing candidate
            secs += fit["s"]
            floors.append(fit["floor"])
            gains.append(_fold_gain(bases[k], fit))
            if "noise_nll" in fit and "dev" in base:
                noise.append(base["dev"] - fit["noise_nll"] * n_test)
            if "noise_slots" in fit and "slots" in base:
                cell_gains.append(base["slots"] - fit["noise_slots"])
            if eff.kind == "variance":
                cell_gains.append(base["slots"] - fit["slots"])
                memory.append(fit["memory"])
            else:
                energy[0] += base["energy"]
                energy[1] += fit["energy"]
                bins = [bins[0] + base["bins"], bins[1] + fit["bins"], bins[2] + base["power"]]
            n_tot += n_test
        n_params = fits[((g, i), 0)]["n_params"]
        gain = float(np.sum(gains))
        out.append(CandidateScore(name=eff.name, n_params=n_params, gain=gain,
                                  gain_per_sample=gain / max(n_tot, 1.0),
                                  score=gain - penalty_per_param(penalty, n_tot) * n_params,
                                  fold_gains=[float(x) for x in gains],
                                  slot_share=(slot_share(cell_gains, [~b[0] for b in bases])
                                              if cell_gains else 1.0),
                                  energy_change_db=(_db(energy[1] / energy[0])
                                                    if energy[0] > 0 else 0.0),
                                  **_memory_fields(memory),
                                  outside_share=(outside_share(*bins)
                                                 if eff.kind != "variance" else 0.0),
                                  fit_s=secs, gain_floor=float(np.median(floors)),
                                  noise_gain=(float(np.sum(noise)) - penalty_per_param(
                                      penalty, n_tot) if noise else None)))
    return sorted(out, key=lambda c: c.score, reverse=True)


#: share of the model's power held by the range bins of its strongest
#: objects (each peak with its two neighbours) in :func:`outside_share`
OBJECT_POWER_SHARE = 0.5


def outside_share(base, cand, power) -> float:
    """Held-out residual energy a candidate removes outside the range bins of
    the model's strongest objects, over what it removes at them.

    ``base``, ``cand``: the held-out residual energy per range bin ``[N]``
    without and with the candidate, ``power`` the base model's.  The
    strongest objects' bins are its largest peaks, each with the bins beside
    it, taken in order until they hold :data:`OBJECT_POWER_SHARE` of the
    power.  An effect on every path (a per-channel gain, IQ imbalance, a
    delay) removes residual wherever there is signal, about in proportion
    to its power; a per-channel effect that takes the misfit of the two
    strongest objects (which per-object patterns explain as well) makes the
    other bins worse.  0 where the arrays are missing or nothing is removed
    at the objects and nothing lost elsewhere."""
    base, cand, power = (np.asarray(a, np.float64) for a in (base, cand, power))
    if base.ndim != 1 or not np.any(power > 0):
        return 0.0
    N = len(power)
    inside = np.zeros(N, bool)
    for k in np.argsort(-power):
        if power[inside].sum() >= OBJECT_POWER_SHARE * power.sum():
            break
        inside[[(k - 1) % N, k, (k + 1) % N]] = True
    removed_in = float(np.sum((base - cand)[inside]))
    removed_out = float(np.sum((base - cand)[~inside]))
    if removed_in <= 0:
        return 0.0 if removed_out >= 0 else -np.inf
    return removed_out / removed_in


#: an effect on every path (``Effect.every_path``) is acceptable only while
#: :func:`outside_share` is at least minus this: it may not make the bins
#: outside the strongest objects worse by more than this share of what it
#: explains at them
OUTSIDE_TOLERANCE = 0.1


class _Tiers:
    """The models candidates are scored on: the chirp-averaged model for the
    chirp-static candidates (as many nats from a fraction of the data;
    :func:`_averaged_scoring`), the full model for the rest; with their
    cross-validation folds.  Adopted chirp-varying components enter the
    averaged model at their current values
    (:class:`~sionna_mmir.effects.frozen.FrozenPart`: a mover's averaged
    path, a noise effect's averaged variance); the full model is used for
    every candidate only when one of them has no averaged counterpart
    (ego motion; ADC clipping behind a chirp-varying mean effect)."""

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
        fast = [c for c in todo if _averaged_scoring(c, self.model)]
        slow = [c for c in todo if not _averaged_scoring(c, self.model)]
        groups = [(m, cands, f) for m, cands, f in ((self.avg, fast, self.avg_folds),
                                                    (self.model, slow, self.folds)) if cands]
        for out in rank_groups(groups, penalty, maxiter, progress, self.pool):
            self.scores.update((c.name, c) for c in out)
        return sorted((self.scores[c.name] for c in candidates), key=lambda c: c.score,
                      reverse=True)

    def on_one_scale(self, ranking, best, pool, ok, penalty, maxiter, progress):
        """``(ranking, best)`` with scores comparable across the tiers.

        A held-out gain on every chirp is not on the chirp average's scale (a
        misfit well above the noise gains up to ``C`` times more nats on the
        full data).  When the best acceptable candidate was scored on the full
        data and an acceptable chirp-averaged one ranks below it, that one is
        scored again on the full data and the two are compared there (not
        when the best was scored with the split likelihood, whose mean part
        is on the chirp average's scale already: :func:`_split_scored`)."""
        effects = {c.name: c for c in pool}
        if self.avg is self.model or _averaged_scoring(effects[best.name], self.model) \
                or _split_scored(effects[best.name], self.model):
            return ranking, best
        rival = next((c for c in ranking
                      if ok(c) and _averaged_scoring(effects[c.name], self.model)), None)
        if rival is None:
            return ranking, best
        (again,) = rank_candidates(self.model, [effects[rival.name]], self.folds, penalty,
                                   maxiter, progress, self.pool)
        # its gain floor stays judged on the chirp average, where it is set
        again = dataclasses.replace(again, gain_per_sample=rival.gain_per_sample)
        ranking = sorted([again if c is rival else c for c in ranking],
                         key=lambda c: c.score, reverse=True)
        return ranking, next((c for c in ranking if ok(c)), None)

    def object_test(self, effect, n_params, penalty, maxiter) -> dict:
        """:func:`~.object_transfer.held_out_object_gain` of the pattern
        ``effect`` on the model it is scored on, with the penalty of
        ``n_params`` parameters there: ``{"shared", "own", "penalty"}`` [nats]."""
        from .object_transfer import held_out_object_gain

        m = self.avg if _averaged_scoring(effect, self.model) else self.model
        shared, own = held_out_object_gain(m, effect, maxiter)
        cost = penalty_per_param(penalty, float(np.prod(m.ctx.shape))) * n_params
        return {"shared": float(shared), "own": float(own), "penalty": float(cost)}


def _averaged_scoring(eff, model) -> bool:
    """Whether ``eff`` is scored and fitted on chirp-averaged data beside
    ``model``'s components: an effect that commutes with the average there
    (:meth:`~sionna_mmir.effects.model.EffectModel.static_flags`: chirp-static,
    or ADC clipping behind a static mean model), unless it also shapes the
    receiver noise (an IF filter): averaging over chirps buries the noise
    shape, its most robust signature, under what the scene leaves
    unexplained."""
    return model.static_flags(eff)[-1] and not getattr(eff, "shapes_noise", False)


def _mean_only(eff) -> bool:
    """Whether ``eff`` changes the mean model only (no variance, no noise
    shape): such an effect must lower the mean model's squared error
    (:func:`_mean_worse`, :attr:`CandidateScore.energy_change_db`)."""
    return eff.kind != "variance" and not getattr(eff, "shapes_noise", False)


#: a variance effect must lower the held-out NLL in more of the transmit
#: slots (:func:`slot_share`) than this share by two standard deviations of a
#: coin toss (:func:`required_slot_share`): it models stationary noise
MIN_SLOT_SHARE = 0.5


def required_slot_share(n_slots: int) -> float:
    """Least slot share of an acceptable variance effect over ``n_slots``
    transmit slots: :data:`MIN_SLOT_SHARE` plus two standard deviations of
    the share a coin toss per slot would give (``0.5 / sqrt(n)``), so a noise
    model that helps in half the slots, as a disturbance confined to some
    of them lets it, is not "most" (24 slots: 0.70; 192: 0.57)."""
    return min(1.0, MIN_SLOT_SHARE + 1.0 / np.sqrt(max(int(n_slots), 1)))

#: a variance effect is not acceptable when the scatter it claims repeats
#: from chirp to chirp by more than this lag-1 correlation plus three times
#: white noise's (:func:`chirp_memory`: white ~ 1 / sqrt(n); the data's
#: deviation at a droop over the frame or an unexplained walker: 0.6-0.9 on
#: the suite's cascade runs)
MAX_CHIRP_MEMORY = 0.3

#: a held-out object releases a sensor effect that per-object patterns hold
#: back (:func:`_scene_first`, :func:`_objects_agree`) when the strongest
#: object's pattern gains more than this many times the sensor effect's
#: parameter penalty on the second strongest object ...
OBJECT_EVIDENCE = 2.0
#: ... and at least this share of what that object's own pattern gains.
#: Measured (:mod:`~.object_transfer`): shares 0.89-0.99 and gains of 5.7-72
#: penalties with a planted gain (four captures); without one, 0.43 of the
#: own gain on the cascade's clean room (6.9 penalties) and under one
#: penalty on nine AWR1843 captures.  A wrong release puts a sensor effect
#: on a clean capture.
OBJECT_AGREEMENT = 0.8


def _objects_agree(test: dict) -> bool:
    """Whether a held-out object test (:meth:`_Tiers.object_test`) shows the
    pattern common to the objects: :data:`OBJECT_EVIDENCE` and
    :data:`OBJECT_AGREEMENT` both met."""
    return (test["shared"] > OBJECT_EVIDENCE * test["penalty"]
            and test["shared"] >= OBJECT_AGREEMENT * test["own"])


#: a sensor effect is adopted only when its held-out gain exceeds every
#: scene-side candidate's by more than this share (:func:`_scene_first`)
SCENE_MARGIN = 0.1


def _scene_first(ranking, best, ok, scene_side, admissible=None, common=None):
    """The scene-side candidate adopted in place of a sensor-side ``best``
    whose held-out gain a scene-side candidate reaches to within
    :data:`SCENE_MARGIN`: the best acceptable one within reach; when every
    one within reach is acceptable but for its penalty (``admissible``, the
    acceptance rules without ``score > 0``), the best acceptable scene-side
    candidate of the round, or None (nothing of this tier is named);
    ``best`` when no scene-side candidate comes within reach.

    Scene mismatch before sensor effects: the scene-side candidates only
    approximate how a real scene differs from its mesh (object patterns,
    points, shifts), while a per-channel sensor effect mimics much of that
    difference (a per-Tx gain mends a scatterer the mesh puts at a slightly
    wrong height on a radar whose Tx sit at two heights).  A sensor effect
    that beats them narrowly has not shown that the sensor, not the scene,
    is wrong; if it is really there it keeps its gain after the scene is
    mended and is adopted in a later round.

    A scene-side explanation that predicts the held-out channels as well
    but costs more parameters than its gain pays for still shows that the
    residual is organised by the scene, not by the channels: on a clean
    AWR1843 capture of the suite's second hall, object patterns gained 146.5
    held-out nats against a per-channel gain's 107.4 but their 42
    parameters made their score negative, and the gain was adopted for a
    scene misfit.  The sensor effect then waits; what the scene side can
    name is adopted first.

    Unless the objects agree: ``common(best)`` is ``(name, agree)`` for a
    sensor effect with a per-object twin (a per-channel gain and per-object
    patterns), ``agree`` True when the twin fitted on the strongest object
    alone predicts the next strongest nearly as well as that object's own
    pattern, by far more than ``best``'s parameters cost
    (:func:`_objects_agree`); None without a twin or a second object.
    A gain that patterns can only copy onto the strongest objects is the
    sensor's: left to them, it is never mended on the rest (the suite's
    AWR1843 room of seed 3: the planted gain scored -745 nats after the
    patterns took it).

    And the objects must agree wherever the test can be made, within reach
    or not (None is returned when they do not): a sensor's gain is common
    to every object, so a per-channel gain whose pattern the second object
    does not share is fitting the strongest objects' own misfit, however
    far it leads (the suite's AWR1843 hall of seed 4: an unplanted gain led
    the patterns by 16 % on the pose-offset run, and behind ego motion it
    was adopted with the patterns far behind)."""
    if scene_side.get(best.name, True):
        return best
    admissible = admissible or ok
    twin = None if common is None else common(best)
    if twin is not None and not twin[1]:
        return None
    reach = [c for c in ranking if admissible(c) and scene_side.get(c.name, True)
             and c.gain >= (1.0 - SCENE_MARGIN) * best.gain]
    if twin is not None and any(c.name == twin[0] for c in reach):
        return best
    scene = [c for c in reach if ok(c)]
    if scene:
        return max(scene, key=lambda c: c.score)
    if not reach:
        return best
    return max((c for c in ranking if ok(c) and scene_side.get(c.name, True)),
               key=lambda c: c.score, default=None)


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
    every_path = {c.name for c in pool if getattr(c, "every_path", False)}

    def slots_needed():
        shape = tiers.model.ctx.shape
        return required_slot_share(int(np.prod(shape[:4])) // shape[2])

    held = set()                 # sensor effects a costlier scene-side candidate out-predicts
    tested = {}                  # scene-side name -> object_test (measured once a round)

    def common(b):
        twin = next((e for e in pool if e.shared_twin == b.name), None)
        if twin is None:
            return None
        if twin.name not in tested:
            tested[twin.name] = tiers.object_test(twin, b.n_params, penalty, maxiter)
        if not np.isfinite(tested[twin.name]["shared"]):     # no second object to ask
            return None
        return twin.name, _objects_agree(tested[twin.name])

    def ok(c):
        return c.score > 0 and admissible(c) and c.name not in held

    def admissible(c):
        variance = kinds_of.get(c.name) == "variance"
        stationary = (c.slot_share >= slots_needed() and c.chirp_memory <= c.memory_limit
                      if variance else _stationary_shaper(c, slots_needed))
        predicts_mean = c.name not in mean_only or c.energy_change_db <= 0.0
        follows_signal = c.name not in every_path or c.outside_share >= -OUTSIDE_TOLERANCE
        least = max(floor.get(c.name, min_gain), c.gain_floor)
        return (c.gain_per_sample >= least and stationary
                and predicts_mean and follows_signal and _shapes_held_out_noise(c)
                and c.name not in vetoed)

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
        while best is not None:
            chosen = _scene_first(ranking, best, ok, scene_side, admissible, common)
            if chosen is not None:
                best = chosen
                break
            held.add(best.name)
            best = next((c for c in ranking if ok(c)), None)
        ranking, best = _with_object_tests(ranking, best, tested)
        if best is not None:
            best = _parsimonious(ranking, best, ok, scene_side)
            if kinds == ("basis", "mean") and _shapes_noise(pool, best):
                return _noise_before_shaper(tiers, pool, ranking, best, ok, screened,
                                            (penalty, maxiter, progress))
            return ranking, best
    return ranking, None


def _with_object_tests(ranking, best, tested):
    """``(ranking, best)`` with the measured :attr:`CandidateScore.object_test` filled in."""
    if not tested:
        return ranking, best
    ranking = [dataclasses.replace(c, object_test=tested[c.name]) if c.name in tested else c
               for c in ranking]
    return ranking, None if best is None else next(c for c in ranking if c.name == best.name)


def _shapes_held_out_noise(score) -> bool:
    """Whether a noise shaper scored with the split likelihood predicts the
    held-out chirp-to-chirp scatter better than its base by more than one
    parameter's penalty (:attr:`CandidateScore.noise_gain` > 0; True for
    every other candidate).

    An IF filter's response on the mean is a smooth complex gain over beat
    frequency, which mends a scene misfit as readily as it models a filter
    (the suite's AWR1843 delay-offset run of seed 1: a 7 kHz high-pass and a
    2.4 MHz low-pass filtering none of the noise, adopted for 35 nats of
    scrambled channel phases); the receiver noise passing it is what only a
    filter explains.  Scores from one chirp loop have no scatter to judge
    and are not held to it."""
    return score.noise_gain is None or score.noise_gain > 0.0


def _stationary_shaper(score, slots_needed) -> bool:
    """Whether the noise shape a noise shaper claims (scored with the split
    likelihood: :attr:`CandidateScore.noise_gain` set) is the receiver's: it
    lowers the held-out NLL of the chirp-to-chirp scatter in at least
    ``slots_needed`` of the transmit slots (:func:`slot_share`, as a noise
    model must; a float, or a callable giving it, called only for a noise
    shaper; True for every other candidate).

    Receiver noise passes the IF filter in every transmission; a burst of
    interference in a few chirps is scatter with a spectrum too (the suite's
    AWR1843 interferer: a 9 kHz / 4.9 MHz "filter" gained 146 held-out nats
    on the scatter, in 5 of the 24 slots, and was adopted as the room's only
    sensor effect), and a filter shaped to it is the disturbance absorbed,
    not a filter; the planted filters of the suite claim 0.83-1.0 of the
    slots (`tests/test_residual_diagnosis.py::test_10c`)."""
    if score.noise_gain is None:
        return True
    return score.slot_share >= (slots_needed() if callable(slots_needed) else slots_needed)


def _shapes_noise(pool, score) -> bool:
    """Whether the candidate scored by ``score`` shapes the receiver noise (an IF filter)."""
    return any(getattr(c, "shapes_noise", False) for c in pool if c.name == score.name)


def _noise_before_shaper(tiers, pool, ranking, best, ok, screened, fit_args):
    """``(ranking, best)`` when the round's best mean candidate shapes the
    noise: the noise models are scored too, and the best acceptable one is
    chosen instead when it gains more.

    Noise models are otherwise scored only once no mean candidate is
    acceptable, but an IF filter's gain is mostly its noise shape: left
    alone, a filter took a coloured receiver floor (the suite's phase-noise +
    noise-floor pair: the filter gained 2 709 nats and was adopted, after
    which every noise model's fit lost), while the floor explains that
    shape alone (about 198 000 held-out nats in the noise-floor run).  A
    filter really there keeps its own signature, a notch at low beat
    frequencies that no floor rising towards DC makes, and its mean part
    (the suite's IF-filter run: 195 000 nats in the first round)."""
    noise = [c for c in pool if c.kind == "variance" and c.name not in screened]
    if not noise:
        return ranking, best
    ranking = sorted(ranking + tiers.rank(noise, *fit_args), key=lambda c: c.score,
                     reverse=True)
    names = {c.name for c in noise}
    rival = next((c for c in ranking if c.name in names and ok(c)), None)
    return ranking, (rival if rival is not None and rival.gain > best.gain else best)

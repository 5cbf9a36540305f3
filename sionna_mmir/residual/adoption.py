"""Adopting a chosen effect: the joint refit, restarts and backfitting of the
earlier adoptions, and the guard that undoes an adoption which made the
mean model worse.

The second half of :mod:`~sionna_mmir.residual.diagnosis`: :func:`_adopt`
adds the round's best effect, fits it as it was scored and then refits
every component jointly (on the chirp average where every component allows
it); :func:`_backfit`
re-initialises each earlier effect against the model without it and keeps
what lowers the NLL, with the independent trials on worker processes in an
order that gives the result of trying them one by one (:func:`_in_order`).
"""
from __future__ import annotations

import contextlib
import copy
import time

import numpy as np

from ..effects.blockwise import fit_joint
from ..effects.model import Component as _Component, EffectModel
from .ranking import _averaged_scoring, _fit_candidate, _mean_only
from .workers import SERIAL


def _trial_values(trial: EffectModel) -> tuple:
    """What a trial model's fit changed: its NLL, nuisance and component values."""
    return (trial.nll(),) + trial.snapshot()


def _restart_task(model, i: int, maxiter: int) -> tuple:
    """Worker task: ``model`` with component ``i`` refitted from its initial values."""
    trial = model.copy()
    c = trial.components[i]
    c.values = {k: np.array(s.init, copy=True) for k, s in c.specs.items()}
    fit_joint(trial, maxiter=2 * maxiter)
    return _trial_values(trial)


def _backfit_task(model, i: int, maxiter: int) -> tuple:
    """Worker task: ``model`` with component ``i`` re-initialised against the
    model without it (moved to the end) and everything refitted; returns the
    re-added effect and specs too (its initialisation may set its state)."""
    trial = model.copy()
    old = trial.components[i]
    trial.remove(old)
    new = trial.add(copy.deepcopy(old.effect))
    fit_joint(trial, maxiter=2 * maxiter)
    return _trial_values(trial) + (new.effect, new.specs)


_TRIALS = {"restart": _restart_task, "backfit": _backfit_task}


def _trial_task(model, kind: str, i: int, maxiter: int) -> tuple:
    """Worker task: the ``kind`` trial (``"restart"`` or ``"backfit"``) of component ``i``."""
    return _TRIALS[kind](model, i, maxiter)


def _keep(model: EffectModel, kind: str, i: int, result) -> None:
    """Give ``model`` what the kept ``kind`` trial of component ``i`` fitted
    (a backfitted effect is re-added at the end)."""
    trial = model.copy()
    if kind == "backfit":
        trial.remove(trial.components[i])
        trial.components.append(_Component(effect=result[3], specs=result[4], values={}))
    trial.restore(result[1:3])
    model.components, model.nuisance = trial.components, trial.nuisance


def _effect_position(model: EffectModel, effect) -> int:
    """Index of the component holding ``effect`` (by identity)."""
    return next(i for i, c in enumerate(model.components) if c.effect is effect)


def _in_order(model: EffectModel, plan, best: float, maxiter: int, pool) -> float:
    """The trials ``plan = [(kind, effect), ...]`` in order, each kept when it
    lowers the NLL below ``best``; every trial starts from the model the
    earlier kept ones left.

    The trials are run speculatively on ``pool``
    (:meth:`~.workers.FitPool.first`): all that remain start from the
    current model, the first one (in plan order) that helps is kept, the
    ones not yet started are cancelled, and those after it run again from
    the kept model.  The outcome is that of trying them one by one; on one
    process nothing runs in vain.  Effects are followed by identity, so a
    backfitted effect moving to the end of the chain changes no other
    trial.  Returns the model's NLL."""
    todo = list(plan)
    while todo:
        tasks = [(kind, _effect_position(model, eff), maxiter) for kind, eff in todo]
        bar = best - 1e-6
        hit = pool.first(_trial_task, model, tasks, lambda r: r[0] < bar)
        if hit is None:
            break
        j, r = hit
        _keep(model, tasks[j][0], tasks[j][1], r)
        best, todo = r[0], todo[j + 1:]
    return best


def _backfit(model: EffectModel, newest, maxiter: int, pool=SERIAL):
    """Restart and re-initialise the earlier adopted effects, refit all
    jointly after each, and keep every change that lowers the NLL.

    Restarts first: the components that allow it (e.g. a pose offset fitted
    before a sensor effect bent it) refitted from a fresh start.  Then
    backfitting: an effect adopted while another one was still missing is
    initialised (and fitted) to absorb part of that one's signature:
    per-channel delays adopted before a missing scatterer bend to its
    phases, and the scatterer proposed afterwards lands off its true
    position.  Once the newer effect is in, the earlier one's data-driven
    initialisation from the cleaner residual usually finds the right basin.
    Every earlier effect (not scene-side, not held fixed) whose part of the
    mean model overlaps the newest one's (:func:`_coupled`) gets one trial,
    in chain position order; the trials are one sequence (:func:`_in_order`).
    Returns the newest component (the same object unless a trial replaced
    the list).
    """
    coupled = _coupled(model, newest)
    plan = [("restart", c.effect) for c in model.components
            if getattr(c.effect, "restartable", False) and id(c) in coupled]
    plan += [("backfit", c.effect) for c in model.components
             if c is not newest and c.effect.kind != "basis" and not _frozen(c)
             and id(c) in coupled]
    _in_order(model, plan, model.nll(), maxiter, pool)
    return model.components[_effect_position(model, newest.effect)]


#: an earlier effect whose part of the mean model overlaps the newest effect's
#: by less than this (normalised inner product, :func:`_coupled`) is neither
#: restarted nor backfitted after the newest one's adoption
MIN_OVERLAP = 0.02


def _coupled(model: EffectModel, newest) -> set:
    """The ``id`` of each component that the adoption of ``newest`` may have
    freed from a wrong basin: those whose part of the mean model (the mean
    with minus the mean without them) overlaps ``newest``'s,
    ``|<d_i, d_new>| / (|d_i| |d_new|) >= MIN_OVERLAP``.

    An earlier effect that absorbed part of the newest one's signature
    shares signal with it after the joint refit; one that shares none (a
    static scatterer beside a walker, whose Doppler phases sum to ~0 over
    the chirps) lands in
    the same place when re-initialised, and its trial (a full refit, on
    every chirp beside a mover) is skipped.  Effects that shape the noise or
    spread power into the variance couple through the likelihood's weights,
    not the mean: with either of them every component is coupled, as is any
    component whose part is zero.

    Applied after an effect that varies from chirp to chirp (a mover), where
    every trial is a fit on every chirp and the Doppler phases make the
    test sharp.  After a chirp-static effect the trials run on the chirp
    average at a fraction of the cost and every one is tried: an earlier fit
    can sit in a wrong basin that the joint refit leaves sharing little with
    the newest effect (gated after static effects too, the AWR1843 coupling
    + IF-filter run lost its filter)."""
    comps = model.components
    if getattr(newest.effect, "chirp_static", True) or model.ctx.shape[3] < 2 \
            or not all(_mean_only(c.effect) and not c.effect.has_spread for c in comps):
        return {id(c) for c in comps}
    full = model.mean_variance_numpy()[0]
    parts = {}
    for c in comps:
        every = model.components
        model.components = [x for x in every if x is not c]
        try:
            parts[id(c)] = full - model.mean_variance_numpy()[0]
        finally:
            model.components = every
    d = parts[id(newest)]
    en = float(np.vdot(d, d).real)
    out = set()
    for c in comps:
        di = parts[id(c)]
        ei = float(np.vdot(di, di).real)
        if en <= 0 or ei <= 0 or abs(np.vdot(di, d)) >= MIN_OVERLAP * np.sqrt(en * ei):
            out.add(id(c))
    return out


def _position(model: EffectModel, comp) -> int:
    """Index of ``comp`` (by identity) in ``model.components``."""
    return next(i for i, c in enumerate(model.components) if c is comp)


@contextlib.contextmanager
def _timed(clock, stage: str):
    """Add the seconds of the ``with`` block to ``clock[stage]`` (``clock`` may be None)."""
    t0 = time.perf_counter()
    try:
        yield
    finally:
        if clock is not None:
            clock[stage] = clock.get(stage, 0.0) + time.perf_counter() - t0


def _adopt(model, eff, maxiter, pool=SERIAL, clock=None, hold_refinement=False):
    """Add ``eff``, fit it as it was scored (:func:`~.ranking._fit_candidate`:
    alone beside the model, or from the silenced effects it may replace),
    then refit everything jointly (backfitting earlier effects after a mean
    effect).  The joint fit starts from the candidate's own fit, not from its
    data-driven initial values: from those, on corner_4m7, the nuisance gain
    and the pose offset moved with the per-channel delays while these were
    still far off, and the joint fit stopped in a basin 1.9 dB above the one
    the delays reach alone first (-4.15 against -6.02 dB).  On
    chirp-averaged data when every component allows
    it (then the full model takes the values and refits its noise floor;
    chirp-varying components held fixed there are refitted jointly with the
    rest on the full data).  A noise model is fitted to the chirp-to-chirp
    scatter (:func:`_fit_noise_model`), as it was scored.  An effect fitted
    on every chirp for its noise shape (an IF filter) is backfitted on the
    chirp average: the earlier effects' signatures are in the mean, at
    ``1 / C`` of the cost.  A mover
    is backfitted on every chirp: on the average it would be held fixed, so
    its own refit would wait for a kept trial and leave part of a
    chirp-varying residual to the next mover.  ``clock`` (a dict) collects
    the seconds of the stages (``joint``, ``backfit``, ``carry_back``).
    ``hold_refinement``: the candidate's own fit leaves the base refinement
    where it is even while its pose is pinned (the second start of
    :meth:`~.diagnosis.DiagnosisRun._adopt_or_undo`).  Returns the new
    component."""
    static = _averaged_scoring(eff, model) and model.can_average()
    work = model.chirp_averaged(freeze=True) if static else model
    comp = work.add(copy.deepcopy(eff))
    if eff.kind == "variance" and work.ctx.shape[3] > 1:
        with _timed(clock, "joint"):
            _fit_noise_model(work, comp, maxiter)
        return comp
    with _timed(clock, "joint"):
        _fit_candidate(work, comp.effect, None, 2 * maxiter, hold_refinement)  # as scored
        fit_joint(work, maxiter=2 * maxiter)
    if eff.kind != "variance":      # a noise model only reweights the mean fit
        with _timed(clock, "backfit"):
            if work is model and getattr(eff, "shapes_noise", False) and model.can_average() \
                    and model.ctx.shape[3] > 1:
                return _backfit_on_average(model, comp, maxiter, pool)
            comp = _backfit(work, comp, maxiter, pool)
    if work is not model:                   # the values carry over
        with _timed(clock, "carry_back"):
            comp = _carry_back(model, work, comp, maxiter)
    return comp


def _fit_noise_model(model, comp, maxiter) -> None:
    """Fit the variance component ``comp`` to the chirp-to-chirp scatter it
    was scored on (:meth:`~sionna_mmir.effects.model.EffectModel.fit_to_scatter`),
    then refit the mean components and the nuisance beside it held fixed: a
    noise model fitted to the whole residual would widen its variance where
    the scene misfit is instead of where the noise is."""
    k = _position(model, comp)
    model.fit_to_scatter([k], maxiter=2 * maxiter)
    model.fit(trainable=[i for i in range(len(model.components)) if i != k],
              maxiter=2 * maxiter)


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
    if joint or any(_frozen(c) for c in work.components):
        fit_joint(model, maxiter=2 * maxiter)
    else:
        model.fit(trainable=[], maxiter=maxiter)
    return model.components[k]


def _frozen(comp) -> bool:
    """Whether ``comp`` stands in, fixed, for a chirp-varying component."""
    from ..effects.frozen import FrozenPart

    return isinstance(comp.effect, FrozenPart)


#: a mean-kind adoption is undone when its joint refit raises the residual
#: energy ``|y - x|^2`` of all cells (in the receiver noise's units:
#: :meth:`~sionna_mmir.effects.model.EffectModel.shaped_energy`) by more than
#: this [dB] (:func:`_mean_worse`)
MEAN_GUARD_DB = 0.1
#: a variance-kind adoption is undone when its joint refit raises that energy
#: by more than this [dB] (:func:`_mean_worse`)
VARIANCE_GUARD_DB = 1.0


def _mean_worse(eff, rise: float) -> bool:
    """Whether adopting the mean-kind ``eff`` made the mean model worse: its
    joint refit raised the residual energy by ``rise`` [dB].

    The held-out likelihood is the adoption test, but beside adopted variance
    effects (a phase-noise skirt, a coloured floor) a mean effect can gain
    likelihood by raising the predicted variance where the residual is large
    instead of explaining it (a Tx->Rx leakage fitted beside phase noise on a
    measured capture can gain thousands of held-out nats while its tones
    overshoot the capture's leakage).  A mean effect that is
    really there lowers the squared error of the mean model, on held-out
    channels (:attr:`CandidateScore.energy_change_db`, required <= 0 in the
    ranking) and after the joint refit on all cells (checked here).  Variance
    effects that also shape the receiver noise are not held to it (an IF
    filter: most of its signature is the noise notch, and its fit trades a
    little mean misfit for it).

    Variance effects reweight the mean fit, which moves its squared error a
    little (a planted noise floor or phase noise: under 0.1 dB in the
    suite's runs); one whose joint refit raises it by more than
    :data:`VARIANCE_GUARD_DB` is taking misfit the mean should explain (a
    phase-noise skirt on corner_4m7 let the refit give up 2.1 dB of the
    corner's fit) and is undone too.

    The energy is measured in units of the receiver noise each range bin
    holds behind an adopted IF filter (the model's noise shape before the
    adoption: :meth:`~sionna_mmir.effects.model.EffectModel.shaped_energy`),
    as the likelihood weighs it: a leakage behind a high-pass lives in the
    bins the filter quietened, and its fit may trade a little misfit in the
    loud bins for it (the suite's AWR1843 room of seed 1, leakage and IF
    filter planted: +0.35 dB of plain held-out energy for 300 nats, -0.54 dB
    in the noise's units; adopted, the plain residual fell 1.88 dB).  Without
    a noise shaper that is the plain squared error."""
    if eff.kind == "variance":
        return rise > VARIANCE_GUARD_DB
    return _mean_only(eff) and rise > MEAN_GUARD_DB

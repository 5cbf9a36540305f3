"""The joint refit of a model with chirp-varying components, in two blocks.

A joint refit (:meth:`~.model.EffectModel.fit` of every component) of a
model that holds a chirp-varying effect (a mover, ego motion, ADC clipping
behind them) runs on every chirp: each loss-and-gradient evaluation moves the
whole scene through every stage, ``C`` times the samples of the chirp
average, for up to a few hundred L-BFGS iterations.  The scene-side
components, most of the parameters, commute with the chirp average, and the
chirp-varying ones have a chirp-averaged counterpart at fixed values
(:class:`~.frozen.FrozenPart`), so the refit splits into two blocks
(block-coordinate descent, alternated until the NLL settles):

1. **static block**: every chirp-static mean component and the nuisance gain
   on the chirp average, the chirp-varying ones frozen at their values
   (:meth:`~.model.EffectModel.chirp_averaged` with ``freeze=True``);
2. **varying block**: the chirp-varying components, the components that
   shape or spread the noise (fitted on every chirp, as they are scored) and
   the nuisance on every chirp, the static chain before them held and
   evaluated once (:meth:`~.model.EffectModel.frozen_prefix`).

With a white floor the first block is exact where the chirp-varying part is
added to the static one (a mover) and nothing static acts on it afterwards
(the static block holds the components before the first chirp-varying one
in the chain): for a chirp-static ``s`` and the rest held, ``sum_c |y_c - s - m_c|^2 = C |mean_c y_c - s - mean_c m_c|^2 +
const``, because the chirp-to-chirp deviation ``m_c - mean_c m_c`` does not
depend on ``s``; its optimum is then the full objective's optimum in those
parameters.  Behind ADC clipping the deviation of the clipped signal depends
on ``s`` where the clip is active, and the first block is exact only away
from it.  The descent stops when a cycle lowers the full NLL by less than
:data:`BLOCK_TOL` per sample, or after :data:`MAX_CYCLES` cycles; a cycle
that raises it is undone.

Ego motion is a map of the whole static scene: the deviation it makes is
the scene moved, a function of every static parameter, so the first block
would fit a different objective and the descent would settle away from the
joint optimum (on the suite's cascade room its adoption, blockwise, ran six
cycles and ended 0.013 nats per sample, ~10 000 nats, above the joint fit,
in more time: 389 against 328 s).  A model with a chirp-varying map of the
scene takes the one joint fit.

:func:`fit_joint` is the entry point: it takes the blocks where they exist
(two or more chirp loops, every component averageable, something to fit in
each block, no chirp-varying map of the scene) and the one joint fit
otherwise.
"""
from __future__ import annotations

import numpy as np

#: a cycle of the two blocks that lowers the full NLL by less than this
#: (nats per complex sample; ~0.8 nats over a 12 x 16 x 16 x 256 capture)
#: ends the descent
BLOCK_TOL = 1e-6
#: the most cycles of the two blocks in one refit
MAX_CYCLES = 6


def blocks(model, cells=None):
    """``(static, varying)`` component indices of ``model`` for the two
    blocks, or None where the blockwise refit does not apply: one chirp loop,
    a component without a chirp-averaged counterpart, a mask that does not
    hold every chirp of its channels, an empty block, a chirp-varying
    map of the scene (ego motion, :func:`_maps_scene`), or a model whose
    one joint fit runs on the chirp average already
    (:meth:`~.model.EffectModel.split_averaged`: nothing chirp-varying in
    the mean and a noise shaper), exact and as cheap, where the blocks
    would only alternate between coupled components (a Tx->Rx leakage
    regrowing behind an IF filter that replaces it: the AWR1843 coupling +
    IF-filter pair lost its filter to the descent).

    ``static``: the chirp-static mean and basis components with parameters
    that neither shape nor spread the noise and come before every
    chirp-varying mean component in the chain (the scene a mover is added
    to; a per-channel gain after it would also scale the mover's
    chirp-to-chirp deviation, which the chirp average cannot see);
    ``varying``: every other component with parameters (movers, clipping
    behind them, the sensor stages after them, noise shapers, variance
    effects)."""
    C = model.ctx.shape[3]
    if C < 2 or not model.can_average():
        return None
    if cells is not None:
        cells = np.asarray(cells, bool)
        if not np.array_equal(cells, np.broadcast_to(cells[..., :1], cells.shape)):
            return None
    flags, order = model.static_flags(), model._order()
    moving = [order.index(i) for i, (c, s) in enumerate(zip(model.components, flags))
              if not s and c.effect.kind == "mean"]
    if not moving and model.split_averaged(cells) is not None:
        return None
    first = min(moving, default=len(order))
    static, varying = [], []
    for i, (c, s) in enumerate(zip(model.components, flags)):
        if not c.specs:
            continue
        e = c.effect
        if s and e.kind in ("mean", "basis") and not e.has_spread \
                and not getattr(e, "shapes_noise", False) and order.index(i) < first:
            static.append(i)
        else:
            varying.append(i)
    if not static or not varying or any(_maps_scene(model.components[i].effect)
                                        for i in varying):
        return None
    return static, varying


def _maps_scene(effect) -> bool:
    """Whether a chirp-varying ``effect`` is a map of the scene before it
    (ego motion moves every static path), not an added path (a mover) or a
    sample-wise stage (clipping): its chirp-to-chirp deviation then depends
    on every static parameter, which the static block cannot see (module
    docstring)."""
    return effect.kind == "mean" and not effect.chirp_static \
        and not getattr(effect, "additive", False) and not effect.pointwise


def fit_joint(model, cells=None, maxiter: int = 300) -> dict:
    """Refit every component of ``model`` and the nuisance on ``cells``
    (None: all), blockwise where :func:`blocks` allows it (module docstring),
    else by one joint :meth:`~.model.EffectModel.fit`.  ``maxiter`` bounds
    each block's fit.  Returns ``{"nll", "cycles"}`` (``cycles`` 0: one joint fit)."""
    split = blocks(model, cells)
    if split is None:
        out = model.fit(cells=cells, maxiter=maxiter)
        return {"nll": out["nll"], "cycles": 0}
    static, varying = split
    best, cycles = model.nll(cells), 0
    while cycles < MAX_CYCLES:
        cycles += 1
        kept = model.snapshot()
        _fit_static(model, static, cells, maxiter)
        model.fit(trainable=varying, cells=cells, maxiter=maxiter)
        nll = model.nll(cells)
        if nll > best:                      # a cycle that made it worse is undone
            model.restore(kept)
            break
        if not best - nll > BLOCK_TOL:
            best = nll
            break
        best = nll
    return {"nll": best, "cycles": cycles}


def _fit_static(model, static, cells, maxiter: int) -> None:
    """The static block: fit components ``static`` and the nuisance gain on
    the chirp average with the chirp-varying components frozen, and give
    ``model`` the fitted values (its white floor is refitted in the varying
    block)."""
    avg = model.chirp_averaged(freeze=True)
    avg_cells = None if cells is None else np.asarray(cells, bool)[..., :1]
    avg.fit(trainable=static, cells=avg_cells, maxiter=maxiter)
    for i in static:
        model.components[i].values = {k: np.array(v, copy=True)
                                      for k, v in avg.components[i].values.items()}
    model.nuisance.values["gain"] = np.array(avg.nuisance.values["gain"], copy=True)

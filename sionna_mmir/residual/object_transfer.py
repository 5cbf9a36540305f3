"""A held-out object: is a per-object pattern the sensor's?

A per-channel gain of the sensor multiplies every object's return alike; a
scene mismatch (an object whose shape, height or aspect the mesh has a
little wrong) changes one object's return across the aperture.  Per-object
patterns (:class:`~sionna_mmir.effects.library.scene_mismatch.ObjectPattern`,
a per-Tx x per-Rx gain per object) take either, and where one object holds
most of the energy both predict held-out *channels* about equally well: on
the suite's AWR1843 room of seed 3 with a planted gain, 6 021 held-out nats
for the gain against 5 572 for the patterns; on the clean control of seed 0,
805 against 738, the same ratio.  A held-out *object* tells them apart: the
pattern is fitted on the strongest object alone and then given unchanged to
the next strongest (:meth:`~sionna_mmir.effects.library.scene_mismatch.ObjectPattern.shared`),
and what it gains there is compared with what that object's own pattern,
fitted from there, gains.  A sensor's gain is the same on both objects:
the shared pattern takes 0.89-0.99 of the own one's gain on four captures
with a planted gain (AWR1843 rooms and hall, the cascade room: +293 to
+21 703 nats).  Where the pattern is the first object's own misfit it gains
nothing there or less than the 14 parameters of a gain cost (-94 to +49
nats on nine AWR1843 captures without one: clean controls, a pose offset, a
Tx droop, a leakage beside an IF filter); where similar objects share part
of a misfit (the cascade's clean room, four trihedrals under one aspect
error) it gains a real amount, but only 0.43 of the own pattern's 4 862.

The next strongest object, not the sum over all of them: the weak ones
carry little evidence either way, while a sum lets chance agreement of
several small misfits add up.  Nor the other way round (fitted on the
others, scored on the strongest): the components overlap in range, so a
pattern fitted on the others also mends the strongest object's misfit
where it leaks into them (0.3-0.8 of its own fit's gain on every capture,
with or without a gain).
"""
from __future__ import annotations

import numpy as np

from ..effects.library.scene_mismatch import _strongest


def held_out_object_gain(model, pattern, maxiter: int = 150) -> tuple:
    """``(shared, own)`` NLL reductions [nats] on ``model``'s second
    strongest object: with ``pattern`` fitted on the strongest object alone
    and given to it unchanged, and with its own pattern fitted from there.

    ``model``: an :class:`~sionna_mmir.effects.model.EffectModel` with a
    per-object basis (the chirp-averaged model a round scores on);
    ``pattern``: an effect with ``on_lead()`` and ``shared(comp, ctx,
    objects)`` (:class:`~sionna_mmir.effects.library.scene_mismatch.ObjectPattern`).
    The nuisance gain and noise are fitted with the strongest object's
    pattern and then held, so only the second object's return changes.
    ``(-inf, 0.0)`` when the model has fewer than two objects."""
    lead = pattern.on_lead()
    m = model.copy()
    comp = m.add(lead)
    order = _strongest(m.ctx.basis.current_shares, 0.0, 2) if m.ctx.basis is not None else []
    if len(order) < 2 or lead.objects(m.ctx) != order[:1]:
        return -np.inf, 0.0
    m.fit(trainable=[len(m.components) - 1], maxiter=maxiter)
    n = float(m.mask_tensor()[1])
    alone = m.nll()
    second = m.add(pattern.on_lead())
    second.effect, second.specs, second.values = lead.shared(comp, m.ctx, order[1:])
    shared = (alone - m.nll()) * n
    m.fit(trainable=[len(m.components) - 1], maxiter=maxiter, nuisance=False)
    return shared, max(shared, (alone - m.nll()) * n)


__all__ = ["held_out_object_gain"]

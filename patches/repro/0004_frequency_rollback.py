"""0004: a failed ``scene.frequency`` update leaves the scene half-updated.

Bundled ``floor_wall`` scene (ITU concrete + brick) at the default 3.5 GHz;
``scene.frequency = 77e9`` raises because ITU-R P.2040 defines brick only for
1-40 and 110-330 GHz.  Stock 2.2.0: the scene then reports 77 GHz while its
materials keep their 3.5 GHz (or, depending on order, partly 77 GHz)
properties.  Patched: the error is still raised, and frequency and material
properties are those from before the assignment.
"""
from __future__ import annotations

from _common import report, setup

args, rt = setup(__doc__.splitlines()[0])

scene = rt.load_scene(rt.scene.floor_wall)


def state():
    return (float(scene.frequency[0]),
            tuple(f"{n} eps_r={float(m.relative_permittivity[0]):.4g} "
                  f"sigma={float(m.conductivity[0]):.4g}"
                  for n, m in sorted(scene.radio_materials.items())))


before = state()
try:
    scene.frequency = 77e9
    raised = "nothing raised"
except ValueError as e:
    raised = f"ValueError: {e}"
after = state()
if raised == "nothing raised":
    observed = "unexpected"
elif after == before:
    observed = "fixed"
else:
    observed = "bug"
report("0004 frequency rollback", args.expect, observed,
       f"{raised}; frequency {before[0]/1e9:g} GHz -> {after[0]/1e9:g} GHz, "
       f"materials {', '.join(before[1])} -> {', '.join(after[1])}")

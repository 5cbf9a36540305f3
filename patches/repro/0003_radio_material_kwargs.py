"""0003: unknown ``RadioMaterial`` keywords give an error naming neither.

``RadioMaterial("m", relative_permittivity=3.0, colour=(1, 0, 0))`` (a
misspelled ``color``) is passed on to the scattering pattern.  Stock 2.2.0:
``TypeError: LambertianPattern() takes no arguments``.  Patched: a
``TypeError`` naming the material, the parameter and the pattern.  Valid
pattern keywords (``alpha_r`` for "directive") and subclasses consuming their
own keywords keep working in both.
"""
from __future__ import annotations

from _common import report, setup

args, rt = setup(__doc__.splitlines()[0])


class RoughMaterial(rt.RadioMaterial):
    """A subclass adding its own parameter."""

    def __init__(self, *a, roughness: float = 0.0, **kw):
        super().__init__(*a, **kw)
        self.roughness = roughness


# Must keep working (before and after): valid pattern keyword, subclass keyword
rt.RadioMaterial("ok-directive", relative_permittivity=3.0, scattering_coefficient=0.3,
                 scattering_pattern="directive", alpha_r=4)
assert RoughMaterial("ok-rough", relative_permittivity=3.0, roughness=0.2).roughness == 0.2

try:
    rt.RadioMaterial("typo-mat", relative_permittivity=3.0, colour=(1.0, 0.0, 0.0))
    msg = "no error raised"
    observed = "unexpected"
except TypeError as e:
    msg = str(e)
    clear = "typo-mat" in msg and "colour" in msg and "lambertian" in msg
    observed = "fixed" if clear else "bug"
report("0003 RadioMaterial unknown kwargs", args.expect, observed, f"message: {msg!r}")

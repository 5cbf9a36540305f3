"""Radio devices: antenna element beam patterns of the radar's Tx/Rx elements.

``beam_pattern``  learnable ``cos^q`` element pattern (closed-form directivity
                  normalisation, per-element parameters), one shared ``cos^q``
                  shape per array with per-element gain residuals, isotropic pattern,
                  an adapter for Sionna RT's own patterns, and ``make_pattern``.

Importing this package configures the Dr.Jit backend
(:func:`sionna_mmir.utils.backend.init_backend`); Sionna RT itself is only
imported when a :class:`SionnaPattern` is built.
"""
from .beam_pattern import (
    DEFAULT_Q_AZ,
    DEFAULT_Q_EL,
    HALF_POWER_DB,
    Q_MIN,
    QUARTER_POWER_DB,
    BeamPattern,
    CosinePowerPattern,
    IsotropicPattern,
    SharedShapePattern,
    SionnaPattern,
    available_patterns,
    cosine_power_normalisation_np,
    make_pattern,
)

__all__ = [
    "BeamPattern",
    "CosinePowerPattern",
    "DEFAULT_Q_AZ",
    "DEFAULT_Q_EL",
    "HALF_POWER_DB",
    "IsotropicPattern",
    "Q_MIN",
    "QUARTER_POWER_DB",
    "SharedShapePattern",
    "SionnaPattern",
    "available_patterns",
    "cosine_power_normalisation_np",
    "make_pattern",
]

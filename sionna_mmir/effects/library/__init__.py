"""The effects library: one effect per module; :data:`LIBRARY` maps names to classes.

Each effect, its stage and what the base model lacks:

``missing_scatterer``
    scene: a static point scatterer (repeatable)
``moving_scatterer``
    scene: a moving point target, per-frame state
``multipath_ghost``
    scene: the strongest scatterer seen via a flat surface
``coupling``
    RF: Tx->Rx leakage at short delays
``channel_gain``
    RF: per-Tx and per-Rx complex gain
``delay_offset``
    RF: per-Tx and per-Rx delay
``frequency_offset``
    RF: per-chip beat-frequency offset
``chirp_nonlinearity``
    RF: chirp instantaneous-frequency error
``ego_motion``
    RF: radar radial velocity over slow time
``phase_noise``
    RF: LO phase-noise skirt (variance)
``if_filter``
    IF: two high-pass stages (with their settling) and the anti-alias low-pass
``noise_floor``
    IF: coloured receiver noise (variance)
``dc_offset``
    ADC: per-Rx DC
``iq_imbalance``
    ADC: per-Rx I/Q gain and phase error
``adc_clipping``
    ADC: I/Q saturation
"""
from .adc_clipping import ADCClipping
from .channel_gain import ChannelGain
from .chirp_nonlinearity import ChirpNonlinearity
from .coupling import Coupling
from .dc_offset import DCOffset
from .delay_offset import DelayOffset
from .ego_motion import EgoMotion
from .frequency_offset import FrequencyOffset
from .ghost import MultipathGhost
from .if_filter import IFFilter
from .iq_imbalance import IQImbalance
from .moving_scatterer import MovingScatterer
from .noise_floor import NoiseFloor
from .phase_noise import PhaseNoise
from .scatterer import MissingScatterer

_CLASSES = (MissingScatterer, MovingScatterer, MultipathGhost, Coupling, ChannelGain,
            DelayOffset, FrequencyOffset, ChirpNonlinearity, EgoMotion, PhaseNoise, IFFilter,
            NoiseFloor, DCOffset, IQImbalance, ADCClipping)
LIBRARY = {cls.name: cls for cls in _CLASSES}


def default_library() -> list:
    """One instance of every library effect."""
    return [cls() for cls in LIBRARY.values()]


def candidate_effects(names=None) -> list:
    """Library instances for a list or comma-separated string of names.

    Parameters
    ----------
    names : str, sequence of str or None
        Effect names (``None``: the whole library).

    Returns
    -------
    list
        One new instance per name, in the given order.
    """
    from ...errors import ConfigError

    if names is None:
        return default_library()
    if isinstance(names, str):
        names = [x.strip() for x in names.split(",")]
    out = []
    for n in (x for x in names if x):
        if n not in LIBRARY:
            raise ConfigError(f"unknown effect {n!r}; the library has {sorted(LIBRARY)}")
        out.append(LIBRARY[n]())
    if not out:
        raise ConfigError("empty list of candidate effects")
    return out

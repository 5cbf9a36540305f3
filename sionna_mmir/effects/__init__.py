"""Effects the base forward model lacks, as small differentiable modules.

``context`` (axes), ``ops`` (complex tensors, DFT nodes), ``base`` (the
:class:`Effect` interface), ``model`` (base render + effects + Gaussian NLL)
and ``library/`` (one effect per file).
"""
from .base import Effect, ParamSpec
from .context import EffectContext
from .model import Component, EffectModel

__all__ = ["Effect", "ParamSpec", "EffectContext", "EffectModel", "Component"]

"""Baselines the mmIR renderer is compared against.

:class:`~sionna_mmir.baseline.sionna_rt.SionnaBaseline`: plain, unmodified
Sionna RT 2.2 on the same scene and radar (per-object ITU materials, its own
``PathSolver``), its paths turned into raw ADC by the same
:func:`~sionna_mmir.fmcw.synthesize_adc`.  Imported lazily (it starts the
Mitsuba backend).
"""
from __future__ import annotations

import importlib

__all__ = ["SionnaBaseline"]


def __getattr__(name):
    if name == "SionnaBaseline":
        value = importlib.import_module("sionna_mmir.baseline.sionna_rt").SionnaBaseline
        globals()[name] = value
        return value
    raise AttributeError(f"module 'sionna_mmir.baseline' has no attribute {name!r}")

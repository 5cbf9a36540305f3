"""Closing the loop: scene, solver, ADC and sensor chain as one model, and its diagnosis.

``radar_model``
    :class:`RadarModel`: scene -> solver -> per-object ADC basis -> sensor
    chain (adopted effects), refined in the ADC domain
``diagnosis``
    :class:`Diagnosis`: ``Diagnosis(model).run()``, the residual loop
``loop``
    :func:`run_loop`: fit -> base -> diagnose -> report, resumable
``report``
    the loop's ``report.json`` / ``report.md`` / pictures
"""
from .diagnosis import Diagnosis
from .loop import LoopRequest, run_loop
from .radar_model import RadarModel, loop_solver_options

__all__ = ["Diagnosis", "LoopRequest", "RadarModel", "loop_solver_options", "run_loop"]

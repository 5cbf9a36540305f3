"""``render``: scene + radar -> raw FMCW ADC, one Dr.Jit graph.

    rays -> interactions (AD) -> BSDF / physical optics -> per-pair phasors
    (:class:`~sionna_mmir.paths.solver.RadarPathSolver`) -> ADC
    (:func:`~sionna_mmir.fmcw.synthesize_adc`)
"""
from __future__ import annotations

import numpy as np

from .solver import RadarPathSolver, radar_of


def render(scene, radar=None, *, solver: RadarPathSolver | None = None, return_paths: bool = False,
           **options):
    """Render one frame of raw ADC ``[tx, rx, chirp, sample]``.

    ============  ========================================================
    scene         :class:`~sionna_mmir.scene.RadarScene`
    radar         :class:`~sionna_mmir.radar.RadarConfig` (default
                  ``scene.radar``)
    solver        a :class:`RadarPathSolver` to reuse (default: new one)
    return_paths  also return the :class:`RadarPaths`
    options       solver options (``num_rays``, ``max_depth``, ``seed``, ...;
                  see :class:`RadarPathSolver`)
    returns       ``DrAdc`` (``real``, ``imag`` ``mi.TensorXf``), inside the
                  AD graph; ``(adc, paths)`` with ``return_paths``
    ============  ========================================================

    ``to_numpy(adc)`` converts the result to complex64.
    """
    radar = radar_of(scene, radar)
    paths = (solver or RadarPathSolver())(scene, radar, **options)
    adc = paths.adc(radar)
    return (adc, paths) if return_paths else adc


def to_numpy(adc) -> np.ndarray:
    """``DrAdc`` -> complex64 ``np.ndarray`` (detached)."""
    import drjit as dr

    re = np.asarray(dr.detach(adc.real), dtype=np.float32)
    im = np.asarray(dr.detach(adc.imag), dtype=np.float32)
    return (re + 1j * im).astype(np.complex64)

"""Inverse rendering: fit a differentiable radar model to a capture.

``reparam``
    latent <-> physical maps keeping parameters in their bounds
``models``
    :class:`MMIRModel` (per-vertex materials, normals, beam
    patterns, optional positions / pose) -- any object with
    ``latents() / render(latents, seed)`` can be fitted
``adam``
    a NumPy Adam with checkpointable state and LR schedules
``fitter``
    :func:`fit`: the loop (RA loss of paper eq. 7, progress bar,
    HDF5 checkpoints, resume)
``fitted``
    :func:`load_fitted_scene`: meshes + a checkpoint's latents as a scene
``export``
    :func:`~sionna_mmir.fit.export.fitted_scene`: a fit's latents into its scene, and to PLY
"""
from .adam import Adam, schedule_lr
from .fitted import load_fitted_scene
from .fitter import FitResult, fit, load_checkpoint
from .models import MMIRModel, SionnaModel

__all__ = ["Adam", "FitResult", "MMIRModel", "SionnaModel", "fit", "load_checkpoint",
           "load_fitted_scene", "schedule_lr"]

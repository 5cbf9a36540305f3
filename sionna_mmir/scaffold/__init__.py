"""The LiDAR scaffold: from a noisy scan to the mesh the fitters get.

``denoise``
    MLS denoising of LiDAR-like meshes (feature preserving)
``planes``
    :func:`snap_planes` (planar regions onto fitted planes)
``shading``
    :func:`flat_shaded`, :func:`crease_shaded`, :func:`auto_shaded`
    (no normals averaged across creases)
``prepare``
    :class:`ScaffoldOptions` and :func:`prepare_scaffold` (denoise ->
    planes -> shading), the one chain every command uses

NumPy / SciPy / trimesh only; nothing here touches Dr.Jit.
"""
from __future__ import annotations

from .denoise import denoise_mesh, denoise_meshes
from .planes import snap_planes
from .prepare import SHADINGS, ScaffoldOptions, prepare_scaffold
from .shading import auto_shaded, crease_shaded, curved_fraction, flat_shaded

__all__ = ["SHADINGS", "ScaffoldOptions", "auto_shaded", "crease_shaded", "curved_fraction",
           "denoise_mesh", "denoise_meshes", "flat_shaded", "prepare_scaffold", "snap_planes"]

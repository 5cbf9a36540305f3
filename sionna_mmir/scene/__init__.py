"""Differentiable radar scene: mesh input and the ``RadarScene`` Sionna subclass.

``mesh_io``  read / validate PLY, OBJ or trimesh meshes, build ``mi.Mesh``
``scene``    :class:`RadarScene` (subclass of ``sionna.rt.Scene``) and
             :func:`load_scene`
``sionna_import``  Sionna RT scenes / Mitsuba XML -> ``RadarScene`` (ITU
             materials at 77 GHz: the out-of-band policy)
``ply_export``  ``RadarScene`` <-> PLY with per-vertex materials; fitted
             scenes to PLY
``denoise``  MLS denoising of LiDAR-like meshes
``planes``   :func:`snap_planes` (planar regions onto fitted planes)
``scaffold`` :func:`prepare_scaffold` (denoise -> planes -> shading)
``shading``  :func:`flat_shaded`, :func:`crease_shaded`, :func:`auto_shaded` (no normals
             averaged across creases)

Importing :mod:`sionna_mmir.scene.scene` initialises the Mitsuba backend;
this package imports it lazily so that ``mesh_io`` stays NumPy-only.
"""
from __future__ import annotations

import importlib

from .denoise import denoise_mesh, denoise_meshes
from .planes import snap_planes
from .scaffold import SHADINGS, prepare_scaffold
from .mesh_io import DEGENERATE_AREA_M2, TriMeshData, read_mesh, to_mitsuba_mesh
from .shading import auto_shaded, crease_shaded, flat_shaded

_LAZY = {"RadarScene", "MeshObject", "ObjectData", "load_scene", "scene_from_objects",
         "DEFAULT_FREQUENCY_HZ", "ATTR_NORMAL", "ATTR_MAT0", "ATTR_MAT1"}

__all__ = sorted(_LAZY | {"DEGENERATE_AREA_M2", "TriMeshData", "read_mesh", "to_mitsuba_mesh",
                          "auto_shaded", "crease_shaded", "denoise_mesh", "denoise_meshes",
                          "flat_shaded", "prepare_scaffold", "SHADINGS", "snap_planes"})


def __getattr__(name):
    if name not in _LAZY:
        raise AttributeError(f"module 'sionna_mmir.scene' has no attribute {name!r}")
    value = getattr(importlib.import_module("sionna_mmir.scene.scene"), name)
    globals()[name] = value
    return value

"""Differentiable radar scene: mesh input and the ``RadarScene`` Sionna subclass.

``mesh_io``  read / validate PLY, OBJ or trimesh meshes, build ``mi.Mesh``
``scene``    :class:`RadarScene` (subclass of ``sionna.rt.Scene``) and
             :func:`load_scene`
``edges``    diffracting edges (boundary / crease) for free-space diffraction

Importing :mod:`sionna_mmir.scene.scene` initialises the Mitsuba backend;
this package imports it lazily so that ``mesh_io`` stays NumPy-only.
LiDAR mesh repair (denoising, plane snapping, shading) is
:mod:`sionna_mmir.scaffold`.
"""
from __future__ import annotations

import importlib

from .mesh_io import DEGENERATE_AREA_M2, TriMeshData, read_mesh, to_mitsuba_mesh

_LAZY = {"RadarScene", "MeshObject", "load_scene", "DEFAULT_FREQUENCY_HZ"}
__all__ = sorted(_LAZY | {"DEGENERATE_AREA_M2", "TriMeshData", "read_mesh", "to_mitsuba_mesh"})


def __getattr__(name):
    if name not in _LAZY:
        raise AttributeError(f"module 'sionna_mmir.scene' has no attribute {name!r}")
    value = getattr(importlib.import_module("sionna_mmir.scene.scene"), name)
    globals()[name] = value
    return value

"""Differentiable radar scene: mesh input and the ``RadarScene`` Sionna subclass.

``mesh_io``
    read / validate PLY, OBJ or trimesh meshes, build ``mi.Mesh``
``scene``
    :class:`RadarScene` (subclass of ``sionna.rt.Scene``)
``vertex_material``
    :class:`VertexRadioMaterial`, the Sionna radio material
             holding an object's per-vertex ITU-R P.2040 parameters
``load``
    :func:`load_scene` (meshes, Sionna scenes, material PLYs)
``edges``
    diffracting edges (boundary / crease) for free-space diffraction
``sionna_import``
    Sionna RT scenes / Mitsuba XML -> ``RadarScene`` (ITU
             materials at 77 GHz: the out-of-band policy)
``ply_export``
    ``RadarScene`` <-> PLY with per-vertex materials

Importing :mod:`sionna_mmir.scene.scene` initialises the Mitsuba backend;
this package imports it lazily so that ``mesh_io`` stays NumPy-only.
LiDAR mesh repair (denoising, plane snapping, shading) is
:mod:`sionna_mmir.scaffold`.
"""
from __future__ import annotations

import importlib

from .mesh_io import DEGENERATE_AREA_M2, TriMeshData, read_mesh, to_mitsuba_mesh

_LAZY = {"RadarScene": "scene", "MeshObject": "scene", "ObjectData": "scene",
         "scene_from_objects": "scene", "DEFAULT_FREQUENCY_HZ": "scene", "load_scene": "load",
         "VertexRadioMaterial": "vertex_material"}
__all__ = sorted(set(_LAZY) | {"DEGENERATE_AREA_M2", "TriMeshData", "read_mesh", "to_mitsuba_mesh"})


def __getattr__(name):
    if name not in _LAZY:
        raise AttributeError(f"module 'sionna_mmir.scene' has no attribute {name!r}")
    value = getattr(importlib.import_module(f"sionna_mmir.scene.{_LAZY[name]}"), name)
    globals()[name] = value
    return value

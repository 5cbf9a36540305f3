"""Flat shading for reconstructed meshes: every face its own vertices and normal.

A mesh that shares vertices across creases (a box's edges, a kerb, a wall
meeting the floor) gets vertex normals averaged over faces on both sides,
and the renderer interpolates them across every triangle touching the
crease: a strip of triangles whose shading normals lean by up to half the
crease angle.  On the benchmark street (noise-free scan, true materials,
depth 3) this took the RA correlation from 0.80 (flat) to 0.19; on its
denoised scan from 0.67 to 0.18 (NOTES.md, session 7).  Flat shading --
shading normal = geometric normal -- removes the artefact at the price of
three vertices per face (per-vertex materials become per face corner).

==========  ==================================================================
mesh        ``trimesh.Trimesh`` or ``dict`` name -> ``trimesh.Trimesh``
returns     the same kind: meshes with ``3 F`` vertices (face ``i`` uses
            ``3i, 3i+1, 3i+2``, same winding) and vertex normals equal to
            their face's unit normal; degenerate faces (area below
            ``mesh_io.DEGENERATE_AREA_M2``, as ``read_mesh``) dropped
==========  ==================================================================
"""
from __future__ import annotations

import numpy as np
import trimesh

from ..errors import InputValueError
from .mesh_io import DEGENERATE_AREA_M2


def flat_shaded(mesh):
    """See module docstring."""
    if isinstance(mesh, dict):
        if not mesh:
            raise InputValueError("flat_shaded: empty dict of meshes")
        return {name: _flat(m, name) for name, m in mesh.items()}
    return _flat(mesh, "mesh")


def _flat(mesh, name):
    if not isinstance(mesh, trimesh.Trimesh):
        raise InputValueError(f"flat_shaded: {name!r} is a {type(mesh).__name__}, "
                              "expected trimesh.Trimesh")
    faces = np.asarray(mesh.faces, dtype=np.int64)
    verts = np.asarray(mesh.vertices, dtype=np.float64)
    if len(faces) == 0:
        raise InputValueError(f"flat_shaded: {name!r} has no faces")
    if not np.isfinite(verts).all():
        raise InputValueError(f"flat_shaded: {name!r} has NaN/Inf vertices")
    tri = verts[faces]                                          # (F, 3, 3)
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norm = np.linalg.norm(cross, axis=1)
    keep = 0.5 * norm > DEGENERATE_AREA_M2                      # read_mesh's threshold
    if not keep.any():
        raise InputValueError(f"flat_shaded: {name!r} has only degenerate faces")
    tri, n = tri[keep], cross[keep] / norm[keep, None]
    v = tri.reshape(-1, 3)
    return trimesh.Trimesh(v, np.arange(len(v)).reshape(-1, 3),
                           vertex_normals=np.repeat(n, 3, axis=0), process=False)

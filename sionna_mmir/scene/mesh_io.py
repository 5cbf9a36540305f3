"""Triangle-mesh input: read, validate and convert to a Mitsuba mesh.

Only NumPy and trimesh are imported at module level; Mitsuba is imported
inside :func:`to_mitsuba_mesh`, after
:func:`sionna_mmir.utils.backend.init_backend`.
"""
from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from ..errors import InputValueError

#: Triangles with an area below this are degenerate [m^2].
DEGENERATE_AREA_M2 = 1e-12


@dataclass
class TriMeshData:
    """A validated triangle mesh.

    Parameters
    ----------
    source : str
        description of where the mesh came from (file path)
    vertices : numpy.ndarray
        float64 (Nv, 3), positions [m]
    faces : numpy.ndarray
        int64 (Nf, 3), vertex indices
    normals : numpy.ndarray
        float64 (Nv, 3), unit vertex normals
    """

    source: str
    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray


def trimesh_arrays(mesh, name: str, where: str):
    """``(faces int64 [F, 3], vertices float64 [V, 3])`` of a ``trimesh.Trimesh``
    with at least one face and finite vertices; ``InputValueError`` naming
    ``where`` (the calling function) and ``name`` (the object) otherwise."""
    import trimesh

    if not isinstance(mesh, trimesh.Trimesh):
        raise InputValueError(f"{where}: {name!r} is a {type(mesh).__name__}, "
                              "expected trimesh.Trimesh")
    faces = np.asarray(mesh.faces, dtype=np.int64)
    verts = np.asarray(mesh.vertices, dtype=np.float64)
    if len(faces) == 0:
        raise InputValueError(f"{where}: {name!r} has no faces")
    if not np.isfinite(verts).all():
        raise InputValueError(f"{where}: {name!r} has NaN/Inf vertices")
    return faces, verts


def _triangle_areas(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    p0, p1, p2 = (vertices[faces[:, k]] for k in range(3))
    return 0.5 * np.linalg.norm(np.cross(p1 - p0, p2 - p0), axis=1)


def _vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Unit vertex normals as trimesh computes them (from the kept faces)."""
    import trimesh

    tm = trimesh.Trimesh(vertices=vertices, faces=faces, process=False)
    return np.asarray(tm.vertex_normals, dtype=np.float64)


def read_mesh(mesh, source: str | None = None,
              drop_degenerate: bool = False) -> TriMeshData:
    """Read and validate a triangle mesh.

    Shading normals: the mesh's own vertex normals when it has them (a
    PLY's ``nx ny nz``, a ``Trimesh`` built with ``vertex_normals=``, e.g. by
    :func:`~sionna_mmir.scaffold.denoise.denoise_mesh`), else trimesh's
    face-averaged normals.

    Parameters
    ----------
    mesh : str or os.PathLike or trimesh.Trimesh
        path of a PLY / OBJ file (str or ``os.PathLike``)
        or a ``trimesh.Trimesh``
    source : str, optional
        name used in error messages (default: the path, or
        ``"<trimesh>"``)
    drop_degenerate : bool, optional
        if True, triangles with area < 1e-12 m^2 are removed
        instead of raising

    Returns
    -------
    TriMeshData

    Raises
    ------
    InputValueError
        Naming ``source``: an unreadable file, no faces, NaN/Inf vertices,
        NaN/Inf or zero given normals, face indices out of range and
        (unless ``drop_degenerate``) degenerate triangles.
    """
    import trimesh

    if isinstance(mesh, (str, os.PathLike)):
        path = os.fspath(mesh)
        source = source or path
        if not os.path.isfile(path):
            raise InputValueError(f"{source}: mesh file does not exist")
        try:
            loaded = trimesh.load(path, process=False)
            if not isinstance(loaded, trimesh.Trimesh):     # a Scene: concatenate
                loaded = trimesh.load(path, process=False, force="mesh")
        except Exception as exc:  # trimesh raises many types
            raise InputValueError(f"{source}: cannot read mesh ({exc})") from exc
    elif isinstance(mesh, trimesh.Trimesh):
        source = source or "<trimesh>"
        loaded = mesh
    else:
        raise InputValueError(f"{source or 'mesh'}: expected a PLY/OBJ path or a "
                              f"trimesh.Trimesh, got {type(mesh).__name__}")

    vertices = np.asarray(getattr(loaded, "vertices", np.zeros((0, 3))), dtype=np.float64)
    faces = np.asarray(getattr(loaded, "faces", np.zeros((0, 3))), dtype=np.int64)
    if faces.size == 0:
        raise InputValueError(f"{source}: mesh is empty (no faces)")
    if vertices.ndim != 2 or vertices.shape[1] != 3 or faces.ndim != 2 or faces.shape[1] != 3:
        raise InputValueError(f"{source}: expected vertices (Nv,3) and triangle faces "
                              f"(Nf,3), got {vertices.shape} and {faces.shape}")
    bad_v = np.flatnonzero(~np.isfinite(vertices).all(axis=1))
    if bad_v.size:
        raise InputValueError(f"{source}: {bad_v.size} vertices hold NaN/Inf "
                              f"(first indices {bad_v[:5].tolist()})")
    bad_f = np.flatnonzero(((faces < 0) | (faces >= len(vertices))).any(axis=1))
    if bad_f.size:
        raise InputValueError(f"{source}: {bad_f.size} faces index vertices out of range "
                              f"[0, {len(vertices)}) (first faces {bad_f[:5].tolist()})")
    degenerate = np.flatnonzero(_triangle_areas(vertices, faces) < DEGENERATE_AREA_M2)
    if degenerate.size:
        if not drop_degenerate:
            raise InputValueError(
                f"{source}: {degenerate.size} degenerate triangles (area < "
                f"{DEGENERATE_AREA_M2:g} m^2), first faces {degenerate[:5].tolist()}; "
                "pass drop_degenerate=True to remove them")
        faces = np.delete(faces, degenerate, axis=0)
        if faces.size == 0:
            raise InputValueError(f"{source}: mesh is empty after dropping "
                                  f"{degenerate.size} degenerate triangles")
    normals = _given_normals(loaded, len(vertices), faces, source)
    if normals is None:
        normals = _vertex_normals(vertices, faces)
    return TriMeshData(source=source, vertices=vertices, faces=faces, normals=normals)


def _given_normals(loaded, n_vertices: int, faces: np.ndarray, source: str):
    """The mesh's own vertex normals (a PLY's ``nx ny nz``, a ``Trimesh`` built
    with ``vertex_normals=``; trimesh keeps them in its cache), normalised, or
    None when it has none.  Only vertices used by ``faces`` must have a valid
    normal; unused ones get +z."""
    cache = getattr(loaded, "_cache", None)
    if cache is None or "vertex_normals" not in cache:
        return None
    n = np.array(loaded.vertex_normals, dtype=np.float64)         # a copy (trimesh's is read-only)
    if n.shape != (n_vertices, 3):
        raise InputValueError(f"{source}: vertex normals have shape {n.shape}, expected "
                              f"({n_vertices}, 3)")
    norm = np.linalg.norm(n, axis=1)
    used = np.zeros(n_vertices, dtype=bool)
    used[faces.ravel()] = True
    invalid = ~np.isfinite(norm) | (norm < 1e-12)
    n[invalid & ~used], norm[invalid & ~used] = (0.0, 0.0, 1.0), 1.0
    bad = np.flatnonzero(invalid & used)
    if bad.size:
        raise InputValueError(f"{source}: {bad.size} vertex normals are NaN/Inf or zero "
                              f"(first vertices {bad[:5].tolist()})")
    return n / norm[:, None]


def to_mitsuba_mesh(data: TriMeshData, name: str, bsdf=None):
    """Build a ``mi.Mesh`` from validated data.

    The mesh has no Mitsuba vertex normals (flat shading normals); keep
    shading normals in a separate attribute, Mitsuba recomputes
    ``vertex_normals`` whenever positions change.

    Parameters
    ----------
    data : TriMeshData
        :class:`TriMeshData`
    name : str
        Mitsuba shape id (also the Sionna object name)
    bsdf : mi.BSDF, optional
        Mitsuba BSDF (e.g. a Sionna radio material)

    Returns
    -------
    mi.Mesh
    """
    import mitsuba as mi

    mesh = mi.Mesh(name, len(data.vertices), len(data.faces), has_vertex_normals=False)
    params = mi.traverse(mesh)
    params["vertex_positions"] = mi.Float(data.vertices.astype(np.float32).ravel())
    params["faces"] = mi.UInt32(data.faces.astype(np.uint32).ravel())
    params.update()
    if bsdf is not None:
        mesh.set_bsdf(bsdf)
    return mesh

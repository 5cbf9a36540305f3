"""``RadarScene`` <-> PLY with per-vertex materials; fitted scenes to PLY.

:func:`save_scene_ply` writes all objects of a scene into one binary
little-endian PLY that MeshLab and Blender open as a coloured mesh:

==============================  ==============================================
vertex ``x y z``                float32 positions [m] (the scene's tensors)
vertex ``nx ny nz``             float32 shading normals
vertex ``eps_real eps_imag``    float32 per-vertex materials, the order of
``sigma_h l_c tau thickness``   :data:`~sionna_mmir.radio_materials.VERTEX_PARAMETER_NAMES`
                                (``sigma_h``, ``l_c``, ``thickness`` in m)
vertex ``red green blue``       uchar, ``eps_real`` on the viridis map (for
                                viewing only; ignored on reading)
vertex ``object``               int, index of the vertex's object
face ``vertex_indices``         triangles (``list uchar int``)
``comment sionna_mmir {...}``   JSON: format, frequency [Hz], and per object
                                its name, material label, vertex and face
                                counts (objects are stored as consecutive
                                blocks)
==============================  ==============================================

The scene's tensors are float32, so :func:`load_scene` of the file (it
recognises the comment) restores positions, normals, faces and the six
per-vertex materials bit for bit.  Other PLYs go through the ordinary mesh
reader.

:func:`sionna_mmir.fit.export.fitted_scene` writes a fit's latents (a :class:`~sionna_mmir.fit.FitResult`,
its ``latents`` dict, or a ``fit_*.h5`` checkpoint of ``sionna-mmir fit
--out``) into the model's scene as physical values; ``sionna-mmir fit``
saves the result as ``scene_mmir.ply`` in its report folder.  Learned beam
patterns are radar properties and are not part of the PLY.
"""
from __future__ import annotations

import json
import os

import numpy as np

from ..errors import ConfigError, InputValueError
from ..radio_materials.itu_table import VERTEX_PARAMETER_NAMES
from ..utils.atomic import atomic_path

PLY_FORMAT = "sionna_mmir.scene_ply"
_TAG = "comment sionna_mmir "
_VERTEX_FIELDS = ("x", "y", "z", "nx", "ny", "nz") + VERTEX_PARAMETER_NAMES
_VERTEX_DTYPE = np.dtype([(n, "<f4") for n in _VERTEX_FIELDS]
                         + [("red", "u1"), ("green", "u1"), ("blue", "u1"), ("object", "<i4")])
_FACE_DTYPE = np.dtype([("n", "u1"), ("v", "<i4", (3,))])
_PLY_TYPES = {"float": "f4", "uchar": "u1", "int": "i4"}


def _colours(eps_real: np.ndarray) -> np.ndarray:
    from matplotlib import colormaps

    lo, hi = float(eps_real.min()), float(eps_real.max())
    t = (eps_real - lo) / (hi - lo) if hi > lo else np.full_like(eps_real, 0.5)
    return np.round(colormaps["viridis"](t)[:, :3] * 255).astype(np.uint8)


def _header(meta: dict, n_vertices: int, n_faces: int) -> bytes:
    lines = ["ply", "format binary_little_endian 1.0", _TAG + json.dumps(meta, sort_keys=True),
             f"element vertex {n_vertices}"]
    for name in _VERTEX_DTYPE.names:
        kind = {"f4": "float", "u1": "uchar", "i4": "int"}[_VERTEX_DTYPE[name].str[1:]]
        lines.append(f"property {kind} {name}")
    lines += [f"element face {n_faces}", "property list uchar int vertex_indices", "end_header"]
    return ("\n".join(lines) + "\n").encode("ascii")


def save_scene_ply(scene, path, overwrite: bool = False) -> str:
    """Write ``scene`` (a :class:`RadarScene`) to ``path`` (see module docstring).

    Returns the path; raises ``FileExistsError`` when it exists and not
    ``overwrite``.  The write is atomic.
    """
    path = os.fspath(path)
    if os.path.exists(path) and not overwrite:
        raise FileExistsError(f"{path} exists; pass overwrite=True to replace it")
    blocks, faces, objects, offset = [], [], [], 0
    for k, (name, obj) in enumerate(scene.mesh_objects.items()):
        pos, nrm, mat = (np.asarray(t, dtype=np.float32).reshape(-1, c) for t, c in
                         ((obj.vertex_positions, 3), (obj.vertex_normals, 3),
                          (obj.vertex_materials, 6)))
        block = np.zeros(len(pos), dtype=_VERTEX_DTYPE)
        for j, field in enumerate(_VERTEX_FIELDS):
            block[field] = np.concatenate([pos, nrm, mat], axis=1)[:, j]
        block["object"] = k
        blocks.append(block)
        faces.append(np.asarray(obj.faces, dtype=np.int64) + offset)
        objects.append({"name": name, "material": obj.material, "vertices": len(pos),
                        "faces": len(obj.faces)})
        offset += len(pos)
    verts = np.concatenate(blocks)
    rgb = _colours(verts["eps_real"].astype(np.float64))
    verts["red"], verts["green"], verts["blue"] = rgb.T
    face_rec = np.zeros(sum(len(f) for f in faces), dtype=_FACE_DTYPE)
    face_rec["n"], face_rec["v"] = 3, np.concatenate(faces)
    meta = {"format": PLY_FORMAT, "version": 1,
            "frequency_hz": float(np.asarray(scene.frequency).reshape(-1)[0]),
            "objects": objects}
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            f.write(_header(meta, len(verts), len(face_rec)))
            f.write(verts.tobytes())
            f.write(face_rec.tobytes())
    return path


def _read_header(f, path):
    """``(meta, [(element, count, [(type, name)])])`` of a PLY opened in binary."""
    if f.readline().strip() != b"ply":
        raise InputValueError(f"{path}: not a PLY file")
    meta, elements = None, []
    while True:
        line = f.readline()
        if not line:
            raise InputValueError(f"{path}: PLY header has no end_header")
        text = line.decode("ascii", "replace").strip()
        if text == "end_header":
            return meta, elements
        if text.startswith("format") and text != "format binary_little_endian 1.0":
            raise InputValueError(f"{path}: sionna_mmir scene PLYs are binary_little_endian")
        if text.startswith(_TAG.strip()):
            meta = json.loads(text[len(_TAG):])
        elif text.startswith("element"):
            _, name, count = text.split()
            elements.append((name, int(count), []))
        elif text.startswith("property") and elements:
            elements[-1][2].append(text.split()[1:])


def is_scene_ply(obj) -> bool:
    """True for the path of a PLY written by :func:`save_scene_ply`."""
    if not isinstance(obj, (str, os.PathLike)) or not os.fspath(obj).lower().endswith(".ply"):
        return False
    try:
        with open(obj, "rb") as f:
            head = f.read(1 << 16)
    except OSError:
        return False
    header = head.split(b"end_header", 1)[0]
    return head.startswith(b"ply") and any(
        line.startswith(_TAG.encode()) and PLY_FORMAT.encode() in line
        for line in header.splitlines())


def _vertex_dtype(props, path) -> np.dtype:
    fields = []
    for p in props:
        if p[0] == "list" or p[0] not in _PLY_TYPES:
            raise InputValueError(f"{path}: unsupported vertex property {' '.join(p)}")
        fields.append((p[1], "<" + _PLY_TYPES[p[0]]))
    dtype = np.dtype(fields)
    missing = [n for n in _VERTEX_FIELDS if n not in dtype.names]
    if missing:
        raise InputValueError(f"{path}: vertex properties {missing} missing")
    return dtype


def read_scene_ply(path) -> tuple[dict, dict]:
    """``(meta, dict name -> ObjectData)`` of a :func:`save_scene_ply` file.

    Raises ``InputValueError`` naming ``path`` for a truncated file, bad
    indices or NaN.
    """
    from .mesh_io import TriMeshData
    from .scene import ObjectData

    path = os.fspath(path)
    with open(path, "rb") as f:
        meta, elements = _read_header(f, path)
        names = [e[0] for e in elements]
        if meta is None or meta.get("format") != PLY_FORMAT or names != ["vertex", "face"]:
            raise InputValueError(f"{path}: not a sionna_mmir scene PLY")
        vdtype = _vertex_dtype(elements[0][2], path)
        nv, nf = elements[0][1], elements[1][1]
        vbytes, fbytes = f.read(nv * vdtype.itemsize), f.read(nf * _FACE_DTYPE.itemsize)
    if len(vbytes) != nv * vdtype.itemsize or len(fbytes) != nf * _FACE_DTYPE.itemsize:
        raise InputValueError(f"{path}: truncated PLY ({nv} vertices, {nf} faces declared)")
    verts = np.frombuffer(vbytes, dtype=vdtype)
    faces = np.frombuffer(fbytes, dtype=_FACE_DTYPE)
    if nf and not np.all(faces["n"] == 3):
        raise InputValueError(f"{path}: faces that are not triangles")
    cols = np.stack([verts[n].astype(np.float64) for n in _VERTEX_FIELDS], axis=1)
    if not np.isfinite(cols).all():
        raise InputValueError(f"{path}: vertex data hold NaN/Inf")
    objects, v0, f0 = {}, 0, 0
    for o in meta["objects"]:
        nvo, nfo = int(o["vertices"]), int(o["faces"])
        fo = faces["v"][f0:f0 + nfo].astype(np.int64) - v0
        if len(fo) != nfo or v0 + nvo > nv or fo.min(initial=0) < 0 or fo.max(initial=0) >= nvo:
            raise InputValueError(f"{path}: object {o['name']!r}: faces index outside its vertices")
        block = cols[v0:v0 + nvo]
        mesh = TriMeshData(source=f"{path}: object {o['name']!r}", vertices=block[:, 0:3],
                           faces=fo, normals=block[:, 3:6])
        objects[o["name"]] = ObjectData(mesh, o["material"], block[:, 6:12])
        v0, f0 = v0 + nvo, f0 + nfo
    return meta, objects


def load_scene_ply(path, frequency: float = 77e9, materials: dict | None = None, radar=None):
    """:class:`RadarScene` of a :func:`save_scene_ply` file (materials restored).

    ``frequency`` is the scene's carrier (the file's ``frequency_hz`` is a
    record of where the materials were evaluated or fitted); ``materials``
    must be empty: the file carries them.
    """
    from .scene import scene_from_objects

    if materials:
        raise ConfigError(f"{os.fspath(path)}: the PLY carries per-vertex materials; "
                          "materials= cannot be given for it")
    _, objects = read_scene_ply(path)
    return scene_from_objects(objects, frequency=frequency, radar=radar)

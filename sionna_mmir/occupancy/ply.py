"""PLY point clouds with an ``intensity`` property.

Written format (one ``vertex`` element, no faces)::

    ply
    format binary_little_endian 1.0        (or: format ascii 1.0)
    comment <free text>
    element vertex <n>
    property double x                      [m]
    property double y
    property double z
    property float intensity               normalised, [0, 1]
    end_header

:func:`read_ply` reads that layout and any PLY whose *first* element is
``vertex`` with scalar properties ``x``, ``y``, ``z`` (any PLY scalar type),
ASCII or binary little endian; ``intensity`` is optional (NaN when absent),
later elements are ignored.  Files are written atomically.
"""
from __future__ import annotations

import os

import numpy as np

from ..errors import InputValueError
from ..utils.atomic import atomic_path

_TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2",
          "int16": "i2", "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4",
          "uint": "u4", "uint32": "u4", "float": "f4", "float32": "f4", "double": "f8",
          "float64": "f8"}


def write_ply(path, points, intensity=None, *, binary: bool = True, comment: str = "") -> None:
    """Write a PLY point cloud (atomically).

    Parameters
    ----------
    path : str or os.PathLike
        Output file.
    points : array_like, shape (n, 3)
        Positions [m].
    intensity : array_like, shape (n,), optional
        Normalised intensity (default 1).
    binary : bool, optional
        Binary little endian (default) or ASCII.
    comment : str, optional
        Header comment lines.

    Raises
    ------
    InputValueError
        An empty point set, wrong shapes or non-finite values (nothing is written).
    """
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise InputValueError(f"{path}: points must be [n, 3], got {p.shape}")
    if len(p) == 0:
        raise InputValueError(f"{path}: empty point cloud, nothing to write")
    i = np.ones(len(p)) if intensity is None else np.asarray(intensity, dtype=np.float64)
    if i.shape != (len(p),) or not (np.isfinite(p).all() and np.isfinite(i).all()):
        raise InputValueError(f"{path}: intensity must be [n={len(p)}] and all values finite")
    head = ["ply", f"format {'binary_little_endian' if binary else 'ascii'} 1.0"]
    head += [f"comment {line}" for line in comment.splitlines() if line.strip()]
    head += [f"element vertex {len(p)}", "property double x", "property double y",
             "property double z", "property float intensity", "end_header"]
    rec = np.zeros(len(p), dtype=[("x", "<f8"), ("y", "<f8"), ("z", "<f8"),
                                  ("intensity", "<f4")])
    rec["x"], rec["y"], rec["z"], rec["intensity"] = p[:, 0], p[:, 1], p[:, 2], i
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            f.write(("\n".join(head) + "\n").encode("ascii"))
            if binary:
                f.write(rec.tobytes())
            else:
                for r in rec:
                    f.write(f"{r['x']:.9g} {r['y']:.9g} {r['z']:.9g} "
                            f"{r['intensity']:.7g}\n".encode("ascii"))


def _header(f, path):
    if f.readline().strip() != b"ply":
        raise InputValueError(f"{path}: not a PLY file")
    fmt, elements = None, []
    while True:
        line = f.readline()
        if not line:
            raise InputValueError(f"{path}: PLY header has no end_header")
        words = line.decode("ascii", "replace").split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "end_header":
            return fmt, elements
        if words[0] == "format":
            fmt = words[1]
        elif words[0] == "element":
            elements.append((words[1], int(words[2]), []))
        elif words[0] == "property" and elements:
            if words[1] == "list" or words[1] not in _TYPES:
                raise InputValueError(f"{path}: unsupported PLY property {' '.join(words[1:])!r}")
            elements[-1][2].append((words[2], _TYPES[words[1]]))


def read_ply(path):
    """Read a PLY point cloud.

    Parameters
    ----------
    path : str
        PLY file (layout in the module docstring).

    Returns
    -------
    points : ndarray of float64, shape (n, 3)
        Positions [m].
    intensity : ndarray of float64, shape (n,)
        The ``intensity`` property, NaN when absent.

    Raises
    ------
    InputValueError
        Missing or unreadable file, unsupported layout, truncated data.
    """
    if not os.path.isfile(path):
        raise InputValueError(f"{path}: file does not exist")
    with open(path, "rb") as f:
        try:
            fmt, elements = _header(f, path)
        except (ValueError, IndexError) as exc:
            raise InputValueError(f"{path}: malformed PLY header ({exc})") from exc
        if not elements or elements[0][0] != "vertex":
            raise InputValueError(f"{path}: the first PLY element must be 'vertex'")
        _, n, props = elements[0]
        names = [p[0] for p in props]
        if not {"x", "y", "z"} <= set(names):
            raise InputValueError(f"{path}: PLY vertices lack x, y, z")
        dtype = np.dtype([(name, "<" + t) for name, t in props])
        if fmt == "binary_little_endian":
            buf = f.read(n * dtype.itemsize)
            if len(buf) != n * dtype.itemsize:
                raise InputValueError(f"{path}: truncated PLY ({len(buf)} of "
                                      f"{n * dtype.itemsize} vertex bytes)")
            rec = np.frombuffer(buf, dtype=dtype)
        elif fmt == "ascii":
            rec = _ascii_rows(f, n, dtype, path)
        else:
            raise InputValueError(f"{path}: unsupported PLY format {fmt!r}")
    pts = np.stack([rec["x"], rec["y"], rec["z"]], axis=1).astype(np.float64)
    inten = rec["intensity"].astype(np.float64) if "intensity" in names else np.full(n, np.nan)
    return pts, inten


def _ascii_rows(f, n, dtype, path):
    k = len(dtype.names)
    rows = [f.readline().split() for _ in range(n)]
    if any(len(r) < k for r in rows):
        raise InputValueError(f"{path}: truncated ASCII PLY")
    try:
        return np.array([tuple(float(v) for v in r[:k]) for r in rows], dtype=dtype)
    except ValueError as exc:
        raise InputValueError(f"{path}: non-numeric value in ASCII PLY ({exc})") from exc

"""Declared array sizes of a MATLAB v5 ``.mat`` file, read from its headers only.

:func:`declared_arrays` walks the file's data elements (MATLAB's "MAT-File
Format", level 5): for each wanted variable it reads the array headers
(class, dimensions, name) and skips the data, descending into structs and
cells, so that a reader can check shapes and sizes before
``scipy.io.loadmat`` allocates anything.  Compressed variables are
inflated as a stream in bounded pieces and their data discarded, so the
walk takes constant memory however large the arrays claim to be; variables
that are not wanted are skipped without inflating them.
"""
from __future__ import annotations

import dataclasses
import math
import struct
import zlib

MI_INT8, MI_INT32, MI_UINT32, MI_MATRIX, MI_COMPRESSED = 1, 5, 6, 14, 15
MX_CELL, MX_STRUCT, MX_OBJECT, MX_CHAR, MX_SPARSE = 1, 2, 3, 4, 5
#: bytes per element of each numeric MATLAB class (as scipy returns it)
CLASS_BYTES = {MX_CHAR: 4, 6: 8, 7: 4, 8: 1, 9: 1, 10: 2, 11: 2, 12: 4, 13: 4, 14: 8, 15: 8}
#: most struct / cell elements walked in one file
MAX_ELEMENTS = 100_000
#: most an element may inflate, in units of its compressed size
MAX_RATIO = 64
_CHUNK = 1 << 16


class MatHeaderError(ValueError):
    """The element headers are not those of a MATLAB v5 file."""


@dataclasses.dataclass(frozen=True)
class Declared:
    """One array as its header declares it (``name`` dotted through structs)."""

    name: str
    shape: tuple
    mclass: int
    is_complex: bool
    nzmax: int = 0

    @property
    def nbytes(self) -> int:
        """Bytes the array takes once read (sparse: its declared non-zeros)."""
        if self.mclass == MX_SPARSE:
            return self.nzmax * 24
        per = CLASS_BYTES.get(self.mclass, 8) * (2 if self.is_complex else 1)
        return math.prod(self.shape) * per


class _Raw:
    """Bytes of the file itself, counted."""

    def __init__(self, f):
        self.f, self.pos = f, 0

    def read(self, n: int) -> bytes:
        data = self.f.read(n)
        if len(data) != n:
            raise MatHeaderError("the file ends inside an element (truncated)")
        self.pos += n
        return data

    def skip(self, n: int) -> None:
        self.f.seek(n, 1)
        self.pos += n


class _Inflate:
    """The inflated bytes of one compressed element, produced in bounded pieces.

    Skips are lazy (data skipped at the end of an element is never
    inflated), and inflating more than :data:`MAX_RATIO` times the
    compressed size (plus 1 MiB) is refused: no measured array compresses
    so well, a decompression bomb does.
    """

    def __init__(self, f, nbytes: int):
        self.f, self.left, self.pos, self.pending = f, nbytes, 0, 0
        self.z, self.buf, self.limit = zlib.decompressobj(), b"", MAX_RATIO * nbytes + (1 << 20)

    def _more(self) -> bool:
        data = self.z.unconsumed_tail
        if not data:
            if self.left <= 0:
                return False
            data = self.f.read(min(self.left, _CHUNK))
            self.left -= len(data)
            if not data:
                return False
        try:
            out = self.z.decompress(data, _CHUNK)
        except zlib.error as e:
            raise MatHeaderError(f"a compressed element does not inflate ({e})") from None
        self.limit -= len(out)
        if self.limit < 0:
            raise MatHeaderError(f"a compressed element inflates to more than {MAX_RATIO} "
                                 "times its size (a decompression bomb?)")
        self.buf += out
        return True

    def _drop(self) -> None:
        while self.pending > 0:
            if not self.buf and not self._more():
                raise MatHeaderError("a compressed element ends early (truncated)")
            k = min(self.pending, len(self.buf))
            self.buf, self.pending = self.buf[k:], self.pending - k

    def read(self, n: int) -> bytes:
        self._drop()
        while len(self.buf) < n:
            if not self._more():
                raise MatHeaderError("a compressed element ends early (truncated)")
        out, self.buf = self.buf[:n], self.buf[n:]
        self.pos += n
        return out

    def skip(self, n: int) -> None:
        self.pending += n
        self.pos += n


def _pad8(n: int) -> int:
    return (n + 7) & ~7


def _tag(s, endian: str) -> tuple:
    """``(type, nbytes, data of a small element or None)``."""
    raw = s.read(8)
    first, second = struct.unpack(endian + "II", raw)
    if first >> 16:                                   # small data element
        return first & 0xFFFF, first >> 16, raw[4:4 + (first >> 16)]
    return first, second, None


def _sub(s, endian: str) -> tuple:
    """``(type, data)`` of a sub-element read whole (headers only: small)."""
    mtype, n, small = _tag(s, endian)
    if small is not None:
        return mtype, small
    if n > 1 << 20:
        raise MatHeaderError(f"an array header element of {n} bytes")
    data = s.read(n)
    s.skip(_pad8(n) - n)
    return mtype, data


class _Walk:
    def __init__(self, endian: str):
        self.endian, self.out, self.count = endian, [], 0

    def matrix(self, s, nbytes: int, name: str | None) -> None:
        """Record the arrays of one miMATRIX body of ``nbytes``, then skip to its end."""
        if nbytes == 0:
            return
        end = s.pos + nbytes
        e = self.endian
        _, flags = _sub(s, e)
        _, dims = _sub(s, e)
        _, own = _sub(s, e)
        if len(flags) < 8 or len(dims) % 4:
            raise MatHeaderError("a malformed array header")
        word, nzmax = struct.unpack(e + "II", flags[:8])
        mclass, shape = word & 0xFF, struct.unpack(e + f"{len(dims) // 4}i", dims)
        if any(d < 0 for d in shape):
            raise MatHeaderError(f"negative dimensions {shape}")
        name = name if name is not None else own.decode("latin-1")
        if mclass in (MX_STRUCT, MX_OBJECT):
            self._struct(s, name, shape, mclass)
        elif mclass == MX_CELL:
            for i in range(self._elements(math.prod(shape))):
                self._child(s, f"{name}{{{i}}}")
        else:
            self.out.append(Declared(name, tuple(shape), mclass, bool(word & 0x800), nzmax))
        s.skip(end - s.pos)

    def _elements(self, n: int) -> int:
        self.count += n
        if self.count > MAX_ELEMENTS:
            raise MatHeaderError(f"more than {MAX_ELEMENTS} struct / cell elements")
        return n

    def _child(self, s, name: str) -> None:
        mtype, n, _ = _tag(s, self.endian)
        if mtype != MI_MATRIX:
            raise MatHeaderError(f"{name} is not an array element")
        self.matrix(s, n, name)

    def _struct(self, s, name: str, shape, mclass: int) -> None:
        e = self.endian
        if mclass == MX_OBJECT:
            _sub(s, e)                                       # class name
        _, width = _sub(s, e)
        _, names = _sub(s, e)
        step = struct.unpack(e + "i", width[:4])[0] if len(width) >= 4 else 0
        if step <= 0 or len(names) % step:
            raise MatHeaderError(f"{name}: malformed struct field names")
        fields = [names[i:i + step].split(b"\0")[0].decode("latin-1")
                  for i in range(0, len(names), step)]
        n = math.prod(shape)
        self._elements(n * len(fields))
        for i in range(n):
            for field in fields:
                self._child(s, f"{name}[{i}].{field}" if n != 1 else f"{name}.{field}")


def _top_level(f, walk: _Walk, wanted) -> None:
    """Walk the top-level elements of an open file positioned after the header."""
    while True:
        raw = f.read(8)
        if not raw:
            return
        if len(raw) < 8:
            raise MatHeaderError("the file ends inside an element tag (truncated)")
        mtype, nbytes = struct.unpack(walk.endian + "II", raw)
        start = f.tell()
        if mtype == MI_COMPRESSED:
            s = _Inflate(f, nbytes)
            inner, n, _ = _tag(s, walk.endian)
            if inner == MI_MATRIX:
                _maybe(s, walk, n, wanted)
        elif mtype == MI_MATRIX:
            _maybe(_Raw(f), walk, nbytes, wanted)
        f.seek(start + (nbytes if mtype == MI_COMPRESSED else _pad8(nbytes)))


def _maybe(s, walk: _Walk, nbytes: int, wanted) -> None:
    """Walk a top-level array whose name is wanted (its name comes third)."""
    if wanted is None:
        walk.matrix(s, nbytes, None)
        return
    probe = _Probe(s)
    for _ in range(3):
        _sub(probe, walk.endian)
    if probe.seen_name(walk.endian) in wanted:
        walk.matrix(probe.replay(), nbytes, None)


class _Probe:
    """A stream that records what it reads, to replay the first elements."""

    def __init__(self, s):
        self.s, self.data, self.pos = s, b"", 0

    def read(self, n: int) -> bytes:
        out = self.s.read(n)
        self.data += out
        self.pos += n
        return out

    def skip(self, n: int) -> None:
        self.read(n)

    def seen_name(self, endian: str) -> str:
        replay = _Replay(self.data, None)
        for _ in range(2):
            _sub(replay, endian)
        return _sub(replay, endian)[1].decode("latin-1")

    def replay(self):
        return _Replay(self.data, self.s)


class _Replay:
    """Recorded bytes first, then the rest of the stream."""

    def __init__(self, data: bytes, rest):
        self.data, self.rest, self.pos = data, rest, 0

    def read(self, n: int) -> bytes:
        head = self.data[self.pos:self.pos + n] if self.pos < len(self.data) else b""
        tail = self.rest.read(n - len(head)) if n > len(head) else b""
        self.pos += n
        return head + tail

    def skip(self, n: int) -> None:
        inside = max(0, min(n, len(self.data) - self.pos))
        if n > inside:
            self.rest.skip(n - inside)
        self.pos += n


def declared_arrays(path, wanted=None) -> list | None:
    """Arrays a MATLAB v5 file declares, without reading their data.

    Parameters
    ----------
    path : str or os.PathLike
        The ``.mat`` file.
    wanted : iterable of str, optional
        Top-level variable names to walk (default all).

    Returns
    -------
    list of Declared or None
        The numeric / char / sparse arrays (struct fields as
        ``var.field``), or None for a file that is not MATLAB v5 (v4, v7.3).

    Raises
    ------
    MatHeaderError
        Malformed or truncated element headers.
    """
    wanted = None if wanted is None else set(wanted)
    with open(path, "rb") as f:
        header = f.read(128)
        if len(header) < 128 or not header.startswith(b"MATLAB 5.0"):
            return None
        endian = {b"IM": "<", b"MI": ">"}.get(header[126:128])
        if endian is None:
            raise MatHeaderError("unknown byte-order mark in the header")
        walk = _Walk(endian)
        _top_level(f, walk, wanted)
    return walk.out

"""Atomic file writes: write to a temporary sibling, move it into place on success.

:func:`atomic_path` yields a temporary path ``.<name>-<pid>-<random><suffix>``
beside the target.  On success the file gets the mode a plain ``open``
would give it (``0o666 & ~umask``; ``mkstemp`` creates ``0o600``) and is
moved into place: replacing an existing target, or, with
``overwrite=False``, hard-linked to the target name, which fails if the
target appeared meanwhile (no check-then-rename race between two writers).
A failure (exception, interrupt) removes the temporary file, so no partial
output is ever left at the target; an ``OSError`` about the temporary file
(a full disk, a read-only folder) is re-raised naming the target.

Stale temporary files of the same target, left by killed writers, are
removed before each write.  A temporary file is stale when

* the process whose id is in its name is not running on this machine and
  the file has not been modified for :data:`STALE_DEAD_S` seconds, or
* it has not been modified for :data:`STALE_ANY_S` seconds (a writer on
  another machine sharing the folder, a reused process id, or a name
  without a process id written by an older version).
"""
from __future__ import annotations

import contextlib
import errno
import hashlib
import os
import re
import tempfile
import time

#: a temporary file of a process that is gone is stale after this long untouched [s]
STALE_DEAD_S = 60.0
#: any temporary file is stale after this long untouched [s]
STALE_ANY_S = 3600.0
#: length of ``tempfile.mkstemp``'s random part
_RANDOM = r"[a-z0-9_]{8}"


def current_umask() -> int:
    """The process umask (read without changing it where Linux allows)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def name_max(folder) -> int:
    """Longest file name (bytes) allowed in ``folder`` (255 where unknown)."""
    try:
        return int(os.pathconf(folder, "PC_NAME_MAX"))
    except (OSError, ValueError, AttributeError):
        return 255


def _temp_prefix(name: str, suffix: str, limit: int) -> str:
    """``.<name>-``, shortened with a hash of ``name`` when the temporary
    name ``.<name>-<pid>-<random><suffix>`` would exceed ``limit`` bytes."""
    prefix = f".{name}-"
    room = limit - len(os.fsencode(suffix)) - 8 - 12      # random part, "<pid>-"
    if len(os.fsencode(prefix)) <= room:
        return prefix
    digest = hashlib.sha1(os.fsencode(name)).hexdigest()[:8]
    head = os.fsdecode(os.fsencode(name)[:max(room - 11, 1)])
    return f".{head}~{digest}-"


def _is_stale(path: str, pid: int | None, now: float) -> bool:
    try:
        age = now - os.stat(path).st_mtime
    except OSError:
        return False
    if age > STALE_ANY_S:
        return True
    if pid is None or age < STALE_DEAD_S or pid == os.getpid():
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    except OSError:                        # exists, owned by another user
        return False
    return False


def remove_stale_temporaries(folder: str, prefix: str, suffix: str) -> list:
    """Remove stale temporary files ``<prefix><pid>-<random><suffix>`` (see
    the module docstring for the rule); returns the removed paths."""
    current = re.compile(re.escape(prefix) + r"(\d+)-" + _RANDOM + re.escape(suffix) + "$")
    legacy = re.compile(re.escape(prefix) + _RANDOM + re.escape(suffix) + "$")
    removed, now = [], time.time()
    try:
        entries = [e.name for e in os.scandir(folder) if e.name.startswith(prefix)]
    except OSError:
        return removed
    for name in entries:
        m = current.match(name)
        if not (m or legacy.match(name)):
            continue
        path = os.path.join(folder, name)
        if _is_stale(path, int(m.group(1)) if m else None, now):
            with contextlib.suppress(OSError):
                os.remove(path)
                removed.append(path)
    return removed


def _commit(tmp: str, path: str, overwrite: bool) -> None:
    """Move ``tmp`` to ``path``; without ``overwrite`` never replace a file."""
    if overwrite:
        os.replace(tmp, path)
        return
    try:
        os.link(tmp, path)
    except FileExistsError:
        raise FileExistsError(errno.EEXIST, "appeared while this output was written (another "
                              "writer?); it was not replaced", path) from None
    except OSError as exc:
        if exc.errno not in (errno.EPERM, errno.ENOTSUP, errno.EOPNOTSUPP, errno.EXDEV,
                             errno.ENOSYS, errno.EMLINK):
            raise
        # no hard links here: claim the name exclusively, then replace the claim
        os.close(os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600))
        os.replace(tmp, path)
        return
    with contextlib.suppress(OSError):
        os.remove(tmp)


def _errno_of(exc: OSError):
    """``exc.errno``, or the ``errno = N`` HDF5 puts in its messages."""
    if exc.errno is not None:
        return exc.errno
    m = re.search(r"errno = (\d+)", str(exc))
    return int(m.group(1)) if m else None


def _about_target(exc: OSError, tmp, path: str) -> OSError:
    """``exc`` re-made to name ``path`` when it names the temporary file (or nothing)."""
    if exc.filename not in (None, tmp) or isinstance(exc, FileExistsError):
        return exc
    code = _errno_of(exc)
    text = os.strerror(code) if code is not None else (exc.strerror or str(exc))
    return OSError(code, text, path)


@contextlib.contextmanager
def atomic_path(path, suffix: str = ".part", overwrite: bool = True):
    """Yield a temporary path beside ``path``; move it to ``path`` on success.

    Parameters
    ----------
    path : str or os.PathLike
        The target file.
    suffix : str
        Ending of the temporary name (e.g. ``".h5.part"``).
    overwrite : bool
        Replace an existing ``path``.  When False, the commit fails with
        ``FileExistsError`` if ``path`` exists by then, and nothing is replaced.
    """
    path = os.fspath(path)
    folder = os.path.dirname(os.path.abspath(path))
    os.makedirs(folder, exist_ok=True)
    prefix = _temp_prefix(os.path.basename(path), suffix, name_max(folder))
    remove_stale_temporaries(folder, prefix, suffix)
    try:
        fd, tmp = tempfile.mkstemp(prefix=f"{prefix}{os.getpid()}-", suffix=suffix, dir=folder)
    except OSError as exc:                 # a read-only folder, a full disk
        raise _about_target(exc, exc.filename, path) from exc
    os.close(fd)
    try:
        yield tmp
        os.chmod(tmp, 0o666 & ~current_umask())
        _commit(tmp, path, overwrite)
    except BaseException as exc:
        with contextlib.suppress(OSError):
            os.remove(tmp)
        if isinstance(exc, OSError):
            raise _about_target(exc, tmp, path) from exc
        raise

"""Output paths checked before the work starts, and report folders locked while in use.

:func:`check_output_file` and :func:`check_output_folder` refuse, before
anything is computed, an output that exists (without ``overwrite``), is of
the wrong kind (a folder where a file is written or the reverse), has a
name longer than the file system allows, or lies in a folder that cannot
be written (tried by creating and removing a probe file, which catches
read-only mounts and immutable folders that permission bits do not show).

:func:`folder_lock` holds ``<folder>.lock`` (an ``flock``, released by the
kernel when the process dies) for the time a report folder is written, so
that a second run writing the same folder fails at once with
``<folder>: in use by another run`` instead of deleting the first run's
output.
"""
from __future__ import annotations

import contextlib
import errno
import os
import tempfile

from ..errors import OutputError
from .atomic import name_max

#: siblings a report folder ``X`` uses while it is written: ``X.partial``, ``X.lock``
FOLDER_SIBLINGS = (".partial", ".lock")


def _existing_ancestor(path: str) -> str:
    folder = os.path.dirname(os.path.abspath(path))
    while not os.path.exists(folder):
        folder = os.path.dirname(folder)
    return folder


def check_name(path, extra: int = 0) -> None:
    """Raise ``OSError(ENAMETOOLONG)`` naming ``path`` when its last component,
    plus ``extra`` bytes of a sibling's suffix, is too long for its folder."""
    path = os.fspath(path)
    name = os.path.basename(os.path.normpath(path))
    limit = name_max(_existing_ancestor(path))
    size = len(os.fsencode(name)) + extra
    if size > limit:
        more = f" with the {extra} bytes of a sibling's suffix" if extra else ""
        raise OSError(errno.ENAMETOOLONG, f"file name too long ({size} bytes{more}; at most "
                                          f"{limit} here)", path)


def check_writable(path) -> None:
    """Raise ``OSError`` naming the folder when ``path`` cannot be created there.

    The nearest existing folder above ``path`` must be a folder in which a
    file can be created (a probe file is created and removed at once).
    """
    folder = _existing_ancestor(os.fspath(path))
    if not os.path.isdir(folder):
        raise OutputError(f"{folder}: is not a folder, so {path} cannot be written")
    try:
        fd, probe = tempfile.mkstemp(prefix=".sionna-mmir-probe-", dir=folder)
    except OSError as exc:
        raise OSError(exc.errno, f"cannot write in this folder ({exc.strerror})",
                      folder) from None
    os.close(fd)
    os.remove(probe)


def check_output_file(path, overwrite: bool) -> None:
    """Refuse an output file that cannot or may not be written (see module docstring)."""
    path = os.fspath(path)
    check_name(path)
    if os.path.isdir(path) or path.endswith(os.sep):
        raise OutputError(f"{path}: is a folder; give the name of a file to write")
    if os.path.lexists(path) and not overwrite:
        raise FileExistsError(f"{path}: exists; pass --overwrite to replace it")
    check_writable(path)


def check_output_folder(path, overwrite: bool) -> None:
    """Refuse an output folder that cannot or may not be written (see module docstring)."""
    path = os.fspath(path)
    check_name(path, max(len(s) for s in FOLDER_SIBLINGS))
    if os.path.lexists(path) and not os.path.isdir(path):
        raise OutputError(f"{path}: exists and is not a folder (the output is a report "
                          f"folder); remove it or choose another name")
    if os.path.exists(path) and not overwrite:
        raise FileExistsError(f"{path}: exists; pass --overwrite to replace it")
    check_writable(path)


def _lock_owner(fd: int) -> str:
    with contextlib.suppress(OSError, ValueError):
        text = os.pread(fd, 64, 0).decode("ascii", "replace").strip()
        if text:
            return f" (pid {text})"
    return ""


def _acquire(lock: str, folder: str) -> int:
    """An open, ``flock``-ed descriptor of ``lock`` (the file now at that name)."""
    import fcntl

    while True:
        fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o666)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            owner = _lock_owner(fd)
            os.close(fd)
            if exc.errno in (errno.EAGAIN, errno.EACCES, errno.EWOULDBLOCK):
                raise OutputError(f"{folder}: in use by another run{owner}; wait for it "
                                  f"to finish (lock {lock})") from None
            raise
        # a finishing holder removes the file: hold the lock only of the file now there
        mine = os.fstat(fd)
        with contextlib.suppress(FileNotFoundError):
            now = os.stat(lock)
            if (now.st_ino, now.st_dev) == (mine.st_ino, mine.st_dev):
                return fd
        os.close(fd)


@contextlib.contextmanager
def folder_lock(folder):
    """Hold ``<folder>.lock`` while the block runs.

    Raises
    ------
    OutputError
        Another process holds the lock (``<folder>: in use by another run``).
    """
    try:
        import fcntl  # noqa: F401
    except ImportError:                     # no flock on this platform: no lock
        yield
        return
    folder = os.fspath(folder).rstrip(os.sep) or os.sep
    lock = folder + ".lock"
    made = _make_parents(folder)
    try:
        fd = _acquire(lock, folder)
        try:
            os.ftruncate(fd, 0)
            os.pwrite(fd, str(os.getpid()).encode(), 0)
            yield
        finally:
            with contextlib.suppress(OSError):
                os.remove(lock)
            os.close(fd)
    finally:
        for parent in reversed(made):       # the parents created here, if left empty
            with contextlib.suppress(OSError):
                os.rmdir(parent)


def _make_parents(path: str) -> list:
    """Create the missing folders above ``path``; returns them, outermost first."""
    missing, folder = [], os.path.dirname(os.path.abspath(path))
    while not os.path.exists(folder):
        missing.append(folder)
        folder = os.path.dirname(folder)
    missing.reverse()
    for m in missing:
        os.makedirs(m, exist_ok=True)
    return missing

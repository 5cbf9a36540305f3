"""The command line's error boundary: expected failures become one line and exit 2.

Bad input -- a missing, unreadable or malformed file, an impossible setting,
an output that exists, a folder that cannot be written, a full disk, a
request larger than the machine -- prints ``error: <path>: <problem>`` on
stderr and returns :data:`EXIT_BAD_INPUT` (2), never a traceback.
"""
from __future__ import annotations

import errno
import sys

#: exit status of a command refused for bad input
EXIT_BAD_INPUT = 2


def describe(exc: BaseException) -> str:
    """``<path>: <problem>`` of an expected failure."""
    if isinstance(exc, OSError):
        problem = exc.strerror or str(exc) or type(exc).__name__
        if exc.errno == errno.ENOSPC:
            problem = "no space left on the device"
        if exc.filename is not None:
            return f"{exc.filename}: {problem}"
        return str(exc) or problem
    if isinstance(exc, MemoryError):
        return f"out of memory: {exc}" if str(exc) else "out of memory"
    if isinstance(exc, KeyboardInterrupt):
        return "interrupted"
    return str(exc) or type(exc).__name__


def expected_errors() -> tuple:
    """Exception types that mean bad input, not a bug."""
    from ..errors import SionnaMMIRError
    from ..utils.backend import BackendError

    return (SionnaMMIRError, BackendError, OSError, IndexError, MemoryError, OverflowError,
            KeyboardInterrupt)


def error_boundary(run, args) -> int:
    """Run ``run(args)``; an expected failure prints one line and returns 2."""
    try:
        return int(run(args) or 0)
    except expected_errors() as exc:
        print(f"error: {describe(exc)}", file=sys.stderr)
        return EXIT_BAD_INPUT

"""The command line's error boundary: every failure becomes one line on stderr.

Expected failures -- bad input (a missing, unreadable or malformed file, an
impossible setting, an output that exists or is in use by another run), the
operating system refusing (a folder that cannot be written, a full disk, a
file name too long), a request larger than the machine (a memory estimate
over the available memory, a Dr.Jit limit) or an interrupt -- print
``error: <path>: <problem>`` and return :data:`EXIT_BAD_INPUT` (2), never a
traceback.  They are the exceptions of :func:`expected_errors`: the
package's own :class:`~sionna_mmir.errors.SionnaMMIRError` family (which
readers and validators raise with the offending path or option first),
``OSError``, ``MemoryError`` and ``KeyboardInterrupt``.

Any other exception is a bug, not bad input: it prints
``error: internal error: <type>: <message>`` with a request to report it
and returns :data:`EXIT_INTERNAL` (1).  Setting the environment variable
``SIONNA_MMIR_TRACEBACK=1`` adds the traceback, for the report.
"""
from __future__ import annotations

import errno
import os
import sys
import traceback

#: exit status of a command refused for bad input (or an OS / resource limit)
EXIT_BAD_INPUT = 2
#: exit status of an unexpected exception (a bug)
EXIT_INTERNAL = 1
#: how a full disk is described
NO_SPACE = "no space left on the device"
#: environment variable that adds the traceback to an internal error
ENV_TRACEBACK = "SIONNA_MMIR_TRACEBACK"


def describe(exc: BaseException) -> str:
    """``<path>: <problem>`` of an expected failure."""
    if isinstance(exc, OSError):
        problem = exc.strerror or str(exc) or type(exc).__name__
        if exc.errno == errno.ENOSPC:
            std = os.strerror(errno.ENOSPC)
            problem = problem.replace(std, NO_SPACE) if std in problem else NO_SPACE
        if exc.filename is not None:
            return f"{os.fsdecode(exc.filename)}: {problem}"
        return str(exc) or problem
    if isinstance(exc, MemoryError):
        return f"out of memory: {exc}" if str(exc) else "out of memory"
    if isinstance(exc, KeyboardInterrupt):
        return "interrupted"
    return str(exc) or type(exc).__name__


def expected_errors() -> tuple:
    """Exception types that mean bad input or a limit of the machine, not a bug."""
    from ..errors import SionnaMMIRError
    from ..utils.backend import BackendError

    return (SionnaMMIRError, BackendError, OSError, MemoryError, KeyboardInterrupt)


def report_internal(exc: BaseException) -> None:
    """Print an unexpected exception as an internal error (see module docstring)."""
    print(f"error: internal error: {type(exc).__name__}: {exc}", file=sys.stderr)
    if os.environ.get(ENV_TRACEBACK):
        traceback.print_exception(exc, file=sys.stderr)
    else:
        print(f"this is a bug in sionna-mmir, please report it with the command line "
              f"(set {ENV_TRACEBACK}=1 to add the traceback)", file=sys.stderr)


def error_boundary(run, args) -> int:
    """Run ``run(args)``: 2 for an expected failure, 1 for a bug, one line each."""
    try:
        return int(run(args) or 0)
    except expected_errors() as exc:
        print(f"error: {describe(exc)}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except Exception as exc:  # noqa: BLE001 -- the boundary: a bug, reported as one
        report_internal(exc)
        return EXIT_INTERNAL

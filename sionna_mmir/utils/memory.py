"""Memory estimates checked against the machine before large allocations.

A request whose estimated working memory exceeds what the machine has
available is refused with :class:`~sionna_mmir.errors.ResourceError`
naming the estimate, instead of being killed by the kernel part way.
"Available" is ``MemAvailable`` of ``/proc/meminfo`` (Linux), else the free
physical pages of ``os.sysconf``; where neither is known nothing is refused.
"""
from __future__ import annotations

import math
import os

from ..errors import ResourceError

#: environment variable overriding the available memory [bytes] (tests, containers)
ENV_AVAILABLE = "SIONNA_MMIR_AVAILABLE_MEMORY"


def available_memory() -> int | None:
    """Bytes of memory available for new allocations, or None when unknown."""
    override = os.environ.get(ENV_AVAILABLE)
    if override:
        return int(float(override))
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return int(os.sysconf("SC_AVPHYS_PAGES")) * int(os.sysconf("SC_PAGE_SIZE"))
    except (AttributeError, ValueError, OSError):
        return None


def format_bytes(n: float) -> str:
    """``n`` bytes in binary units, e.g. ``'18.6 TiB'``."""
    n = float(n)
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if abs(n) < 1024 or unit == "PiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    return f"{n:.1f} EiB"


def array_bytes(shape, itemsize: int) -> int:
    """Bytes of an array of ``shape`` and ``itemsize`` (exact, no overflow)."""
    return math.prod(int(s) for s in shape) * int(itemsize)


def check_memory(nbytes: int, what: str) -> None:
    """Raise :class:`ResourceError` when ``nbytes`` exceed the available memory.

    Parameters
    ----------
    nbytes : int
        Estimated working memory of the request [bytes].
    what : str
        What needs it, starting with the offending path or option, e.g.
        ``"synth --chirps 1000000: the ADC"``.
    """
    avail = available_memory()
    if avail is not None and nbytes > avail:
        raise ResourceError(f"{what} needs about {format_bytes(nbytes)} of memory, more than "
                            f"the {format_bytes(avail)} available on this machine")

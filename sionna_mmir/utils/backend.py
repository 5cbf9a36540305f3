"""Pick the Dr.Jit / Mitsuba backend before anything imports Dr.Jit.

Dr.Jit's LLVM backend JIT-compiles through a system ``libLLVM``.  Dr.Jit 1.5
aborts the whole process (``LLVM ERROR: Cannot select ... fmaximum``) when it
loads LLVM 14 or 15, which Debian 12 ships as ``libLLVM.so``.  Because that is
an abort, not an exception, we must choose the library *before* Dr.Jit starts:

1. ``DRJIT_LIBLLVM_PATH`` set by the user is respected if its major version is
   at least :data:`MIN_LLVM_MAJOR` (else a :class:`BackendError` names the fix).
2. Otherwise the usual library folders are searched and the newest suitable
   ``libLLVM`` is exported through ``DRJIT_LIBLLVM_PATH``.
3. With none found (and no CUDA GPU), import fails with a message naming the
   fix: ``apt-get install libllvm19`` or pointing ``DRJIT_LIBLLVM_PATH`` at one.

The Mitsuba variant is ``cuda_ad_mono_polarized`` when a CUDA device answers,
else ``llvm_ad_mono_polarized``; ``SIONNA_MMIR_VARIANT`` overrides both.
"""
from __future__ import annotations

import ctypes
import glob
import os
import re
import sys

MIN_LLVM_MAJOR = 16
VARIANT_ENV = "SIONNA_MMIR_VARIANT"
CPU_VARIANT = "llvm_ad_mono_polarized"
GPU_VARIANT = "cuda_ad_mono_polarized"

_SEARCH_GLOBS = (
    "/usr/lib/x86_64-linux-gnu/libLLVM*.so*",
    "/usr/lib/aarch64-linux-gnu/libLLVM*.so*",
    "/usr/lib/llvm-*/lib/libLLVM*.so*",
    "/usr/lib64/libLLVM*.so*",
    "/usr/local/lib/libLLVM*.so*",
    "/usr/local/opt/llvm/lib/libLLVM*.dylib",
    "/opt/homebrew/opt/llvm/lib/libLLVM*.dylib",
)


class BackendError(ImportError):
    """No usable Dr.Jit backend could be configured."""


def llvm_major_version(path: str) -> int | None:
    """Major LLVM version encoded in a library file name, or ``None``.

    Recognises ``libLLVM-19.so``, ``libLLVM.so.19.1``, ``libLLVM-17.0.6.so``
    and ``/usr/lib/llvm-18/lib/libLLVM.so``.
    """
    name = os.path.basename(path)
    for pattern in (r"libLLVM-(\d+)", r"libLLVM\.so\.(\d+)", r"libLLVM\.(\d+)\.dylib"):
        m = re.search(pattern, name)
        if m:
            return int(m.group(1))
    m = re.search(r"llvm-(\d+)", path)
    return int(m.group(1)) if m else None


def find_libllvm(min_major: int = MIN_LLVM_MAJOR, extra_globs=()) -> str | None:
    """Newest ``libLLVM`` of at least ``min_major`` on this machine, or ``None``."""
    patterns = list(extra_globs) + list(_SEARCH_GLOBS)
    for d in os.environ.get("LD_LIBRARY_PATH", "").split(os.pathsep):
        if d:
            patterns.append(os.path.join(d, "libLLVM*.so*"))
    best, best_v = None, -1
    for pat in patterns:
        for p in sorted(glob.glob(pat)):
            v = llvm_major_version(p)
            if v is not None and v >= min_major and v > best_v and os.path.isfile(p):
                best, best_v = p, v
    return best


def cuda_available() -> bool:
    """True when a CUDA driver loads and reports at least one device."""
    try:
        lib = ctypes.CDLL("libcuda.so.1")
    except OSError:
        return False
    try:
        if lib.cuInit(0) != 0:
            return False
        count = ctypes.c_int(0)
        return lib.cuDeviceGetCount(ctypes.byref(count)) == 0 and count.value > 0
    except AttributeError:
        return False


def choose_variant() -> str:
    """The Mitsuba variant to use (environment override, else GPU, else CPU)."""
    v = os.environ.get(VARIANT_ENV)
    if v:
        return v
    return GPU_VARIANT if cuda_available() else CPU_VARIANT


def configure_llvm() -> str | None:
    """Export ``DRJIT_LIBLLVM_PATH`` for a suitable LLVM; return the path used.

    Raises :class:`BackendError` when Dr.Jit would otherwise load an LLVM that
    aborts the process.
    """
    user = os.environ.get("DRJIT_LIBLLVM_PATH")
    if user:
        if not os.path.isfile(user):
            raise BackendError(
                f"DRJIT_LIBLLVM_PATH={user!r} does not exist. Point it at libLLVM "
                f">= {MIN_LLVM_MAJOR} (Debian: apt-get install libllvm19 -> "
                "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1) or unset it.")
        v = llvm_major_version(user)
        if v is not None and v < MIN_LLVM_MAJOR:
            raise BackendError(
                f"DRJIT_LIBLLVM_PATH={user!r} is LLVM {v}; Dr.Jit aborts with "
                f"'LLVM ERROR: Cannot select ... fmaximum' on LLVM < {MIN_LLVM_MAJOR}. "
                "Install libllvm19 (apt-get install libllvm19) and point "
                "DRJIT_LIBLLVM_PATH at /usr/lib/x86_64-linux-gnu/libLLVM.so.19.1.")
        return user
    path = find_libllvm()
    if path is None:
        raise BackendError(
            f"No libLLVM >= {MIN_LLVM_MAJOR} found; Dr.Jit's CPU backend would abort "
            "on the system LLVM 14/15. Fix: 'apt-get install libllvm19' (Debian 12) "
            "or set DRJIT_LIBLLVM_PATH to a libLLVM >= 16; on a CUDA machine set "
            f"{VARIANT_ENV}={GPU_VARIANT}.")
    os.environ["DRJIT_LIBLLVM_PATH"] = path
    return path


_CONFIGURED: str | None = None


def init_backend() -> str:
    """Configure LLVM, import Mitsuba and set the variant (idempotent).

    Returns the Mitsuba variant name in use.
    """
    global _CONFIGURED
    if _CONFIGURED is not None:
        return _CONFIGURED
    variant = choose_variant()
    if variant.startswith("llvm") or not cuda_available():
        if "drjit" in sys.modules and "DRJIT_LIBLLVM_PATH" not in os.environ:
            # Dr.Jit already started with whatever it found; nothing we can change.
            pass
        else:
            configure_llvm()
    import mitsuba as mi  # noqa: WPS433  (import after configuration, on purpose)

    if variant not in mi.variants():
        raise BackendError(f"Mitsuba variant {variant!r} is not available; "
                           f"choose one of {mi.variants()} via {VARIANT_ENV}.")
    mi.set_variant(variant)
    _CONFIGURED = variant
    return variant

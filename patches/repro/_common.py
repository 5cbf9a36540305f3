"""Shared set-up of the reproductions in this folder.

Each ``NNNN_*.py`` script reproduces one issue of sionna-rt 2.2.0 against
whichever ``sionna`` package Python imports first: the installed one, or a
patched copy put in front with ``PYTHONPATH=/path/to/copy``.  It prints one
line ``PASS|FAIL <name>: observed <bug|fixed>, expected <...> (...)`` and
exits 0 exactly when the observed behaviour matches ``--expect``.
"""
from __future__ import annotations

import argparse
import os
import sys


def setup(description: str):
    """Parse ``--expect bug|fixed``, start the backend, return ``(args, sionna.rt)``.

    ``sionna_mmir`` is imported first when available: it points
    ``DRJIT_LIBLLVM_PATH`` at an LLVM >= 16 before Dr.Jit starts (Dr.Jit 1.5
    aborts under the LLVM 14/15 of Debian 12) and selects the
    ``*_ad_mono_polarized`` variant.  Without it, Sionna RT picks its variant.
    """
    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("--expect", choices=("bug", "fixed"), required=True,
                    help="behaviour to expect: 'bug' (stock sionna-rt 2.2.0) "
                         "or 'fixed' (with the patch applied)")
    args = ap.parse_args()
    try:
        import sionna_mmir  # noqa: F401  (configures LLVM before Dr.Jit starts)
        from sionna_mmir.utils.backend import init_backend
        init_backend()
    except ImportError:
        pass
    import sionna.rt as rt
    return args, rt


def report(name: str, expect: str, observed: str, detail: str) -> None:
    """Print the PASS/FAIL line and exit (0 when ``observed == expect``)."""
    import sionna
    where = os.path.dirname(os.path.dirname(os.path.abspath(sionna.__file__)))
    ok = observed == expect
    print(f"{'PASS' if ok else 'FAIL'} {name}: observed {observed}, expected {expect} "
          f"({detail}) [sionna from {where}]")
    sys.stdout.flush()
    sys.exit(0 if ok else 1)

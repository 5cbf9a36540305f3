"""Thread control for NumPy's BLAS.

Many small matrix products (effect initial values, per-chunk adjoints of the
ADC synthesis) run far slower on a multi-threaded BLAS when the machine is
loaded (measured up to 600x on a 12 x 641 product); :func:`one_blas_thread`
limits BLAS to one thread inside a block.  ``threadpoolctl`` is optional: without
it the block runs with the default threading.
"""
from __future__ import annotations

import contextlib
import functools


@functools.lru_cache(maxsize=1)
def _controller():
    try:
        from threadpoolctl import ThreadpoolController
    except ImportError:  # optional dependency: keep the default threading
        return None
    return ThreadpoolController()


@contextlib.contextmanager
def one_blas_thread():
    """BLAS on one thread inside the block (no-op without threadpoolctl)."""
    ctl = _controller()
    if ctl is None:
        yield
        return
    with ctl.limit(limits=1, user_api="blas"):
        yield

"""``RadarPaths``: per (tx, rx, path) complex amplitudes and delays.

The result of :class:`~sionna_mmir.paths.solver.RadarPathSolver`, the radar
counterpart of Sionna RT's ``Paths``.  Amplitudes are *voltage ratios*
(``|a|^2`` = received / transmitted power for unit transmit power); the
carrier phase is not in ``a`` but in the delay ``tau`` (paper eq. 4), which
:func:`~sionna_mmir.fmcw.synthesize_adc` applies per ADC sample.

The solver's paths factor over the Tx and Rx elements (MIMO ray reuse)::

    a[t, r, p] = c[p] g_t[t, p] g_r[r, p]      tau[t, r, p] = tau_t[t, p] + tau_r[r, p]

and are kept in that form (:class:`PathFactors`, ``(T + R + 2) P`` numbers
instead of ``2 T R P``): :meth:`RadarPaths.adc` and :meth:`RadarPaths.power`
work on the factors, while the expanded ``a_re`` / ``a_im`` / ``tau`` /
``tau_rate`` are formed on first access, for consumers that need them.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputValueError
from ..utils.backend import init_backend

init_backend()

import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402

_FLAT = ("a_re", "a_im", "tau", "tau_rate")


@dataclass
class PathFactors:
    """Factorised paths (Dr.Jit ``mi.Float`` arrays, inside the AD graph).

    Parameters
    ----------
    c_re, c_im : mi.Float
        [P] per-path amplitude, beat convention (``a = c g_t g_r``)
    g_t : mi.Float
        [T*P] Tx-leg gain (``t`` slowest, ``p`` fastest)
    tau_t : mi.Float
        [T*P] Tx-leg delay [s]
    g_r : mi.Float
        [R*P] Rx-leg gain
    tau_r : mi.Float
        [R*P] Rx-leg delay [s]
    rate : mi.Float or None
        [P] delay rate ``d tau / dt`` [s/s], or ``None`` (static)
    shape : tuple
        ``(T, R, P)``
    """

    c_re: object
    c_im: object
    g_t: object
    tau_t: object
    g_r: object
    tau_r: object
    rate: object
    shape: tuple

    def arrays(self) -> list:
        """The stored Dr.Jit arrays (for ``dr.eval``)."""
        return [x for x in (self.c_re, self.c_im, self.g_t, self.tau_t, self.g_r, self.tau_r,
                            self.rate) if x is not None]

    def _index(self):
        """Flat ``[T*R*P]`` gather indices ``(t * P + p, r * P + p, p)``."""
        T, R, P = self.shape
        i = dr.arange(mi.UInt32, T * R * P)
        t, r, p = i // (R * P), (i // P) % R, i % P
        return t * P + p, r * P + p, p

    def expand(self, name: str):
        """One expanded field (``a_re``, ``a_im``, ``tau``, ``tau_rate``), ``mi.Float``
        [T*R*P] (AD), or ``None`` for a static ``tau_rate``."""
        if name == "tau_rate" and self.rate is None:
            return None
        it, ir, p = self._index()
        if name == "tau":
            return dr.gather(mi.Float, self.tau_t, it) + dr.gather(mi.Float, self.tau_r, ir)
        if name == "tau_rate":
            return dr.gather(mi.Float, self.rate, p)
        c = self.c_re if name == "a_re" else self.c_im
        return dr.gather(mi.Float, c, p) * dr.gather(mi.Float, self.g_t, it) \
            * dr.gather(mi.Float, self.g_r, ir)

    def numpy(self):
        """Detached factors: ``(c complex128 [P], g_t, tau_t [T, P], g_r, tau_r [R, P],
        rate [P] or None)``, float64."""
        T, R, P = self.shape

        def n(x, shape=None):
            arr = np.asarray(dr.detach(x), dtype=np.float64)
            return arr if shape is None else arr.reshape(shape)
        rate = None if self.rate is None else n(self.rate)
        return (n(self.c_re) + 1j * n(self.c_im), n(self.g_t, (T, P)), n(self.tau_t, (T, P)),
                n(self.g_r, (R, P)), n(self.tau_r, (R, P)), rate)

    def power(self):
        """``mi.Float`` ``sum_p |c_p|^2 (sum_t g_t^2) (sum_r g_r^2)`` (AD)."""
        T, R, P = self.shape
        return dr.sum((dr.square(self.c_re) + dr.square(self.c_im))
                      * _sum_rows(dr.square(self.g_t), T, P) * _sum_rows(dr.square(self.g_r), R, P))

    def path_powers(self) -> np.ndarray:
        """Detached ``|c_p|^2 mean_t g_t^2 mean_r g_r^2`` per path, float64 ``[P]``
        (the path's mean power over the Tx-Rx pairs)."""
        T, R, P = self.shape
        c_re, c_im, g_t, g_r = (dr.detach(x) for x in (self.c_re, self.c_im, self.g_t, self.g_r))
        dr.eval(c_re, c_im, g_t, g_r)

        def msq(x, rows):          # mean square over the rows, float32 in, float64 out
            a = np.asarray(x).reshape(rows, P)
            return np.einsum("ip,ip->p", a, a, dtype=np.float64) / rows
        return (msq(c_re, 1) + msq(c_im, 1)) * msq(g_t, T) * msq(g_r, R)

    def pruned(self, min_rel_power: float) -> "PathFactors":
        """The paths whose power (:meth:`path_powers`) exceeds ``min_rel_power``
        times the strongest's, gathered inside the AD graph (dropped paths get
        no gradient); ``self`` when none is dropped."""
        T, R, P = self.shape
        if not min_rel_power > 0 or P == 0:
            return self
        pw = self.path_powers()
        keep = np.flatnonzero(pw > float(min_rel_power) * pw.max())
        if keep.size == P:
            return self
        n = keep.size
        idx = mi.UInt32(keep.astype(np.uint32))

        def rows(x, m):
            flat = (np.arange(m, dtype=np.uint32)[:, None] * np.uint32(P) + keep[None]).ravel()
            return dr.gather(mi.Float, x, mi.UInt32(flat))
        return PathFactors(dr.gather(mi.Float, self.c_re, idx), dr.gather(mi.Float, self.c_im, idx),
                           rows(self.g_t, T), rows(self.tau_t, T), rows(self.g_r, R),
                           rows(self.tau_r, R),
                           None if self.rate is None else dr.gather(mi.Float, self.rate, idx),
                           (T, R, n))

    def adc(self, radar, min_rel_power: float = 0.0):
        """Raw ADC (``DrAdc``, AD) by the factorised synthesiser; paths weaker
        than ``min_rel_power`` x the strongest are left out (:meth:`pruned`)."""
        from ..fmcw.drjit_factorised import synthesize_adc_factorised_drjit

        f = self.pruned(min_rel_power)
        return synthesize_adc_factorised_drjit(radar, f.c_re, f.c_im, f.g_t, f.tau_t,
                                               f.g_r, f.tau_r, f.rate)


class PathGeometry:
    """Where each path meets the array: the points its legs connect to.

    The delay of path ``p`` between Tx ``t`` and Rx ``r`` is
    ``(|x_tx[p] - tx_t| + chain_tx[p] + |x_rx[p] - rx_r| + chain_rx[p]) / c``
    (``x_rx`` of a mirror chain is the receiver's unfolded image point), so the paths
    can be re-evaluated for moved elements (a pose offset) without tracing.

    Parameters
    ----------
    x_tx, x_rx : mi.Point3f
        Tx-side and Rx-side connection points [m], scene frame.
    chain_tx, chain_rx : mi.Float
        Lengths added on each side [m].
    objects : mi.UInt32
        Object index of each path's first interaction.
    object_names : list of str
        Names of the object indices.
    tx_w, rx_w : mi.Point3f
        Element positions the paths were formed with [m].
    """

    def __init__(self, x_tx, x_rx, chain_tx, chain_rx, objects, object_names, tx_w, rx_w):
        self._arrays = (x_tx, x_rx, chain_tx, chain_rx, objects, tx_w, rx_w)
        self.object_names = list(object_names)
        self._numpy = None

    def numpy(self) -> dict:
        """Detached float64 arrays: ``x_tx``, ``x_rx`` ``[P, 3]``, ``chain_tx``,
        ``chain_rx`` ``[P]``, ``objects`` int ``[P]``, ``tx``, ``rx`` ``[T|R, 3]``."""
        if self._numpy is None:
            x_tx, x_rx, c_t, c_r, obj, tx_w, rx_w = self._arrays

            def pts(v):
                return np.stack([np.asarray(dr.detach(v[c]), dtype=np.float64)
                                 for c in range(3)], axis=1)
            self._numpy = {"x_tx": pts(x_tx), "x_rx": pts(x_rx),
                           "chain_tx": np.asarray(dr.detach(c_t), dtype=np.float64),
                           "chain_rx": np.asarray(dr.detach(c_r), dtype=np.float64),
                           "objects": np.asarray(obj, dtype=np.int64),
                           "tx": pts(tx_w), "rx": pts(rx_w)}
        return self._numpy


def _sum_rows(x, n: int, P: int):
    """``sum_i x[i * P + p]`` over ``i < n``: ``mi.Float`` [P] (AD)."""
    p = dr.arange(mi.UInt32, P)
    total = dr.gather(mi.Float, x, p)
    for i in range(1, n):
        total = total + dr.gather(mi.Float, x, p + i * P)
    return total


class RadarPaths:
    """Paths of one radar frame (Dr.Jit arrays, inside the AD graph).

    Built either from the expanded arrays (``RadarPaths(a_re, a_im, tau,
    tau_rate, shape, depth, num_candidates)``) or from factors
    (:meth:`from_factors`); with factors the expanded fields are gathered on
    first access and cached.  Assigning an expanded field turns the object
    into an expanded one (the factors are dropped).

    Parameters
    ----------
    a_re, a_im : mi.Float, optional
        [T*R*P], amplitude (``t`` slowest, ``p``
        fastest), dimensionless voltage ratio
    tau : mi.Float, optional
        [T*R*P], delay [s]
    tau_rate : mi.Float, optional
        [T*R*P] ``d tau / dt`` [s/s] or ``None``
    shape : tuple, optional
        ``(T, R, P)``
    depth : numpy.ndarray, optional
        [P] number of interactions of each path
    num_candidates : int, optional
        rays launched (the Monte Carlo ``N`` of eq. 3)
    factors : PathFactors, optional
        the factorised paths, or ``None``
    """

    def __init__(self, a_re=None, a_im=None, tau=None, tau_rate=None, shape=(0, 0, 0),
                 depth=None, num_candidates: int = 0, info: dict | None = None,
                 samples: list | None = None, factors: PathFactors | None = None,
                 geometry: PathGeometry | None = None):
        if factors is None and (a_re is None or a_im is None or tau is None):
            raise InputValueError("RadarPaths needs 'a_re', 'a_im' and 'tau', or 'factors'")
        self._flat = dict(a_re=a_re, a_im=a_im, tau=tau, tau_rate=tau_rate)
        self.factors = factors
        self.shape = tuple(factors.shape if factors is not None else shape)
        self.depth = np.zeros(self.shape[2], np.int32) if depth is None else depth
        self.num_candidates = int(num_candidates)
        self.info = {} if info is None else info
        #: recorded discrete decisions, pass as ``samples=`` to replay them
        self.samples = samples
        #: :class:`PathGeometry` of the paths (solver output), or ``None``
        self.geometry = geometry

    @classmethod
    def from_factors(cls, factors: PathFactors, depth=None, num_candidates: int = 0,
                     info: dict | None = None, samples=None,
                     geometry: PathGeometry | None = None) -> "RadarPaths":
        """Paths held as :class:`PathFactors` (no ``[T, R, P]`` expansion)."""
        return cls(factors=factors, depth=depth, num_candidates=num_candidates, info=info,
                   samples=samples, geometry=geometry)

    # ------------------------------------------------------- expanded fields
    def _get(self, name):
        if self._flat[name] is None and self.factors is not None:
            self._flat[name] = self.factors.expand(name)
        return self._flat[name]

    def _set(self, name, value):
        if self.factors is not None:
            for other in _FLAT:
                self._get(other)
            self.factors = None
        self._flat[name] = value

    a_re = property(lambda self: self._get("a_re"), lambda self, v: self._set("a_re", v))
    a_im = property(lambda self: self._get("a_im"), lambda self, v: self._set("a_im", v))
    tau = property(lambda self: self._get("tau"), lambda self, v: self._set("tau", v))
    tau_rate = property(lambda self: self._get("tau_rate"), lambda self, v: self._set("tau_rate", v))

    @property
    def is_factorised(self) -> bool:
        """True when the paths are held as :class:`PathFactors`."""
        return self.factors is not None

    @property
    def num_paths(self) -> int:
        return self.shape[2]

    def __repr__(self):
        kind = "factorised" if self.is_factorised else "expanded"
        return f"RadarPaths({kind}, shape={self.shape}, num_candidates={self.num_candidates})"

    # ------------------------------------------------------------- accessors
    def arrays(self) -> list:
        """The stored Dr.Jit arrays (factors, or the expanded fields): ``dr.eval(*paths.arrays())``."""
        if self.is_factorised:
            return self.factors.arrays()
        return [x for x in self._flat.values() if x is not None]

    def tensors(self):
        """``(a_re, a_im, tau, tau_rate)`` as ``mi.TensorXf`` ``[T, R, P]`` (expands)."""
        def t(x):
            return None if x is None else mi.TensorXf(x, self.shape)
        return t(self.a_re), t(self.a_im), t(self.tau), t(self.tau_rate)

    def numpy(self):
        """``(a complex128 [T,R,P], tau float64 [T,R,P], tau_rate or None)`` (detached).

        From factors the expansion is done in NumPy (float64), not in Dr.Jit.
        """
        if self.is_factorised:
            c, g_t, tau_t, g_r, tau_r, rate = self.factors.numpy()
            a = c[None, None, :] * g_t[:, None, :] * g_r[None, :, :]
            tau = tau_t[:, None, :] + tau_r[None, :, :]
            rho = None if rate is None else np.broadcast_to(rate, self.shape).copy()
            return a, tau, rho

        def n(x):
            return None if x is None else np.asarray(dr.detach(x), dtype=np.float64).reshape(self.shape)
        return n(self.a_re) + 1j * n(self.a_im), n(self.tau), n(self.tau_rate)

    def power(self):
        """``mi.Float`` total received power ``sum |a|^2`` over pairs and paths (AD)."""
        if self.is_factorised:
            return self.factors.power()
        return dr.sum(dr.square(self.a_re) + dr.square(self.a_im))

    def adc(self, radar, min_rel_power: float = 0.0):
        """Raw ADC (a ``DrAdc``, AD): the factorised synthesiser when factorised
        (paths weaker than ``min_rel_power`` x the strongest left out, see
        :meth:`PathFactors.pruned`), else :func:`~sionna_mmir.fmcw.synthesize_adc`
        on the expanded arrays (no pruning)."""
        if self.is_factorised:
            return self.factors.adc(radar, min_rel_power)
        from ..fmcw.synthesize import synthesize_adc

        a_re, a_im, tau, rate = self.tensors()
        return synthesize_adc(radar, (a_re, a_im), tau, rate)

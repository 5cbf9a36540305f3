"""Ego motion at a fixed velocity, averaged over chirp loops.

:class:`~.ego_motion.EgoMotion` moves the static scene differently in every
chirp, so a model holding it has no chirp-averaged counterpart in the sense
of :meth:`~sionna_mmir.effects.model.EffectModel.chirp_averaged` (an effect
that commutes with the average).  At a *fixed* velocity it is still a linear
map of the static signal ``x [F, T, R, 1, N]`` (everything before it in the
chain is the same in every chirp), so its chirp average is one linear map
too, and the residual loop can score and fit the chirp-static candidates
beside an adopted ego motion on the chirp average, as it does everywhere
else.  With the geometry of :func:`~.ego_motion.ego_geometry` (derived from
the same static signal, so the same atoms and bin directions as the full
model)::

    mean_c x'_c = sum_j c_j A_j + IDFT-free part K DFT(x_rest)
    c = x W,  x_rest = x - c waves
    A[f, t, r, j, n] = mean_c S[f, t, r, c, j] Q[f, t, c, j, n]
    K[f, t, n, k]   = (1 / C) sum_c E[f, t, c, n] P[f, t, c, k] F^H[n, k]

(the source effect gives the geometry, its time terms and its hold, so
this module does not import :mod:`~.ego_motion`) with ``S``, ``Q`` the
atoms' slow- and fast-time factors
(:class:`~.ego_motion._MovedAtoms`), ``P[k] = e^{j v 2 pi f_c rho' T_c
cos_k}`` the rest's per-bin slow-time factor, ``E[n] = e^{j v phi_fast}``
its fast-time factor and ``F^H`` the unitary inverse DFT.  Exact to float32
(the mean over chirps of :meth:`~.ego_motion.EgoMotion.apply`, test
``test_effects_scene::test_14h``); ``A`` and ``K`` are remembered per
geometry.  ``A`` has ``F T R J N`` entries and ``K`` ``F T N^2`` (0.8 M each
on a 12 x 16 x 16 x 256 cascade capture): an evaluation is a few small
matrix products instead of ``C`` moved copies of the scene.

The velocity is not a parameter here (it hardly shows on the average): the
full model refits it (:func:`~sionna_mmir.residual.adoption._carry_back`).
"""
from __future__ import annotations

import numpy as np

from .. import ops
from ..frozen import FrozenPart
from ._sensor_common import _rows_times as _rows
from .scatterer import one_blas_thread, static_view

dr, mi = ops.dr, ops.mi


def rest_kernel(bins, fast, cos_bins, v) -> np.ndarray:
    """``K [F, T, N, N]``: the chirp-mean of the rest's move as a matrix on
    its unitary DFT (``y[n] = sum_k K[n, k] X[k]``).

    ``bins [F, T, 1, C, 1]`` and ``fast [F, T, 1, C, N]`` from
    :func:`~.ego_motion.phase_terms` [rad per m/s], ``cos_bins [N]``, ``v`` [m/s]."""
    N = fast.shape[-1]
    C = fast.shape[3]
    E = np.exp(1j * v * fast[:, :, 0])                                       # [F, T, C, N]
    P = np.exp(1j * v * bins[:, :, 0] * cos_bins[None, None, None, :])       # [F, T, C, N]
    M = np.matmul(E.transpose(0, 1, 3, 2), P) / C                            # [F, T, N, N]
    n = np.arange(N)
    Fh = np.exp(2j * np.pi * np.outer(n, n) / N) / np.sqrt(N)
    return M * Fh


def atom_kernel(geo, bins, fast, v) -> np.ndarray:
    """``A [F, T, R, J, N]``: the chirp-mean of the atoms' moved waves
    (``mean_c S Q``, :class:`~.ego_motion._MovedAtoms`)."""
    J = geo.waves.shape[0]
    F, T, _, C, N = fast.shape
    R = geo.cos_pairs.shape[2]
    slow = bins[:, :, 0, :, 0][:, :, None, :, None] \
        * np.transpose(geo.cos_pairs, (1, 2, 0))[None, :, :, None, :]            # [F,T,R,C,J]
    qbar = geo.cos_pairs.reshape(J, -1).mean(axis=1)
    S = np.exp(1j * v * slow)
    Q = geo.waves[None, None, None] * np.exp(1j * v * qbar[:, None]
                                              * fast[:, :, 0][:, :, :, None, :])  # [F,T,C,J,N]
    out = np.empty((F, T, R, J, N), complex)
    for j in range(J):
        out[:, :, :, j] = np.matmul(S[..., j], Q[:, :, :, j]) / C               # [F,T,R,N]
    return out


class _AveragedMove(dr.CustomOp):
    """``y = sum_j c_j A_j + K DFT(x - c waves)``, ``c = x W`` (AD node on the
    host; the map is linear, its adjoint the conjugate transpose:
    ``G_r = DFT^H K^H G``, ``G_c = G A^H - G_r waves^H``, ``G_x = G_r + G_c W^H``)."""

    def eval(self, re, im, W=None, waves=None, A=None, K=None):
        self.W, self.waves, self.A, self.K = W, waves, A, K
        return ops.tensor(self._map(ops._numpy_pair(re, im)[:, :, :, 0])[:, :, :, None])

    def _map(self, x):
        """The forward map on a NumPy ``[F, T, R, N]`` signal."""
        c = _rows(x, self.W)
        y = np.matmul(np.fft.fft(x - _rows(c, self.waves), axis=-1, norm="ortho"),
                      np.swapaxes(self.K, -1, -2))
        if self.A.shape[3]:
            y = y + np.matmul(c[..., None, :], self.A)[..., 0, :]
        return y

    def forward(self):
        dx = ops._numpy_pair(self.grad_in("re"), self.grad_in("im"))[:, :, :, 0]
        self.set_grad_out(ops.tensor(self._map(dx)[:, :, :, None]))

    def backward(self):
        G = ops._numpy_pair(*self.grad_out())[:, :, :, 0]
        Gr = np.fft.ifft(np.matmul(G, np.conj(self.K)), axis=-1, norm="ortho")
        Gc = -_rows(Gr, np.conj(self.waves).T)
        if self.A.shape[3]:
            Gc = Gc + np.matmul(G[..., None, :], np.conj(np.swapaxes(self.A, -1, -2)))[..., 0, :]
        Gx = Gr + _rows(Gc, np.conj(self.W).T)
        gx = ops.tensor(Gx[:, :, :, None])
        self.set_grad_in("re", gx[0])
        self.set_grad_in("im", gx[1])

    def name(self):
        return "AveragedEgoMotion"


class AveragedEgoMotion(FrozenPart):
    """:class:`~.ego_motion.EgoMotion` at a fixed velocity, averaged over
    the ``C`` chirp loops of the full context ``ctx`` (no parameters).

    Parameters
    ----------
    source : EgoMotion
        the effect it stands for (its ``max_directions`` and ``angle_aware``)
    velocity : float
        [m/s]
    ctx : EffectContext
        the full model's context (its slow and fast times)
    """

    _CACHED = ("_kernels",)

    def __init__(self, source, velocity: float, ctx):
        self._stand_for(source, f"at {velocity:.4f} m/s")
        self.velocity = float(velocity)
        F, T, _, C, N = ctx.shape
        bins, fast = source.time_terms(ctx)
        self.bins = np.ascontiguousarray(np.broadcast_to(bins, (F, T, 1, C, 1)))
        self.fast = np.ascontiguousarray(np.broadcast_to(fast, (F, T, 1, C, N)))
        self._kernels = None

    def held_state(self):
        """The geometry held (:func:`~.ego_motion.hold_geometry`)."""
        return self.source.held_state()

    def kernels(self, geo):
        """``(A, K)`` for geometry ``geo`` (remembered for the last one)."""
        if self._kernels is None or self._kernels[0] is not geo:
            v = self.velocity
            self._kernels = (geo, atom_kernel(geo, self.bins, self.fast, v),
                             rest_kernel(self.bins, self.fast, geo.cos_bins, v))
        return self._kernels[1], self._kernels[2]

    def apply(self, x, p, ctx):
        if not self.source.angle_aware:
            e = np.exp(1j * self.velocity * (self.bins + self.fast)).mean(axis=3, keepdims=True)
            return ops.cmul(x, ops.tensor(e))
        xn = ops.to_numpy(x)
        with one_blas_thread():
            geo = self.source.geometry(static_view(xn), ctx)
            A, K = self.kernels(geo)
        out = dr.custom(_AveragedMove, x[0], x[1], W=geo.W, waves=geo.waves, A=A, K=K)
        return out[0], out[1]

    def variance(self, x, X, p, ctx):
        raise NotImplementedError("AveragedEgoMotion is a mean effect")

"""Laplacian-smoothed ("large steps") parameterisation of per-vertex fields.

Nicolet, Jacobson & Jakob 2021, "Large Steps in Inverse Rendering of Geometry",
ACM TOG 40(6): optimise ``u = (I + lambda L) x`` instead of the per-vertex
field ``x`` (``L`` the combinatorial graph Laplacian of the mesh, ``D - W``).
The forward map is ``x = A^-1 u`` with ``A = I + lambda L`` (symmetric
positive definite), so a gradient ``g_x`` pulls back to ``g_u = A^-1 g_x``:

* a field constant over a connected component passes unchanged (``L 1 = 0``),
  so a coherent update (a whole wall tilting) keeps its size;
* vertex-to-vertex noise in the gradient -- and Adam's first steps, which
  move every component by about the step size whatever its gradient -- is
  averaged over ``~sqrt(lambda)`` edges before it reaches the field.

Used for the shading normals: on a denoised LiDAR scaffold they are within
~0.1 deg of the truth, and independent per-vertex steps of that size already
break the coherence of the physical-optics sums of flat walls.  Smoothing
does not cure that: on the benchmark (20 iterations, lambda 500) learned
normals still cost accuracy (mean RA correlation 0.670 vs 0.774 without them,
``comparisons/with_normals/``); it is the tool for scaffolds whose normals
are noisy, and the default is off.  ``A`` is factorised once (SciPy SuperLU);
each forward map and pull-back is a pair of triangular solves per column.

==========  ================================================================
faces       (F, 3) int vertex indices of one mesh
n_vertices  number of vertices ``Nv`` (vertices no face uses get ``L``'s
            zero row: they stay as given)
lam         smoothing weight ``lambda >= 0`` (0: identity)
==========  ================================================================
"""
from __future__ import annotations

import numpy as np

from ..errors import ConfigError


def graph_laplacian(faces: np.ndarray, n_vertices: int):
    """Combinatorial Laplacian ``D - W`` (``scipy.sparse.csr_matrix`` [Nv, Nv]) of
    the mesh's unique undirected edges (``W_ij = 1`` per edge)."""
    from scipy.sparse import coo_matrix, diags

    f = np.asarray(faces, dtype=np.int64)
    if f.ndim != 2 or f.shape[1] != 3:
        raise ConfigError(f"graph_laplacian: faces must be (F, 3), got {f.shape}")
    n = int(n_vertices)
    if f.size and (f.min() < 0 or f.max() >= n):
        raise ConfigError(f"graph_laplacian: face indices outside [0, {n})")
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    e = np.unique(np.sort(e, axis=1), axis=0)
    e = e[e[:, 0] != e[:, 1]]
    i = np.concatenate([e[:, 0], e[:, 1]])
    j = np.concatenate([e[:, 1], e[:, 0]])
    W = coo_matrix((np.ones(len(i)), (i, j)), shape=(n, n)).tocsr()
    deg = np.asarray(W.sum(axis=1)).ravel()
    return (diags(deg) - W).tocsr()


class LaplacianParam:
    """``x <-> u = (I + lam L) x`` for one mesh (see module docstring)."""

    def __init__(self, faces: np.ndarray, n_vertices: int, lam: float):
        from scipy.sparse import identity
        from scipy.sparse.linalg import splu

        lam = float(lam)
        if not np.isfinite(lam) or lam < 0:
            raise ConfigError(f"LaplacianParam: lam must be >= 0, got {lam!r}")
        self.lam = lam
        self.n = int(n_vertices)
        self.A = (identity(self.n, format="csr") + lam * graph_laplacian(faces, self.n)).tocsc()
        self._lu = splu(self.A) if lam > 0 else None

    def _solve(self, b: np.ndarray) -> np.ndarray:
        b = np.asarray(b, dtype=np.float64)
        if b.shape[0] != self.n:
            raise ConfigError(f"LaplacianParam: expected {self.n} rows, got {b.shape}")
        if self._lu is None:
            return b.copy()
        return self._lu.solve(np.ascontiguousarray(b))

    def to_latent(self, x: np.ndarray) -> np.ndarray:
        """``u = A x`` (``x`` [Nv] or [Nv, C])."""
        x = np.asarray(x, dtype=np.float64)
        return np.asarray(self.A @ x)

    def from_latent(self, u: np.ndarray) -> np.ndarray:
        """``x = A^-1 u``."""
        return self._solve(u)

    def pullback(self, g_x: np.ndarray) -> np.ndarray:
        """``dL/du = A^-T dL/dx = A^-1 dL/dx`` (``A`` symmetric)."""
        return self._solve(g_x)

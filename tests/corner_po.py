"""Brute-force physical optics of flat PEC plates and their specular chains (NumPy).

A reference for the radar path solver's corner reflectors that shares no
code with it.  The field of a chain of plates ``P1 -> P2 .. -> Pl`` is the
Kirchhoff (physical-optics) integral over the *first* plate, with the
transmitter replaced by its image through the mirrors of ``Pl .. P2``
(image theory), kept where the broken ray from the point to the transmitter
really crosses ``P2 .. Pl`` in that order and nothing blocks any leg:

    a = sum_chains (1 / 4 pi) int_{P1, lit} pol c_po exp(-j k (L_r + L_t)) / (L_r L_t) dA

``L_r = |y - rx|``, ``L_t = |y - T'|`` (``T'`` the image of the
transmitter), ``c_po = (cos_in + cos_out) / 2`` on ``P1`` and ``pol = e_t .
(-1)^l R_l .. R_1 e_r`` (``R = I - 2 n n^T``, the PEC mirror applied to the
receiver's polarisation).  The channel convention is the solver's, so
``sigma = |a|^2 (4 pi)^3 L_r^2 L_t^2 / lambda^2``.  The integral is a
midpoint rule on cells of edge ``h`` (a fraction of a millimetre, well below
the ``lambda / 2`` fringes of the depth-1 terms).
"""
from __future__ import annotations

import itertools

import numpy as np


class Plate:
    """A flat convex plate ``O + u e1 + v e2``: a triangle (``u + v <= 1``)
    or a parallelogram (``u, v`` in ``[0, 1]``)."""

    def __init__(self, origin, e1, e2, triangle: bool):
        self.o = np.asarray(origin, float)
        self.e1, self.e2 = np.asarray(e1, float), np.asarray(e2, float)
        self.triangle = bool(triangle)
        n = np.cross(self.e1, self.e2)
        self.area = np.linalg.norm(n) * (0.5 if triangle else 1.0)
        self.n = n / np.linalg.norm(n)
        g12 = self.e1 @ self.e2
        G = np.array([[self.e1 @ self.e1, g12], [g12, self.e2 @ self.e2]])
        self._dual = np.linalg.solve(G, np.stack([self.e1, self.e2]))    # [2, 3]

    def corners(self) -> np.ndarray:
        """Vertices ``[3 or 4, 3]`` [m]."""
        c = [self.o, self.o + self.e1, self.o + self.e2] if self.triangle else \
            [self.o, self.o + self.e1, self.o + self.e1 + self.e2, self.o + self.e2]
        return np.array(c)

    def inside(self, p) -> np.ndarray:
        """``[M]`` bool: points ``p [M, 3]`` (on the plane) inside the plate."""
        uv = (p - self.o) @ self._dual.T
        u, v = uv[:, 0], uv[:, 1]
        ok = (u >= 0) & (v >= 0)
        return ok & ((u + v <= 1) if self.triangle else ((u <= 1) & (v <= 1)))

    def mirror(self, p) -> np.ndarray:
        """Mirror image of points ``p [..., 3]`` in the plate's plane."""
        return p - 2.0 * ((p - self.o) @ self.n)[..., None] * self.n

    def grid(self, h: float):
        """Cell centres ``[M, 3]`` and cell area [m^2] of a midpoint rule of
        edge about ``h``."""
        n = max(1, int(np.ceil(max(np.linalg.norm(self.e1), np.linalg.norm(self.e2)) / h)))
        t = (np.arange(n) + 0.5) / n
        if self.triangle:
            # the n^2 congruent sub-triangles: centroids of up and down cells
            i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
            up = i + j <= n - 1
            dn = i + j <= n - 2
            u = np.concatenate([(i[up] + 1 / 3), (i[dn] + 2 / 3)]) / n
            v = np.concatenate([(j[up] + 1 / 3), (j[dn] + 2 / 3)]) / n
            dA = self.area / n ** 2
        else:
            U, V = np.meshgrid(t, t, indexing="ij")
            u, v, dA = U.ravel(), V.ravel(), self.area / n ** 2
        return self.o + u[:, None] * self.e1 + v[:, None] * self.e2, dA


def _crosses(plate, a, b) -> np.ndarray:
    """``[M]`` bool: the open segments ``a -> b`` (``[M, 3]``) cross ``plate``."""
    da, db = (a - plate.o) @ plate.n, (b - plate.o) @ plate.n
    hit = (da * db) < 0
    s = da / np.where(hit, da - db, 1.0)
    p = a + s[:, None] * (b - a)
    return hit & plate.inside(p) & (s > 1e-9) & (s < 1 - 1e-9)


def _transverse(v, k):
    t = v - np.sum(v * k, axis=-1, keepdims=True) * k
    return t / np.linalg.norm(t, axis=-1, keepdims=True)


def chain_field(plates, chain, rx, tx, wavelength, h, pol=(0.0, 0.0, 1.0)) -> complex:
    """Complex channel coefficient of one chain (indices into ``plates``)."""
    k = 2 * np.pi / wavelength
    ps = [plates[i] for i in chain]
    others = [p for i, p in enumerate(plates)]
    y, dA = ps[0].grid(h)
    # images of the Tx through the mirrors of P_l .. P_j, j = 2 .. l
    targets = [np.asarray(tx, float)]
    for p in reversed(ps[1:]):
        targets.insert(0, p.mirror(targets[0]))
    ok = ~np.any([_crosses(p, np.broadcast_to(rx, y.shape), y) for p in others
                  if p is not ps[0]], axis=0) if len(others) > 1 else np.ones(len(y), bool)
    cur = y
    for j, p in enumerate(ps[1:]):
        tgt = targets[j]
        d = tgt - cur
        s = ((p.o - cur) @ p.n) / np.where(np.abs(d @ p.n) > 1e-12, d @ p.n, 1e-12)
        nxt = cur + s[:, None] * d
        ok &= (s > 1e-9) & (s < 1 - 1e-9) & p.inside(nxt)
        for q in others:
            if q is not p and q is not ps[j]:
                ok &= ~_crosses(q, cur, nxt)
        cur = nxt
    for q in others:
        if q is not ps[-1]:
            ok &= ~_crosses(q, cur, np.broadcast_to(tx, cur.shape))
    y = y[ok]
    Lr_v = y - rx
    Lr = np.linalg.norm(Lr_v, axis=1)
    Lt_v = targets[0] - y
    Lt = np.linalg.norm(Lt_v, axis=1)
    n1 = ps[0].n
    c_po = 0.5 * (np.abs(Lr_v @ n1) / Lr + np.abs(Lt_v @ n1) / Lt)
    # polarisation: receiver's E along the incident ray, PEC mirrors, Tx's E
    k_in = Lr_v / Lr[:, None]
    E = _transverse(np.broadcast_to(np.asarray(pol, float), y.shape), k_in)
    for p in ps:
        E = -(E - 2.0 * (E @ p.n)[:, None] * p.n)
    k_out = -(Lt_v / Lt[:, None])       # from the (unfolded) Tx towards the plate
    e_t = _transverse(np.broadcast_to(np.asarray(pol, float), y.shape),
                      _unfolded_direction(ps, k_out))
    f = np.sum(E * e_t, axis=1) * c_po * np.exp(-1j * k * (Lr + Lt)) / (Lr * Lt)
    return complex(np.sum(f) * dA / (4 * np.pi))


def _unfolded_direction(ps, k_out):
    """Direction of the real last leg (Tx -> last plate) of the unfolded ray."""
    d = -k_out
    for p in ps[1:]:
        d = d - 2.0 * (d @ p.n)[:, None] * p.n
    return -d


def chains(num_plates: int, depth: int):
    """All plate index sequences of length ``depth`` without repeats in a row."""
    return [c for c in itertools.product(range(num_plates), repeat=depth)
            if all(a != b for a, b in zip(c, c[1:]))]


def corner_field(plates, rx, tx, wavelength, depths=(1, 2, 3), h=2.5e-4, pol=(0, 0, 1)) -> dict:
    """``{depth: complex coefficient}`` summed over the chains of each depth."""
    return {d: sum(chain_field(plates, c, rx, tx, wavelength, h, pol)
                   for c in chains(len(plates), d)) for d in depths}


def trihedral(a: float):
    """Triangular trihedral of edge ``a`` at the origin (faces in the
    coordinate planes of the first octant)."""
    X, Y, Z = np.eye(3) * a
    o = np.zeros(3)
    return [Plate(o, X, Y, True), Plate(o, Y, Z, True), Plate(o, Z, X, True)]


def dihedral(origin, u1, u2, w):
    """Dihedral of two parallelograms ``origin + s u_i + t w`` sharing the fold ``w``."""
    return [Plate(origin, u1, w, False), Plate(origin, u2, w, False)]


def rotation_to(a, b) -> np.ndarray:
    """Rotation matrix ``[3, 3]`` taking unit vector ``a`` to unit vector ``b``
    (the rotation about ``a x b``; a half turn about ``z`` for ``b = -a``)."""
    a, b = np.asarray(a, float) / np.linalg.norm(a), np.asarray(b, float) / np.linalg.norm(b)
    v, c = np.cross(a, b), float(a @ b)
    if np.linalg.norm(v) < 1e-12:
        return np.eye(3) if c > 0 else np.diag([-1.0, -1.0, 1.0])
    K = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + K + K @ K / (1 + c)


def placed(plates, rot, shift):
    """The plates rotated by ``rot`` about the origin, then moved by ``shift``."""
    return [Plate(rot @ p.o + shift, rot @ p.e1, rot @ p.e2, p.triangle) for p in plates]


def corner_target(kind: str, size: float, centre, subdiv: int = 0):
    """``(plates, meshes)`` of a target whose boresight (the trihedral's
    symmetry axis, the dihedral's bisector, the plate's normal) points along
    ``-x`` at the point ``centre - (R, 0, 0)`` it faces.

    ``kind`` is ``"trihedral"`` (edge ``size``; apex at ``centre``),
    ``"dihedral"`` (two ``size x size`` plates, fold along ``z`` through
    ``centre``) or ``"plate"`` (a ``size x size`` square centred at
    ``centre``, normal ``-x``).  ``meshes`` are trimesh meshes of the plates
    (one object per plate, each triangle split ``subdiv`` times 4:1).
    """
    import trimesh

    c = np.asarray(centre, float)
    if kind == "trihedral":
        plates = placed(trihedral(size), rotation_to(np.ones(3), [-1.0, 0, 0]), c)
    elif kind == "dihedral":
        s = np.sqrt(0.5) * size
        plates = dihedral(c - [0, 0, size / 2], [-s, s, 0], [-s, -s, 0], [0, 0, size])
    elif kind == "plate":
        plates = [Plate(c - [0, size / 2, size / 2], [0, size, 0], [0, 0, size], False)]
    else:
        raise ValueError(kind)
    meshes = {}
    for i, p in enumerate(plates):
        v = p.corners()
        f = [[0, 1, 2]] if p.triangle else [[0, 1, 2], [0, 2, 3]]
        m = trimesh.Trimesh(v, f, process=False)
        for _ in range(subdiv):
            m = m.subdivide()
        meshes[f"{kind}{i}"] = m
    return plates, meshes

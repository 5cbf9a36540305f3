"""Candidate-ray strategies of the radar path solver (paper Sec. 3.1).

A strategy produces the first rays from the array's phase centre and says how
the estimator weights them:

:class:`RandomCone`
    ``N`` cosine-weighted Monte Carlo directions in a cone about boresight;
    ``pdf`` in [1/sr]; estimates divide by ``N``; coherent chains continue
    at random (specular with probability ``eta``) under Russian roulette
:class:`FacetQuadrature`
    one ray to a node of every (sub-)facet in the cone, weighted by the
    facet's solid angle (a deterministic quadrature; ``pdf = 1 / Omega_s``);
    coherent chains always continue and are never rouletted, and integrate
    over the lit footprint of their cell (:mod:`.transport.aperture`)

Rays are generated outside AD (the directions are samples, not parameters).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..utils.backend import init_backend
from .transport.aperture import CutPolygons, LitAperture
from .transport.clip_lines import clip_lines

init_backend()

import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402


@dataclass
class Candidates:
    """First rays of one solver call.

    Parameters
    ----------
    origin : mi.Point3f
        Ray origins [m] (the array centre), width ``N``.
    direction : mi.Vector3f
        Unit directions in the scene frame.
    pdf : mi.Float
        Sampling density of each direction [1/sr].
    target : mi.UInt32 or None
        The facet each ray aims at (facet quadrature), else ``None``.
    sub_uv : list of mi.Float or None
        ``u, v`` of the three corners of each ray's sub-facet in its facet's
        barycentric coordinates (six arrays), or ``None``.
    """

    origin: object
    direction: object
    pdf: object
    target: object = None
    sub_uv: list | None = None

    @property
    def count(self) -> int:
        """Number of candidate rays ``N``."""
        return dr.width(self.pdf)


def cone_directions(u1, u2, cone_angle):
    """Cosine-weighted directions in a cone about ``+z``.

    Concentric disk mapping (Shirley & Chiu 1997) scaled by ``sin(cone_angle)``.

    Parameters
    ----------
    u1, u2 : mi.Float
        Uniform samples in ``[0, 1)``.
    cone_angle : float
        Half-angle of the cone [rad].

    Returns
    -------
    local : mi.Vector3f
        Unit directions, ``+z`` the cone axis.
    pdf : mi.Float
        ``cos(theta) / (pi sin^2(cone_angle))`` [1/sr].
    """
    s = math.sin(min(float(cone_angle), math.pi / 2))
    d = mi.warp.square_to_uniform_disk_concentric(mi.Point2f(u1, u2)) * s
    z = dr.safe_sqrt(1.0 - dr.squared_norm(d))
    return mi.Vector3f(d.x, d.y, z), z / (math.pi * s * s)


class RandomCone:
    """``N`` cosine-weighted rays in a cone about boresight (Monte Carlo)."""

    name = "random"
    #: coherent chains continue deterministically (no specular/scatter choice)
    deterministic_chains = False

    def __init__(self, options):
        self.num_rays = int(options.num_rays)
        self.cone_angle = math.radians(float(options.cone_angle_deg))
        self.seed = int(options.seed)

    def estimator_count(self, num_candidates: int) -> int:
        """The ``N`` an estimate is divided by."""
        return num_candidates

    def candidates(self, geo, pose, centre, wavelength) -> Candidates:
        """Directions from ``centre`` (``mi.Point3f``, scene frame) about the
        radar's boresight ``pose``."""
        N = self.num_rays
        # opaque seeds: a literal would be baked into the kernels and every new
        # seed (every fit iteration) would recompile them (~1 s per iteration)
        sampler = mi.PCG32(size=N, initstate=dr.opaque(mi.UInt64, self.seed))
        u1, u2 = sampler.next_float32(), sampler.next_float32()
        local, pdf = cone_directions(u1, u2, self.cone_angle)
        d_radar = mi.Vector3f(local.z, local.x, local.y)        # +z_local -> boresight +x
        with dr.suspend_grad():
            d_scene = pose.to_scene(d_radar)
            origin = dr.zeros(mi.Point3f, N) + dr.detach(centre)
        return Candidates(origin, d_scene, pdf)

    def keep_hits(self, valid, face, cands, tape):
        """Rays that count (every hit)."""
        return valid

    def first_triangle(self, it, cands, keep):
        """The region the first interaction integrates over (its triangle)."""
        return it.tri

    def aperture(self, options, keep, face, tri, sub):
        """No lit apertures: Monte Carlo rays sample the lit region."""
        return None


#: barycentric weights of a sub-facet's node on its corners: near the centroid
#: (a midpoint rule) but off every symmetry line of the cell, so that the node
#: of a symmetric scene (a corner reflector on its axis) is not traced exactly
#: into a crease
NODE_WEIGHTS = np.array([0.33, 0.35, 0.32])


class FacetQuadrature:
    """One ray to a node of every (sub-)facet in the cone (deterministic).

    A facet too large for a linear phase across it (``k D^2 / R >=
    facet_fresnel``, ``D`` its longest edge, ``R`` the range of its nearest
    vertex) is split into ``n^2`` congruent sub-facets,
    ``n = ceil(sqrt(k D^2 / (R facet_fresnel)))`` (at most
    ``max_facet_split``), each one ray (to the node :data:`NODE_WEIGHTS`) and
    one exact triangle average.  A coherent chain of two or more bounces
    integrates over the lit footprint of its node's cell on its last triangle
    (:class:`~.transport.aperture.LitAperture`).
    """

    name = "facets"
    deterministic_chains = True

    def __init__(self, options):
        self.cone_angle_deg = float(options.cone_angle_deg)
        self.fresnel = float(options.facet_fresnel)
        self.max_split = int(options.max_facet_split)

    def estimator_count(self, num_candidates: int) -> int:
        """A quadrature is not divided by its number of nodes."""
        return 1

    def candidates(self, geo, pose, centre, wavelength) -> Candidates:
        """Rays from ``centre`` to every (sub-)facet node inside the cone."""
        k_wave = 2.0 * math.pi / wavelength
        c = np.array([float(dr.detach(centre)[i][0]) for i in range(3)])
        rows = np.array([[float(r[i][0]) for i in range(3)] for r in pose.rows])
        V = np.asarray(dr.detach(geo.positions), dtype=np.float64).reshape(-1, 3)
        F = np.asarray(geo.faces, dtype=np.int64).reshape(-1, 3)
        fac, uvs, ns = self._split(V, F, c, rows[:, 0], k_wave)
        p0, p1, p2 = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
        cr = np.cross(p1 - p0, p2 - p0)
        area = 0.5 * np.linalg.norm(cr, axis=1)
        nrm = cr / np.maximum(2 * area, 1e-30)[:, None]
        cu, cv = uvs[:, :, 0] @ NODE_WEIGHTS, uvs[:, :, 1] @ NODE_WEIGHTS
        self._mesh = (V, F, fac, uvs, c)
        q = p0[fac] + cu[:, None] * (p1 - p0)[fac] + cv[:, None] * (p2 - p0)[fac]
        dq = q - c
        dq_n = np.linalg.norm(dq, axis=1)
        dq /= np.maximum(dq_n, 1e-12)[:, None]
        cos_q = np.maximum(np.abs(np.sum(dq * nrm[fac], axis=1)), 1e-6)
        omega = area[fac] / ns ** 2 * cos_q / np.maximum(dq_n, 1e-3) ** 2
        n = len(fac)
        dd = dq.astype(np.float32)
        origin = mi.Point3f(*(dr.full(mi.Float, float(v), n) for v in c))   # n may be 0
        direction = mi.Vector3f(mi.Float(dd[:, 0]), mi.Float(dd[:, 1]), mi.Float(dd[:, 2]))
        sub_uv = [mi.Float(uvs[:, k, j].astype(np.float32)) for k in range(3) for j in range(2)]
        self._sub_uv = sub_uv
        return Candidates(origin, direction, mi.Float((1.0 / omega).astype(np.float32)),
                          mi.UInt32(fac.astype(np.uint32)), sub_uv)

    def _split(self, V, F, c, bore, k_wave):
        """``(face [n], sub-facet corners [n, 3, 2], splits [n])`` of the facets
        in the cone facing the centre ``c`` (boresight ``bore``)."""
        p0, p1, p2 = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
        cen = (p0 + p1 + p2) / 3.0
        cr = np.cross(p1 - p0, p2 - p0)
        nrm = cr / np.maximum(np.linalg.norm(cr, axis=1), 1e-30)[:, None]
        d = cen - c
        dist = np.linalg.norm(d, axis=1)
        d /= np.maximum(dist, 1e-12)[:, None]
        cos_n = np.abs(np.sum(d * nrm, axis=1))
        ok = ((d @ bore >= np.cos(np.radians(self.cone_angle_deg)) - 1e-9) & (cos_n > 1e-4)
              & (dist > 1e-3))
        idx = np.flatnonzero(ok)
        # splits per facet from its quadratic phase at its nearest vertex
        D2 = np.max(np.stack([np.sum((p1 - p0) ** 2, 1), np.sum((p2 - p0) ** 2, 1),
                              np.sum((p2 - p1) ** 2, 1)]), axis=0)[idx]
        near = np.min(np.stack([np.linalg.norm(p - c, axis=1)[idx] for p in (p0, p1, p2)]), axis=0)
        n_split = np.clip(np.ceil(np.sqrt(k_wave * D2 / (np.maximum(near, 1e-3) * self.fresnel))),
                          1, self.max_split).astype(np.int64)
        fac, uvs, ns = [], [], []
        for n in np.unique(n_split):
            sel = idx[n_split == n]
            cells = subfacet_cells(int(n))                   # [n^2, 3, 2] corner (u, v)
            fac.append(np.repeat(sel, len(cells)))
            uvs.append(np.tile(cells, (len(sel), 1, 1)))
            ns.append(np.full(len(sel) * len(cells), float(n)))
        if not fac:
            return np.zeros(0, np.int64), np.zeros((0, 3, 2)), np.zeros(0)
        return np.concatenate(fac), np.concatenate(uvs), np.concatenate(ns)

    def keep_hits(self, valid, face, cands, tape):
        """Rays that reach their own facet (the quadrature node is on it)."""
        return valid & tape.freeze(face == cands.target)

    def first_triangle(self, it, cands, keep):
        """The first interaction integrates over its sub-facet, not the facet."""
        uv = [dr.gather(mi.Float, c, keep) for c in cands.sub_uv]
        P0, P1, P2 = it.tri
        e1, e2 = P1 - P0, P2 - P0
        return tuple(P0 + e1 * uv[2 * c] + e2 * uv[2 * c + 1] for c in range(3))

    def aperture(self, options, keep, face, tri, sub):
        """The :class:`~.transport.aperture.LitAperture` of the kept nodes
        (``keep``: their candidate indices; ``face``, ``tri``: their first
        triangles; ``sub``: their cells' corners), ``None`` without chains."""
        if int(options.max_depth) < 2 or not options.coherent:
            return None
        V, F, fac, uvs, c = self._mesh
        k = np.asarray(keep, dtype=np.int64)
        cut = CutPolygons(c, V, F, fac[k], uvs[k], clip_lines(V, F))
        sub_uv = [dr.gather(mi.Float, x, keep) for x in self._sub_uv]
        return LitAperture(c, face, tuple(dr.detach(p) for p in tri),
                           tuple(dr.detach(p) for p in sub), sub_uv, cut)


def subfacet_cells(n: int) -> np.ndarray:
    """Corners ``[n^2, 3, 2]`` (barycentric ``u, v``) of the ``n^2`` congruent
    sub-triangles of a triangle split ``n`` times per edge (same winding)."""
    out = []
    for i in range(n):
        for j in range(n - i):
            out.append([(i, j), (i + 1, j), (i, j + 1)])
            if i + j < n - 1:
                out.append([(i + 1, j), (i + 1, j + 1), (i, j + 1)])
    return np.asarray(out, dtype=np.float64) / n


def make_sampler(options):
    """The strategy named by ``options.sampling``."""
    return {"random": RandomCone, "facets": FacetQuadrature}[options.sampling](options)

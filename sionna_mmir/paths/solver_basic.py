"""Reference twin of :class:`~sionna_mmir.paths.RadarPathSolver`: the estimator written out.

:func:`solve_basic` evaluates the solver's forward model literally, one
candidate ray at a time in plain NumPy (float64), with Mitsuba ray casts for
hits and shadow rays.  It is slow and simple on purpose; the tests
(``tests/test_paths_solver_basic.py``) compare the optimised solver against
it, as :func:`~sionna_mmir.fmcw.synthesize_adc_basic` is the twin of the ADC
synthesis.

Subset covered (the solver called with ``sampling="random"``,
``coherent=True``, ``scattering=False``, ``diffraction=False``,
``min_rel_power=0``, ``max_depth`` 1 or 2, ``rr_depth >= max_depth``, static
scene and radar; any element patterns, with or without ``triangle_average``):

* candidate rays: the same ``N`` directions and densities as the solver, drawn
  from :class:`~sionna_mmir.paths.sampling.RandomCone` with the same seed
  (the twin re-implements the estimator, not the random numbers);
* depth 1: the coherent physical-optics (Kirchhoff) field of every hit ``x_1``
  connected to the transmitter by a shadow ray,
  ``a_po = j / (4 pi) (e_t . E_refl) (cos_in + cos_t) / 2 sqrt(eta_b) F / (N p_A)``,
  ``p_A = pdf |k . n_g| / L_0^2``, ``eta_b = exp(-(k sigma_h (cos_in +
  cos_t))^2)``, ``E_refl`` the receiver's polarisation Jones-reflected with the
  ITU-R P.2040 slab coefficients of
  :func:`~sionna_mmir.radio_materials.fresnel.slab_coefficients` in the s/p
  basis of :mod:`~sionna_mmir.paths.polarization`;
* depth 2: every hit continues along the mirror direction of its shading
  normal (field times ``sqrt(eta)``, ``eta = exp(-(2 k sigma_h cos_in)^2)``);
  the chain's exit aperture on ``x_2`` radiates with the Rx leg from the
  receiver's image ``x* = M_1 x_2`` (``M_1`` the mirror of the first plane)
  and the area density ``pdf |k_2 . n_g| / (L_0 + |x_2 - x_1|)^2``;
* ``F``: the exact triangle average ``(1 / A) int exp(-j q . (y - x)) dA``
  with ``q = k (M_1^T u_rx + u_tx)``, evaluated as the second divided
  difference of ``exp`` (its partial-fraction sum, or a 3 x 3 matrix
  exponential -- Opitz's formula -- for close nodes), independently of the
  series of :mod:`~sionna_mmir.paths.triangle_po`, where the triangle is
  small against the Fresnel zone (``k D^2 / R < 1``), else 1;
* per-pair legs: ``a[i, j, p] = conj(C_p) sqrt(G_t) sqrt(G_r) / (|X_p - tx_i|
  |X*_p - rx_j|)``, ``tau[i, j, p] = (|X_p - tx_i| + |X*_p - rx_j|) / c``
  (``X*`` = ``X`` at depth 1), the FMCW beat convention of
  :mod:`~sionna_mmir.paths.assemble`.

Where it deliberately differs: float64 throughout (the solver rebuilds
points from float32 barycentrics); the hit point is re-intersected in float64
with the triangle Mitsuba reports; no pruning, no roulette (with
``rr_depth >= max_depth`` the solver's roulette never acts), no
BSDF-scattered term or its reciprocal twin, no diffraction, no facet
quadrature or lit apertures, no motion (delay rates) and no automatic
differentiation (the solver's ``area_ratio`` is 1 in value).

References: Knott, Shaeffer & Tuley, *Radar Cross Section* (physical optics);
ITU-R P.2040-3 (slab coefficients); Opitz, *Z. Angew. Math. Mech.* 44 (1964)
(divided differences as a matrix function).
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from scipy.linalg import expm

from ..radar.config import rotation_matrix
from ..radio_materials.fresnel import SPEED_OF_LIGHT, slab_coefficients
from ..utils.backend import init_backend
from .options import SolverOptions
from .pose import Pose
from .sampling import RandomCone

init_backend()

import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402

RAY_EPSILON = 1e-4       # the solver's offset of secondary rays along the normal [m]


class BasicPaths(NamedTuple):
    """Paths of :func:`solve_basic`.

    Parameters
    ----------
    a : np.ndarray
        complex128 ``[T, R, P]`` amplitudes (layout of :meth:`RadarPaths.numpy`).
    tau : np.ndarray
        float64 ``[T, R, P]`` per-pair delays [s].
    depth : np.ndarray
        int ``[P]`` interactions of each path.
    points : np.ndarray
        float64 ``[P, 3]`` the Tx-side interaction point of each path [m].
    """

    a: np.ndarray
    tau: np.ndarray
    depth: np.ndarray
    points: np.ndarray


class _Mesh:
    """The scene's triangles, normals and materials as float64 NumPy arrays."""

    def __init__(self, scene):
        names = list(scene.mesh_objects)
        objs = [scene.mesh_objects[n] for n in names]
        self.V = np.concatenate([_np(o.vertex_positions).reshape(-1, 3) for o in objs])
        self.N = np.concatenate([_np(o.vertex_normals).reshape(-1, 3) for o in objs])
        self.M = np.concatenate([_np(o.vertex_materials).reshape(-1, 6) for o in objs])
        v_off = np.cumsum([0] + [len(_np(o.vertex_positions).reshape(-1, 3)) for o in objs])
        self.F = np.concatenate([np.asarray(o.faces, np.int64) + v_off[i]
                                 for i, o in enumerate(objs)])
        f_off = np.cumsum([0] + [len(o.faces) for o in objs])
        # Mitsuba shape id -> first global face of that object
        ids = [int(dr.reinterpret_array(mi.UInt32, mi.ShapePtr(scene.mesh(n)))[0]) for n in names]
        self.face_offset = {sid: int(f_off[i]) for i, sid in enumerate(ids)}
        self.mi_scene = scene.mi_scene

    def cast(self, origins, dirs):
        """Global face index of the first hit of each ray (``-1``: miss)."""
        ray = mi.Ray3f(_point(origins), _vector(dirs))
        pi = self.mi_scene.ray_intersect_preliminary(ray, coherent=False)
        valid = np.asarray(pi.is_valid(), bool)
        sid = np.asarray(dr.reinterpret_array(mi.UInt32, pi.shape), np.int64)
        prim = np.asarray(pi.prim_index, np.int64)
        return np.array([self.face_offset[s] + p if v and s in self.face_offset else -1
                         for v, s, p in zip(valid, sid, prim)], dtype=np.int64)

    def visible(self, a, b) -> np.ndarray:
        """Segments ``a [n, 3] -> b`` unobstructed, with the solver's 1 mm margins."""
        d = b[None, :] - a
        dist = np.linalg.norm(d, axis=1)
        u = d / np.maximum(dist, 1e-12)[:, None]
        ray = mi.Ray3f(_point(a + u * 1e-3), _vector(u))
        ray.maxt = mi.Float(np.maximum(dist - 2e-3, 0.0).astype(np.float32))
        return ~np.asarray(self.mi_scene.ray_test(ray), bool)

    def surface(self, face, origin, direction):
        """Hit point, barycentrics-interpolated shading normal and materials,
        geometric normal and corners of the ray's intersection with ``face``."""
        P = self.V[self.F[face]]
        e1, e2 = P[1] - P[0], P[2] - P[0]
        ng = np.cross(e1, e2)
        t = np.dot(P[0] - origin, ng) / np.dot(direction, ng)
        x = origin + t * direction
        # barycentrics of x (Cramer's rule in the triangle's plane)
        d = x - P[0]
        g = np.array([[e1 @ e1, e1 @ e2], [e1 @ e2, e2 @ e2]])
        u, v = np.linalg.solve(g, [d @ e1, d @ e2])
        w = np.array([1.0 - u - v, u, v])
        idx = self.F[face]
        n = w @ self.N[idx]
        return x, n / np.linalg.norm(n), ng / np.linalg.norm(ng), w @ self.M[idx], P


def solve_basic(scene, radar=None, options: SolverOptions | dict | None = None,
                **overrides) -> BasicPaths:
    """Coherent depth-1 and depth-2 radar paths by the literal estimator.

    Parameters
    ----------
    scene : RadarScene
        The scene (:func:`~sionna_mmir.scene.load_scene`).
    radar : RadarConfig, optional
        Default ``scene.radar``; the pose is the scene's ``position`` /
        ``orientation``.
    options : SolverOptions or dict, optional
        With keyword ``overrides``; must lie in the subset of the module
        docstring (``ValueError`` otherwise).

    Returns
    -------
    BasicPaths
        Depth-1 paths first, then depth-2 paths, each in candidate order
        (the order of the solver's output).
    """
    opts = SolverOptions.resolve(options, **overrides)
    _check_subset(opts)
    radar = radar if radar is not None else scene.radar
    mesh = _Mesh(scene)
    pos = _np(scene.position).reshape(3)
    Rm = rotation_matrix(_np(scene.orientation).reshape(3))
    tx = pos + radar.tx_positions @ Rm.T
    rx = pos + radar.rx_positions @ Rm.T
    c = pos + np.concatenate([radar.tx_positions, radar.rx_positions]).mean(axis=0) @ Rm.T
    freq = float(_np(scene.frequency)[0]) if dr.width(scene.frequency) else \
        SPEED_OF_LIGHT / radar.wavelength
    ctx = {"mesh": mesh, "opts": opts, "c": c, "freq": freq, "Rm": Rm,
           "k": 2.0 * math.pi * freq / SPEED_OF_LIGHT, "ptx": _pattern(opts.tx_pattern),
           "prx": _pattern(opts.rx_pattern)}
    dirs, pdf = _candidates(scene, opts, c)
    ctx["n_est"] = len(dirs)
    faces = mesh.cast(np.repeat(c[None], len(dirs), 0), dirs)
    hits = [_first_hit(ctx, dirs[i], faces[i], pdf[i]) for i in np.flatnonzero(faces >= 0)]
    emitted = _emit(ctx, hits)
    depth = [1] * len(emitted)
    if opts.max_depth >= 2:
        chains = _continue(ctx, hits)
        second = _emit(ctx, chains)
        emitted += second
        depth += [2] * len(second)
    a, tau, pts = _legs(emitted, tx, rx, Rm, ctx["ptx"], ctx["prx"])
    return BasicPaths(a, tau, np.array(depth, dtype=np.int64), pts)


def _first_hit(ctx, d0, face, pdf) -> dict:
    """The state of a candidate ray at its first interaction ``x_1``: the
    receiver's polarisation, the area density and the local surface."""
    c, Rm = ctx["c"], ctx["Rm"]
    x1, n_sh, ng, mat, tri = ctx["mesh"].surface(face, c, d0)
    L0 = np.linalg.norm(x1 - c)
    k_in = (x1 - c) / L0
    e_r = _transverse(Rm @ ctx["prx"].polarization_np(Rm.T @ k_in).reshape(3), k_in)
    return {"x": x1, "x_star": x1, "mirror": np.eye(3), "E": e_r.astype(complex),
            "p_area": pdf * abs(k_in @ ng) / L0 ** 2, "pdf": pdf, "L0": L0, "tri": tri,
            "mat": mat, "s": _local(k_in, n_sh, ng, mat, ctx["freq"])}


def _continue(ctx, hits) -> list:
    """Each chain continued along the mirror direction of its shading normal
    to ``x_2`` (the Rx leg then leaves from the receiver's image)."""
    mesh, k = ctx["mesh"], ctx["k"]
    starts = []
    for h in hits:
        s = h["s"]
        k_out = s["k_in"] - 2.0 * (s["k_in"] @ s["n"]) * s["n"]
        side = 1.0 if k_out @ s["ng"] > 0 else -1.0
        starts.append((h["x"] + s["ng"] * RAY_EPSILON * side, k_out))
    faces = mesh.cast(np.array([o for o, _ in starts]).reshape(-1, 3),
                      np.array([d for _, d in starts]).reshape(-1, 3))
    chains = []
    for h, (o2, k_out), face in zip(hits, starts, faces):
        if face < 0:
            continue
        x1, s1 = h["x"], h["s"]
        x2, n2, ng2, mat2, tri2 = mesh.surface(face, o2, k_out)
        seg = np.linalg.norm(x2 - x1)
        k2 = (x2 - x1) / seg
        eta = math.exp(-(2.0 * k * s1["sigma_h"] * s1["cos_in"]) ** 2)
        n1 = s1["n"]
        mirror = np.eye(3) - 2.0 * np.outer(n1, n1)        # M_1 about the plane of x_1
        chains.append({"x": x2, "x_star": mirror @ x2 + 2.0 * (n1 @ x1) * n1,
                       "mirror": mirror, "E": _reflect(h["E"], s1) * math.sqrt(eta),
                       "p_area": h["pdf"] * abs(k2 @ ng2) / (h["L0"] + seg) ** 2,
                       "tri": tri2, "s": _local(k2, n2, ng2, mat2, ctx["freq"])})
    return chains


def _emit(ctx, states) -> list:
    """``(C, X, X*)`` of the chains ending at these interactions whose
    connection to the transmitter holds (shadow rays cast together)."""
    c = ctx["c"]
    ok = []
    for st in states:
        s = st["s"]
        k_t = (c - st["x"]) / np.linalg.norm(c - st["x"])
        ok.append(s["n"] @ k_t > 0 and s["ng"] @ k_t > 0 and s["cos_in"] > 0)
    shadow = np.array([st["x"] + st["s"]["ng"] * RAY_EPSILON for st in states]).reshape(-1, 3)
    visible = ctx["mesh"].visible(shadow, c)
    return [(_coherent(ctx, st), st["x"], st["x_star"])
            for st, o, v in zip(states, ok, visible) if o and v]


def _local(k_in, n_sh, ng, mat, freq) -> dict:
    """Normals turned to face the ray, incidence cosine and slab coefficients."""
    n = -n_sh if k_in @ n_sh > 0 else n_sh
    cos_in = max(-(k_in @ n), 0.0)
    ng = ng if k_in @ ng < 0 else -ng
    eps = mat[0] - 1j * mat[1]
    sc = slab_coefficients(cos_in, eps, mat[5], freq, backend="numpy")
    return {"k_in": k_in, "n": n, "ng": ng, "cos_in": cos_in, "sigma_h": mat[2],
            "r_s": complex(sc.r_s), "r_p": complex(sc.r_p)}


def _coherent(ctx, st) -> complex:
    """Physical-optics field towards the Tx of the chain ending at ``st["x"]``."""
    c, k, Rm, s, x, x_star = ctx["c"], ctx["k"], ctx["Rm"], st["s"], st["x"], st["x_star"]
    k_t = (c - x) / np.linalg.norm(c - x)
    cos_t = s["n"] @ k_t
    e_t = _transverse(Rm @ ctx["ptx"].polarization_np(Rm.T @ -k_t).reshape(3), k_t)
    val = _reflect(st["E"], s) @ e_t
    eta_b = math.exp(-(k * s["sigma_h"] * (s["cos_in"] + cos_t)) ** 2)
    scale = 0.5 * (s["cos_in"] + cos_t) * math.sqrt(eta_b) / (4.0 * math.pi * ctx["n_est"])
    F = 1.0
    tri = st["tri"]
    if ctx["opts"].triangle_average:
        D2 = max(np.sum((tri[1] - tri[0]) ** 2), np.sum((tri[2] - tri[0]) ** 2),
                 np.sum((tri[2] - tri[1]) ** 2))
        near = min(np.linalg.norm(x_star - c), np.linalg.norm(x - c))
        if k * D2 / max(near, 1e-3) < 1.0:     # phase linear across the triangle
            u_rx = (x_star - c) / np.linalg.norm(x_star - c)
            u_tx = (x - c) / np.linalg.norm(x - c)
            F = _triangle_average(k * (st["mirror"].T @ u_rx + u_tx), tri, x)
    return 1j * val * scale * F / st["p_area"]


def _triangle_average(q, tri, x) -> complex:
    """``(1 / A) int_T exp(-j q . (y - x)) dA(y)`` = ``2 exp[z_0, z_1, z_2]``,
    the second divided difference of ``exp`` at ``z_i = -j q . (P_i - x)``:
    ``sum_i exp(z_i) / prod_{k != i} (z_i - z_k)`` for well separated nodes,
    else the corner entry of the exponential of the bidiagonal matrix of the
    nodes (shifted by their mean, which keeps the matrix small)."""
    z = -1j * np.array([q @ (p - x) for p in tri])
    gaps = [abs(z[0] - z[1]), abs(z[0] - z[2]), abs(z[1] - z[2])]
    if min(gaps) > 1e-2:
        dd = sum(np.exp(z[i]) / np.prod([z[i] - z[k] for k in range(3) if k != i])
                 for i in range(3))
        return complex(2.0 * dd)
    mean = z.mean()
    A = np.diag(z - mean) + np.diag([1.0, 1.0], 1)
    return complex(2.0 * np.exp(mean) * expm(A)[0, 2])


def _reflect(E, s):
    """Jones reflection ``r_s (E . s) s + r_p (E . p_in) p_out`` at the surface ``s``."""
    k_in, n = s["k_in"], s["n"]
    sv = np.cross(k_in, n)
    if np.linalg.norm(sv) > 1e-6:
        sv = sv / np.linalg.norm(sv)
    else:   # normal incidence: any s perpendicular to k_in (the solver's helper axis)
        helper = np.array([0.0, 0.0, 1.0]) if abs(k_in[2]) < 0.9 else np.array([1.0, 0, 0])
        sv = np.cross(k_in, helper)
        sv = sv / np.linalg.norm(sv)
    p_in = np.cross(sv, k_in)
    p_out = np.cross(sv, k_in - 2.0 * (k_in @ n) * n)
    return s["r_s"] * (E @ sv) * sv + s["r_p"] * (E @ p_in) * p_out


def _legs(emitted, tx, rx, Rm, ptx, prx):
    """``(a, tau, points)`` of the emitted paths, one Tx-Rx pair at a time."""
    T, R, P = len(tx), len(rx), len(emitted)
    a = np.zeros((T, R, P), complex)
    tau = np.zeros((T, R, P))
    for p, (C, X, X_rx) in enumerate(emitted):
        for i in range(T):
            d_t = np.linalg.norm(X - tx[i])
            g_t = math.sqrt(float(ptx.gain_np(Rm.T @ ((X - tx[i]) / d_t), _element(ptx, i))))
            for j in range(R):
                d_r = np.linalg.norm(X_rx - rx[j])
                g_r = math.sqrt(float(prx.gain_np(Rm.T @ ((X_rx - rx[j]) / d_r),
                                                  _element(prx, j))))
                a[i, j, p] = np.conj(C) * g_t / d_t * g_r / d_r
                tau[i, j, p] = (d_t + d_r) / SPEED_OF_LIGHT
    pts = np.array([e[1] for e in emitted]).reshape(-1, 3)
    return a, tau, pts


def _candidates(scene, opts, c):
    """The solver's candidate directions and densities (same sampler, same seed)."""
    pose = Pose.from_tensors(scene.position, scene.orientation)
    centre = mi.Point3f(*(float(v) for v in c))
    cands = RandomCone(opts).candidates(None, pose, centre, None)
    dirs = np.stack([np.asarray(cands.direction[i], np.float64) for i in range(3)], axis=1)
    return dirs, np.asarray(cands.pdf, np.float64)


def _check_subset(opts) -> None:
    bad = {"sampling": opts.sampling != "random", "coherent": not opts.coherent,
           "scattering": bool(opts.scattering), "diffraction": bool(opts.diffraction),
           "min_rel_power": opts.min_rel_power > 0, "max_depth": opts.max_depth > 2,
           "rr_depth": opts.rr_depth < opts.max_depth,
           "velocities": opts.velocities is not None,
           "radar_velocity": opts.radar_velocity is not None}
    named = [k for k, v in bad.items() if v]
    if named:
        raise ValueError(f"solve_basic covers coherent random-cone paths of depth <= 2 "
                         f"without roulette only; "
                         f"outside that subset: {named}")


def _pattern(spec):
    from ..radio_devices import make_pattern

    return make_pattern(spec)


def _element(pattern, index):
    """The element index a pattern with per-element parameters needs, else ``None``."""
    return index if pattern.n_elements > 1 else None


def _transverse(v, k):
    t = v - (v @ k) * k
    return t / np.linalg.norm(t)


def _np(t) -> np.ndarray:
    return np.asarray(dr.detach(t).array if isinstance(t, mi.TensorXf) else dr.detach(t),
                      dtype=np.float64)


def _point(a):
    a = np.asarray(a, np.float32).reshape(-1, 3)
    return mi.Point3f(mi.Float(a[:, 0]), mi.Float(a[:, 1]), mi.Float(a[:, 2]))


def _vector(a):
    a = np.asarray(a, np.float32).reshape(-1, 3)
    return mi.Vector3f(mi.Float(a[:, 0]), mi.Float(a[:, 1]), mi.Float(a[:, 2]))

"""Specular manifold sampling (SMS) on triangle meshes with smooth shading normals.

LiDAR meshes have triangles far smaller than the 3.9 mm wavelength, so the
image method (mirror the Tx across the plane of the triangle a ray happened to
hit) usually returns a point *outside* that triangle.  Following Zeltner,
Georgiev and Jakob, "Specular Manifold Sampling for Rendering High-Frequency
Caustics and Glints" (SIGGRAPH 2020), :func:`solve_specular` instead walks on
the mesh with Newton's method until the path ``a -> x -> b`` obeys the law of
reflection with respect to the interpolated *shading* normal ``n(x)``.

Constraint
----------
Inside one triangle with vertices ``p0, p1, p2`` and (unnormalised) vertex
normals ``n0, n1, n2`` a point is parameterised by its barycentrics
``(u, v)`` (Mitsuba's ``prim_uv`` convention, weights of ``p1`` and ``p2``)::

    x(u, v) = p0 + u e1 + v e2,            e1 = p1 - p0, e2 = p2 - p0
    n(u, v) = normalize(n0 + u (n1 - n0) + v (n2 - n0))
    wa = (a - x) / |a - x|,  wb = (b - x) / |b - x|,  h = normalize(wa + wb)
    s  = normalize(e1 - n (n . e1)),  t = n x s      (shading frame)
    C(u, v) = [s . h, t . h]

``C = 0`` iff ``h`` is parallel to ``n`` (for ``a``, ``b`` in front), i.e. the
reflection law holds; ``|C|`` is the sine of the angle between ``h`` and ``n``
(rad for small values) and does not depend on the choice of tangent frame.
The 2x2 Jacobian ``J = dC/d(u, v)`` is computed analytically
(:func:`_constraint`; checked against finite differences in the tests).

Walk (wavefront, vectorised over N queries)
-------------------------------------------
1. *Seed projection.*  Rays are cast from ``a`` and from ``b`` towards the
   seed, and from the seed along ``+-h`` (half-vector at the seed); of the
   hits the one nearest the seed starts the walk.  A seed from a hit traced
   from either endpoint is thus reproduced exactly, and an image-method
   point (which may lie off a curved surface, even beyond its silhouette) is
   snapped to the surface next to it.
2. *Newton step in the tangent plane.*  ``(du, dv) = -lambda J^-1 C`` gives the
   step ``dx = du e1 + dv e2`` in the plane of the current triangle (it may
   leave the triangle).  ``|dx|`` is clamped to ``step_limit`` (default: a
   quarter of the shorter distance to ``a`` or ``b``).
3. *Re-projection by ray casting.*  From ``x + dx + L ng`` a ray is cast along
   ``-ng`` (``ng`` the current triangle's geometric normal, oriented like the
   shading normal; ``L = |dx| +`` a small margin; ``maxt = 2 L``).  The
   closest hit gives the new object, triangle and barycentrics, so the walk
   crosses triangle (and object) boundaries.  Projecting along the normal of
   the chart in which the step was taken keeps the step's geometric meaning
   for any surface whose radius of curvature exceeds ``|dx| / 2`` and never
   jumps to a far-away surface; only if that ray misses (e.g. past a sharp
   crease) a second ray from ``a`` through ``x + dx`` is tried.
4. *Damping.*  A step is accepted only if ``|C|`` decreases strictly; then the
   damping factor ``lambda`` doubles (capped at 1).  Otherwise (no decrease,
   or both projection rays missed) the lane stays put and ``lambda`` halves;
   a lane whose ``lambda`` falls below ``2^-12`` or whose ``J`` is singular
   fails.
5. A lane converges when ``|C| < tol``.  Its solution is *valid* when it
   converged, ``a`` and ``b`` lie in front of the surface (positive side of
   both the shading normal and the oriented geometric normal), and shadow
   rays from ``x`` (offset along the normal by Mitsuba's ``RayEpsilon``
   scale) to ``a`` and to ``b`` are unoccluded.

The walk runs detached (no AD graph) as a Python loop over iterations with
one Dr.Jit kernel set per iteration; it stops early when no lane is active.
Geometry is read from the :class:`~sionna_mmir.scene.RadarScene` tensors
``vertex_positions`` / ``vertex_normals`` while rays are traced against the
Mitsuba meshes: call ``scene.sync()`` after changing the tensors.

Gradients (:func:`specular_point_ad`)
-------------------------------------
At convergence ``C(u0, v0; theta) = 0`` where ``theta`` collects the vertex
positions, vertex normals and the endpoints.  The implicit function theorem
gives the derivative of the solution ``(u*, v*)(theta)`` of ``C = 0``::

    d(u*, v*)/dtheta = -J^-1 dC/dtheta.

:func:`specular_point_ad` evaluates, inside the AD graph, one Newton step from
the detached solution with a detached Jacobian::

    (u*, v*) = (u0, v0) - detach(J)^-1 C(u0, v0; theta)

Its value is ``(u0, v0)`` plus the Newton correction ``-J^-1 C``, which is
``O(tol)`` and only moves the point closer to the exact root; its derivative
is exactly the IFT derivative above because ``u0, v0, J`` are constants (the
expression is first-order exact: differentiating ``C(u*(theta), theta) = 0``
gives the same linear system).  ``x = x(u*, v*; theta)`` then picks up both the motion of the
triangle's vertices at fixed barycentrics and the sliding of the specular
point on the triangle.

Path length remark: ``|a - x| + |x - b|`` is stationary in ``x`` along the
surface only where the shading normal equals the geometric normal (e.g. a
flat plate); there its gradient w.r.t. ``a`` is the unit vector
``(a - x) / |a - x|``.  With interpolated normals the reflection point is
generally *not* a stationary point of the path length, and the IFT term
``dL/dx dx/da`` does not vanish.

Shape mapping
-------------
Mitsuba 3.9 / Dr.Jit 1.5 store ``mi.ShapePtr`` arrays as registry ids
(``dr.reinterpret_array(mi.UInt32, ptr)`` gives them, 0 for null), and
``ptr == mi.ShapePtr(mesh)`` compares them lane by lane.  The solver maps the
hit ``ShapePtr`` to the index of the object in ``list(scene.mesh_objects)``
by that comparison (``_Tables.object_ids``); hits on shapes that are no RadarScene
object count as misses.
"""
from __future__ import annotations

from collections import namedtuple

import numpy as np

from ..errors import InputValueError
from ..utils.backend import init_backend

init_backend()

import drjit as dr  # noqa: E402  (after init_backend, on purpose)
import mitsuba as mi  # noqa: E402

__all__ = ["SpecularSolution", "solve_specular", "specular_point_ad", "stationary_phase",
           "object_names", "NO_OBJECT"]

#: ``object_id`` of lanes without a triangle.
NO_OBJECT = 0xFFFFFFFF
_MIN_DAMPING = 2.0 ** -12

SpecularSolution = namedtuple(
    "SpecularSolution",
    ["valid", "shape", "object_id", "prim_index", "bary", "position", "normal",
     "iterations", "error"])
SpecularSolution.__doc__ = """Result of :func:`solve_specular` (all detached, size N).

Fields other than ``valid`` are the walk's last state on invalid lanes.

Attributes
----------
valid : mi.Bool
    Converged, a and b in front, x visible from both.
shape : mi.ShapePtr
    The mesh holding x (null where no triangle).
object_id : mi.UInt32
    Index into ``list(scene.mesh_objects)`` (:data:`NO_OBJECT` where no
    triangle).
prim_index : mi.UInt32
    Triangle index within that mesh.
bary : mi.Point2f
    Barycentrics ``(b1, b2)``: ``x = (1-b1-b2) p0 + b1 p1 + b2 p2``.
position : mi.Point3f
    The reflection point x [m].
normal : mi.Vector3f
    Unit interpolated shading normal at x.
iterations : mi.UInt32
    Newton iterations (accepted + rejected) used.
error : mi.Float
    Final ``|C|`` (sine of the angle between h and n).
"""


# --------------------------------------------------------------------------
# inputs
# --------------------------------------------------------------------------
def _as_point3f(value, name: str) -> mi.Point3f:
    """``mi.Point3f`` from a Dr.Jit 3-vector, or an array-like of shape (3,) / (N, 3)."""
    if isinstance(value, (mi.Point3f, mi.Vector3f, mi.Normal3f, mi.ScalarPoint3f,
                          mi.ScalarVector3f)):
        return mi.Point3f(value)
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputValueError(f"{name}: expected mi.Point3f or an array of shape (N, 3), "
                              f"got {type(value).__name__}") from exc
    if arr.ndim == 1:
        arr = arr.reshape(1, -1)
    if arr.ndim != 2 or arr.shape[1] != 3 or arr.shape[0] == 0:
        raise InputValueError(f"{name}: expected shape (3,) or (N, 3), got {np.shape(value)}")
    arr = arr.astype(np.float32)
    return mi.Point3f(mi.Float(arr[:, 0]), mi.Float(arr[:, 1]), mi.Float(arr[:, 2]))


def _check_finite(p: mi.Point3f, name: str) -> None:
    bad = dr.any(~(dr.isfinite(p.x) & dr.isfinite(p.y) & dr.isfinite(p.z)))
    if bool(bad[0] if dr.width(bad) else bad):
        raise InputValueError(f"{name}: contains NaN or Inf")


def _broadcast_width(arrays: dict) -> int:
    widths = {k: dr.width(v) for k, v in arrays.items()}
    n = max(widths.values())
    bad = {k: w for k, w in widths.items() if w not in (1, n)}
    if bad or n == 0:
        raise InputValueError(f"inconsistent sizes {widths}: each must be 1 or N = {n} > 0")
    return n


def _check_scene(scene) -> list[str]:
    if not hasattr(scene, "mesh_objects") or not hasattr(scene, "mi_scene"):
        raise InputValueError(f"scene: expected a RadarScene, got {type(scene).__name__}")
    names = list(scene.mesh_objects)
    if not names:
        raise InputValueError("scene: has no mesh objects")
    return names


def object_names(scene) -> list[str]:
    """Object names in the order used by ``SpecularSolution.object_id``."""
    return list(scene.mesh_objects)


# --------------------------------------------------------------------------
# mesh access
# --------------------------------------------------------------------------
class _Tables:
    """Per-object faces (mi.UInt32), positions / normals (flat mi.Float), ShapePtr."""

    def __init__(self, scene, detach: bool):
        self.names = _check_scene(scene)
        self.faces, self.positions, self.normals, self.meshes = [], [], [], []
        for name in self.names:
            obj = scene.mesh_objects[name]
            self.faces.append(mi.UInt32(np.ascontiguousarray(obj.faces, dtype=np.uint32).ravel()))
            pos, nor = obj.vertex_positions.array, obj.vertex_normals.array
            if detach:
                pos, nor = dr.detach(pos), dr.detach(nor)
            self.positions.append(pos)
            self.normals.append(nor)
            self.meshes.append(scene.mesh(name))
        self.shape_table = mi.ShapePtr(self.meshes)

    def object_ids(self, shape: mi.ShapePtr) -> mi.UInt32:
        """Map hit shape pointers to object indices (:data:`NO_OBJECT` otherwise)."""
        out = mi.UInt32(NO_OBJECT)
        for k, mesh in enumerate(self.meshes):
            out = dr.select(shape == mi.ShapePtr(mesh), k, out)
        return out

    def shapes(self, obj_id: mi.UInt32) -> mi.ShapePtr:
        return dr.gather(mi.ShapePtr, self.shape_table, dr.select(obj_id == NO_OBJECT, 0, obj_id),
                         obj_id != NO_OBJECT)

    def triangle(self, obj_id: mi.UInt32, prim: mi.UInt32, active=True):
        """(p0, p1, p2, n0, n1, n2) of each lane's triangle (zeros where inactive)."""
        ps = [mi.Point3f(0.0) for _ in range(3)]
        ns = [mi.Vector3f(0.0) for _ in range(3)]
        single = len(self.names) == 1
        for k in range(len(self.names)):
            m = mi.Bool(active) & (obj_id == k)
            for j in range(3):
                vi = dr.gather(mi.UInt32, self.faces[k], prim * 3 + j, m)
                pj = dr.gather(mi.Point3f, self.positions[k], vi, m)
                nj = dr.gather(mi.Vector3f, self.normals[k], vi, m)
                if single:
                    ps[j], ns[j] = pj, nj
                else:
                    ps[j] = ps[j] + pj
                    ns[j] = ns[j] + nj
        return ps, ns


# --------------------------------------------------------------------------
# constraint
# --------------------------------------------------------------------------
def _constraint(ps, ns, u, v, a, b, jacobian: bool):
    """Half-vector constraint on one triangle chart.

    Returns ``(x, n, ng, C, J, la, lb)``: point, unit shading normal, unit
    geometric normal oriented like ``n``, ``C = (C0, C1)``, ``J`` as
    ``((dC0/du, dC0/dv), (dC1/du, dC1/dv))`` (or ``None``) and the distances
    to ``a`` and ``b``.  Works on AD and detached inputs alike.
    """
    p0, p1, p2 = ps
    n0, n1, n2 = ns
    e1, e2 = p1 - p0, p2 - p0
    dn1, dn2 = n1 - n0, n2 - n0
    x = p0 + e1 * u + e2 * v
    m = n0 + dn1 * u + dn2 * v
    inv_m = dr.rcp(dr.norm(m))
    n = m * inv_m
    da, db = a - x, b - x
    la, lb = dr.norm(da), dr.norm(db)
    wa, wb = da / la, db / lb
    hh = wa + wb
    lh = dr.norm(hh)
    h = hh / lh
    s_hat = e1 - n * dr.dot(n, e1)
    ls = dr.norm(s_hat)
    s = s_hat / ls
    t = dr.cross(n, s)
    c = (dr.dot(s, h), dr.dot(t, h))
    ng = dr.normalize(dr.cross(e1, e2))
    ng = dr.select(dr.dot(ng, n) < 0, -ng, ng)
    jac = None
    if jacobian:
        cols = []
        n_e1 = dr.dot(n, e1)
        for dx, dm in ((e1, dn1), (e2, dn2)):
            dn = (dm - n * dr.dot(n, dm)) * inv_m
            dwa = -(dx - wa * dr.dot(wa, dx)) / la
            dwb = -(dx - wb * dr.dot(wb, dx)) / lb
            dhh = dwa + dwb
            dh = (dhh - h * dr.dot(h, dhh)) / lh
            ds_hat = -(dn * n_e1 + n * dr.dot(dn, e1))
            ds = (ds_hat - s * dr.dot(s, ds_hat)) / ls
            dt = dr.cross(dn, s) + dr.cross(n, ds)
            cols.append((dr.dot(ds, h) + dr.dot(s, dh), dr.dot(dt, h) + dr.dot(t, dh)))
        jac = ((cols[0][0], cols[1][0]), (cols[0][1], cols[1][1]))
    return x, n, ng, c, jac, la, lb


def _solve2(jac, c):
    """``J^-1 c`` for a 2x2 ``J``; returns (r0, r1, det)."""
    (j00, j01), (j10, j11) = jac
    det = j00 * j11 - j01 * j10
    inv = dr.rcp(det)
    return (j11 * c[0] - j01 * c[1]) * inv, (j00 * c[1] - j10 * c[0]) * inv, det


def _cnorm(c):
    return dr.sqrt(c[0] * c[0] + c[1] * c[1])


def _scene_scale(p: mi.Point3f):
    return 1.0 + dr.maximum(dr.maximum(dr.abs(p.x), dr.abs(p.y)), dr.abs(p.z))


# --------------------------------------------------------------------------
# solver
# --------------------------------------------------------------------------
def _cast(scene, tables, o, d, maxt, active):
    ray = mi.Ray3f(o, d)
    ray.maxt = maxt
    pi = scene.mi_scene.ray_intersect_preliminary(ray, coherent=False, active=active)
    obj = tables.object_ids(pi.shape)
    hit = active & pi.is_valid() & (obj != NO_OBJECT)
    return hit, obj, pi.prim_index, pi.prim_uv, pi.t


def _project_seed(scene, tables, a, b, seed):
    """Snap seeds onto the mesh: the hit nearest the seed among four rays.

    Rays ``a -> seed`` and ``b -> seed`` reproduce a seed traced from either
    endpoint exactly; rays from the seed along ``+h`` and ``-h`` (``h`` the
    half-vector of ``a`` and ``b`` seen from the seed, i.e. the normal a
    reflector would need there) catch seeds off the surface that the endpoint
    rays miss, e.g. image-method points near a silhouette.
    """
    wa, wb = dr.normalize(a - seed), dr.normalize(b - seed)
    h = dr.normalize(wa + wb)
    h = dr.select(dr.isfinite(h.x) & dr.isfinite(h.y) & dr.isfinite(h.z), h, mi.Vector3f(0, 0, 1))
    best = None
    for src, d in ((a, seed - a), (b, seed - b), (seed, h), (seed, -h)):
        dist = dr.norm(d)
        ok = dist > 0
        d = d / dist
        hit, obj, prim, uv, t = _cast(scene, tables, src, d, dr.inf, ok)
        gap = dr.select(hit, dr.norm(src + d * t - seed), dr.inf)
        if best is None:
            best = [hit, obj, prim, uv, gap]
        else:
            take = hit & (gap < best[4])
            best = [best[0] | hit, dr.select(take, obj, best[1]), dr.select(take, prim, best[2]),
                    dr.select(take, uv, best[3]), dr.select(take, gap, best[4])]
    return best[0], best[1], best[2], best[3]


def solve_specular(scene, a, b, seed, max_iter: int = 30, tol: float = 1e-5,
                   step_limit=None, trace_a: bool = True) -> SpecularSolution:
    """Find reflection points ``x`` on the scene's meshes for ``a -> x -> b``.

    Runs without AD (see the module docstring).  Returns a
    :class:`SpecularSolution` of size N (sizes 1 broadcast); NaN / Inf or
    inconsistently sized inputs raise ``InputValueError``.

    Parameters
    ----------
    scene : RadarScene
        The scene (tensors synced).
    a, b, seed : mi.Point3f or array_like
        Path endpoints; start points on / near the surface; (N, 3) / (3,) [m].
    max_iter, tol : int, float, optional
        Newton iterations at most (accepted + rejected); convergence threshold
        on ``|C|`` (~ angle between h and n) [rad].
    step_limit : float or mi.Float, optional
        Largest step [m]; default a quarter of the shorter distance from x to a or b.
    trace_a : bool, optional
        Trace the shadow ray ``x -> a`` (off when ``a`` is a virtual source,
        the image of a point seen through mirrors).
    """
    tables = _Tables(scene, detach=True)
    if int(max_iter) < 0:
        raise InputValueError(f"max_iter must be >= 0, got {max_iter!r}")
    if not np.isfinite(float(tol)) or float(tol) <= 0:
        raise InputValueError(f"tol must be a positive finite number, got {tol!r}")
    if isinstance(step_limit, (int, float)) and not float(step_limit) > 0:
        raise InputValueError(f"step_limit must be > 0, got {step_limit!r}")
    pts = {"a": _as_point3f(a, "a"), "b": _as_point3f(b, "b"), "seed": _as_point3f(seed, "seed")}
    for name, p in pts.items():
        _check_finite(p, name)
    n = _broadcast_width(pts)

    with dr.suspend_grad():
        a = dr.detach(pts["a"])
        b = dr.detach(pts["b"])
        seed = dr.detach(pts["seed"])
        if dr.width(a) != n:
            a = dr.gather(mi.Point3f, a, dr.zeros(mi.UInt32, n))
        if dr.width(b) != n:
            b = dr.gather(mi.Point3f, b, dr.zeros(mi.UInt32, n))
        if dr.width(seed) != n:
            seed = dr.gather(mi.Point3f, seed, dr.zeros(mi.UInt32, n))
        hit, obj, prim, uv = _project_seed(scene, tables, a, b, seed)
        obj = dr.select(hit, obj, NO_OBJECT)
        prim = dr.select(hit, prim, 0)
        u = dr.select(hit, uv.x, 0.0)
        v = dr.select(hit, uv.y, 0.0)

        def evaluate(obj_, prim_, u_, v_, active):
            ps, ns = tables.triangle(obj_, prim_, active)
            return ps, _constraint(ps, ns, u_, v_, a, b, jacobian=True)

        ps, (x, nrm, ng, c, jac, la, lb) = evaluate(obj, prim, u, v, hit)
        err = dr.select(hit, _cnorm(c), dr.inf)
        failed = ~hit | ~dr.isfinite(err)
        damping = dr.full(mi.Float, 1.0, n)
        iterations = dr.zeros(mi.UInt32, n)
        state = [obj, prim, u, v, x, nrm, ng, c, jac, err, la, lb, ps]
        dr.eval(state, failed, damping, iterations)

        for _ in range(int(max_iter)):
            obj, prim, u, v, x, nrm, ng, c, jac, err, la, lb, ps = state
            active = ~failed & (err >= tol)
            if not bool(dr.any(active)[0]):
                break
            du, dv, det = _solve2(jac, c)
            singular = active & ~(dr.isfinite(du) & dr.isfinite(dv) & (dr.abs(det) > 0))
            failed |= singular
            active &= ~singular
            e1, e2 = ps[1] - ps[0], ps[2] - ps[0]
            dx = -(e1 * du + e2 * dv) * damping
            ldx = dr.norm(dx)
            limit = 0.25 * dr.minimum(la, lb) if step_limit is None else mi.Float(step_limit)
            dx = dx * dr.select(ldx > limit, limit / ldx, 1.0)
            ldx = dr.minimum(ldx, limit)
            xc = x + dx
            margin = 10.0 * mi.math.RayEpsilon * _scene_scale(xc)
            lift = ldx + margin
            hit1, obj1, prim1, uv1, _ = _cast(scene, tables, xc + ng * lift, -ng, 2.0 * lift,
                                              active)
            retry = active & ~hit1
            dxa = xc - a
            hit2, obj2, prim2, uv2, _ = _cast(scene, tables, a, dr.normalize(dxa), dr.inf, retry)
            hitc = hit1 | hit2
            objc = dr.select(hit1, obj1, obj2)
            primc = dr.select(hit1, prim1, prim2)
            uvc = dr.select(hit1, uv1, uv2)
            psc, (xc2, nc, ngc, cc, jc, lac, lbc) = evaluate(objc, primc, uvc.x, uvc.y, hitc)
            errc = _cnorm(cc)
            accept = hitc & (errc < err)
            iterations += dr.select(active, 1, 0)
            damping = dr.select(accept, dr.minimum(1.0, 2.0 * damping),
                                dr.select(active, 0.5 * damping, damping))
            failed |= active & ~accept & (damping < _MIN_DAMPING)
            new = [objc, primc, uvc.x, uvc.y, xc2, nc, ngc, cc, jc, errc, lac, lbc, psc]
            state = [_select_tree(accept, nw, old) for nw, old in zip(new, state)]
            dr.eval(state, failed, damping, iterations)

        obj, prim, u, v, x, nrm, ng, c, jac, err, la, lb, ps = state
        converged = ~failed & (err < tol) & (obj != NO_OBJECT)
        da, db = a - x, b - x
        front = ((dr.dot(da, nrm) > 0) & (dr.dot(db, nrm) > 0)
                 & (dr.dot(da, ng) > 0) & (dr.dot(db, ng) > 0))
        check = converged & front
        valid = check & _visible(scene, x, ng, (a, b) if trace_a else (b,), check)
        sol = SpecularSolution(
            valid=valid, shape=tables.shapes(obj), object_id=obj, prim_index=mi.UInt32(prim),
            bary=mi.Point2f(u, v), position=mi.Point3f(x), normal=mi.Vector3f(nrm),
            iterations=iterations, error=dr.select(dr.isfinite(err), err, dr.inf))
        dr.eval(sol)
    return sol


def _visible(scene, x, ng, targets, check):
    """Shadow rays from ``x`` (offset along ``ng`` by Mitsuba's ``RayEpsilon``
    scale) to every target unoccluded."""
    o = x + ng * (mi.math.RayEpsilon * _scene_scale(x))
    visible = mi.Bool(check)
    for target in targets:
        d = target - o
        dist = dr.norm(d)
        ray = mi.Ray3f(o, d / dist)
        ray.maxt = dist * (1.0 - mi.math.ShadowEpsilon)
        visible &= ~scene.mi_scene.ray_test(ray, check)
    return visible


def _select_tree(mask, new, old):
    if isinstance(new, (tuple, list)):
        return type(new)(_select_tree(mask, n_, o_) for n_, o_ in zip(new, old))
    return dr.select(mask, new, old)


# --------------------------------------------------------------------------
# AD re-evaluation
# --------------------------------------------------------------------------
def _ift_point(scene, solution, a, b):
    """``(valid, ps, ns, u, v, a_s, b_s)``: the IFT barycentrics of
    :func:`specular_point_ad` with the AD triangle and safe endpoints."""
    tables = _Tables(scene, detach=False)
    a = _as_point3f(a, "a")
    b = _as_point3f(b, "b")
    valid = mi.Bool(solution.valid)
    obj = dr.select(valid, solution.object_id, 0)
    prim = dr.select(valid, solution.prim_index, 0)
    u0 = dr.detach(mi.Float(solution.bary.x))
    v0 = dr.detach(mi.Float(solution.bary.y))
    ps, ns = tables.triangle(obj, prim)
    # Invalid lanes get harmless finite endpoints (1 m off the triangle), so no
    # NaN can leak into the backward pass through the masked-out branch.
    with dr.suspend_grad():
        ps_d = [dr.detach(p) for p in ps]
        ns_d = [dr.detach(q) for q in ns]
        e1_d, e2_d = ps_d[1] - ps_d[0], ps_d[2] - ps_d[0]
        x_d = ps_d[0] + e1_d * u0 + e2_d * v0
        ng_d = dr.normalize(dr.cross(e1_d, e2_d))
        safe_a = x_d + ng_d
        safe_b = x_d + ng_d + dr.normalize(e1_d)
    a_s = dr.select(valid, a, safe_a)
    b_s = dr.select(valid, b, safe_b)
    with dr.suspend_grad():
        _, _, _, _, jac, _, _ = _constraint(ps_d, ns_d, u0, v0, dr.detach(a_s), dr.detach(b_s),
                                            jacobian=True)
        jac = tuple(tuple(dr.detach(e) for e in row) for row in jac)
    _, _, _, c, _, _, _ = _constraint(ps, ns, u0, v0, a_s, b_s, jacobian=False)
    du, dv, _ = _solve2(jac, c)
    return valid, ps, ns, u0 - du, v0 - dv, a_s, b_s


def specular_point_ad(scene, solution: SpecularSolution, a, b):
    """Reflection point and shading normal, differentiable by the IFT.

    One Newton step from the detached converged barycentrics with the
    detached Jacobian, ``(u, v) = (u0, v0) - J^-1 C(u0, v0; theta)``, then
    ``x = x(u, v; theta)``: value = the solution, derivative = the implicit
    function theorem's ``-J^-1 dC/dtheta`` (see the module docstring).

    Parameters
    ----------
    scene : RadarScene
        The scene solved on; its ``vertex_positions`` / ``vertex_normals``
        tensors may have gradients enabled.
    solution : SpecularSolution
        From :func:`solve_specular`.
    a, b : mi.Point3f
        The endpoints used there (may carry gradients).

    Returns
    -------
    x : mi.Point3f
        Reflection point [m]; zero on invalid lanes.
    n : mi.Vector3f
        Unit shading normal; zero on invalid lanes.
    """
    valid, ps, ns, u, v, _, _ = _ift_point(scene, solution, a, b)
    p0, p1, p2 = ps
    n0, n1, n2 = ns
    x = p0 + (p1 - p0) * u + (p2 - p0) * v
    nrm = dr.normalize(n0 + (n1 - n0) * u + (n2 - n0) * v)
    return dr.select(valid, x, 0.0), dr.select(valid, nrm, 0.0)


def stationary_phase(scene, solution: SpecularSolution, a, b, k_wave: float):
    r"""Specular point and the stationary-phase area of its reflection (AD).

    The physical-optics integral of ``exp(-j k phi(y))``, ``phi(y) = |y - a|
    + |y - b|``, over the smooth surface that the interpolated normals
    describe is, near a non-degenerate stationary point ``x`` (second-order
    stationary phase; Born & Wolf, *Principles of Optics*, App. III),

    .. math::

        \int e^{-j k \phi} dA \approx e^{-j k \phi(x)}
        \frac{2 \pi}{k \sqrt{|\det H|}} e^{-j \pi\, \mathrm{sig}(H) / 4},

    ``H`` the Hessian of ``phi`` in orthonormal tangent coordinates and
    ``sig`` its signature.  On the manifold walk's chart the tangential
    gradient of ``phi`` is ``-|w_a + w_b| C`` (``C`` the half-vector
    constraint, zero at ``x``), so ``H = -|w_a + w_b| J M^{-1}`` with ``J =
    dC/d(u, v)`` and ``M`` the projection of the triangle's edges on the
    shading frame ``(s, t)``; this is the generalised geometric term of
    Zeltner et al. (2020, Sec. 4) written for a coherent field.

    Parameters
    ----------
    scene : RadarScene
        The scene solved on (tensors may carry gradients).
    solution : SpecularSolution
        From :func:`solve_specular`.
    a, b : mi.Point3f
        The endpoints (may carry gradients).
    k_wave : float
        Wavenumber ``2 pi / lambda`` [rad/m].

    Returns
    -------
    x : mi.Point3f
        Specular point [m] (IFT derivative, :func:`specular_point_ad`).
    u, v : mi.Float
        Its barycentrics (AD).
    area_re, area_im : mi.Float
        ``2 pi / (k sqrt|det H|) exp(-j pi sig(H) / 4)`` [m^2]; zero on
        invalid lanes.
    """
    valid, ps, ns, u, v, a_s, b_s = _ift_point(scene, solution, a, b)
    x, n, _, _, jac, la, lb = _constraint(ps, ns, u, v, a_s, b_s, jacobian=True)
    lh = dr.norm((a_s - x) / la + (b_s - x) / lb)
    e1, e2 = ps[1] - ps[0], ps[2] - ps[0]
    s = dr.normalize(e1 - n * dr.dot(n, e1))
    t = dr.cross(n, s)
    m00, m01, m10, m11 = dr.dot(s, e1), dr.dot(s, e2), dr.dot(t, e1), dr.dot(t, e2)
    det_m = m00 * m11 - m01 * m10
    (j00, j01), (j10, j11) = jac
    # H = -lh J M^-1 (M^-1 = [[m11, -m01], [-m10, m00]] / det_m)
    h00 = -lh * (j00 * m11 - j01 * m10) / det_m
    h01 = -lh * (-j00 * m01 + j01 * m00) / det_m
    h10 = -lh * (j10 * m11 - j11 * m10) / det_m
    h11 = -lh * (-j10 * m01 + j11 * m00) / det_m
    det_h = h00 * h11 - h01 * h10
    mag = 2.0 * np.pi / (k_wave * dr.sqrt(dr.maximum(dr.abs(det_h), 1e-30)))
    # signature: +2 (minimum) -> -j, -2 (maximum) -> +j, 0 (saddle) -> 1
    saddle = dr.detach(det_h) < 0
    minimum = dr.detach(h00 + h11) > 0
    area_re = dr.select(saddle, mag, 0.0)
    area_im = dr.select(saddle, 0.0, dr.select(minimum, -mag, mag))
    ok = valid & dr.isfinite(dr.detach(mag))
    return (dr.select(valid, x, 0.0), u, v, dr.select(ok, area_re, 0.0),
            dr.select(ok, area_im, 0.0))

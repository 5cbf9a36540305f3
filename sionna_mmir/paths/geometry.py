"""Differentiable surface interactions rebuilt from triangle index + barycentrics.

Rays are traced by Mitsuba *outside* the AD graph (``ray_intersect_preliminary``
under ``dr.suspend_grad``); only the discrete hit -- which object, which
triangle, which barycentric coordinates -- is kept.  :class:`SceneGeometry`
then rebuilds every quantity the estimator needs *inside* the AD graph from
the scene's differentiable per-vertex tensors:

position
    ``x = (1-u-v) p0 + u p1 + v p2`` (Mitsuba's ``prim_uv``)
shading normal
    ``normalize((1-u-v) n0 + u n1 + v n2)``
geometric normal
    ``normalize((p1-p0) x (p2-p0))``
area ratio
    ``A(theta) / detach(A)``: the change of the area element of
    the barycentric parameterisation (value 1); multiplying a
    sample's weight by it makes the area-measure estimator exact
    under vertex motion (Jacobian of ``x(u, v; theta)``)
material
    the six per-vertex parameters interpolated barycentrically
    (``[eps', eps'', sigma_h, l_c, tau, d]``)

A surface point is thus *attached* to the material (fixed barycentrics) when
vertices move: gradients of positions, normals and materials reach the three
vertices of each hit triangle, and path-length gradients are exact to first
order at specular vertices (Fermat: the tangential derivative vanishes).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..utils.backend import init_backend

init_backend()

import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402


@dataclass
class Interaction:
    """One differentiable surface interaction per lane (all ``mi.*`` arrays).

    Parameters
    ----------
    valid : mi.Bool
        a triangle was hit
    obj : mi.UInt32
        object index (order of ``SceneGeometry.names``)
    face : mi.UInt32
        global face index
    p : mi.Point3f
        hit position [m] (AD)
    n : mi.Vector3f
        unit shading normal (AD)
    ng : mi.Vector3f
        unit geometric normal (AD)
    area_ratio : mi.Float
        ``A / detach(A)`` of the hit triangle (AD)
    mat : list of mi.Float
        the six materials ``eps', eps'', sigma_h, l_c, tau, d``
    tri : tuple, optional
        the hit triangle's vertices ``(P0, P1, P2)`` (AD)
    """

    valid: object
    obj: object
    face: object
    p: object
    n: object
    ng: object
    area_ratio: object
    mat: list
    tri: tuple = ()


class Tape:
    """Frozen detached values of a Monte Carlo estimator (record, then replay).

    The estimator divides by sampling densities and makes discrete choices
    that are *detached* from AD (pdfs, areas of hit triangles at sampling
    time, Russian-roulette probabilities, visibility).  Recording them on the
    first call and replaying them later keeps the estimator a smooth function
    of the scene parameters -- exactly the function whose gradient AD computes
    -- which is what a finite-difference check or a frozen-sample optimiser
    needs.
    """

    def __init__(self, values: list | None = None):
        self.replaying = values is not None
        self.values = list(values) if values is not None else []
        self._pos = 0

    def freeze(self, x):
        """Detached ``x`` on record; the recorded value on replay."""
        if self.replaying:
            if self._pos >= len(self.values):
                raise RuntimeError("Tape exhausted: replay with the same solver options")
            out = self.values[self._pos]
            self._pos += 1
            return out
        out = dr.detach(x)
        dr.schedule(out)      # stored with the next evaluation, not recomputed by every reader
        self.values.append(out)
        return out

    def freeze_call(self, fn, *args):
        """``freeze(fn(*args))``; on replay ``fn`` is not called (e.g. a shadow ray)."""
        return self.freeze(None if self.replaying else fn(*args))


class SceneGeometry:
    """Global (all objects concatenated) differentiable mesh arrays of a scene.

    Build a new instance after changing the scene's tensors (it concatenates
    them inside the AD graph, so gradients flow back to each object's
    ``vertex_positions`` / ``vertex_normals`` / ``vertex_materials``).

    Parameters
    ----------
    scene : RadarScene
        The scene (:class:`~sionna_mmir.scene.RadarScene`).
    """

    def __init__(self, scene):
        self.scene = scene
        self.names = list(scene.mesh_objects)
        objs = [scene.mesh_objects[n] for n in self.names]
        (self.face_offset, self.faces, self.num_faces, self._shape_table,
         self._face_offset) = _static_tables(scene, self.names, objs)
        self.positions = dr.concat([o.vertex_positions.array for o in objs])
        self.normals = dr.concat([o.vertex_normals.array for o in objs])
        self.materials = dr.concat([o.vertex_materials.array for o in objs])
        #: recorded hits (list) when recording, or a list to replay (popped in order)
        self.record: list | None = None
        self.replay: list | None = None

    def validate(self) -> None:
        """Raise ``InputValueError`` for NaN/Inf tensors or unphysical materials.

        Bounds: ``eps' >= 1``, ``eps'' >= 0``, ``sigma_h >= 0``, ``l_c > 0``,
        ``0 <= tau <= 1``, ``d >= 0``; shading normals must be non-zero.

        A tensor that passed is not checked again while it is unchanged: each
        object remembers the Dr.Jit variable (index, shape; the variable is
        held, so its index cannot be reused) of every tensor that passed.
        Assigning a new tensor, or updating one in place through Dr.Jit
        (``t[...] = x``, ``dr.scatter``: a new variable), makes the next call
        check it again.
        """
        from ..errors import InputValueError

        pending = []
        for name in self.names:
            obj = self.scene.mesh_objects[name]
            passed = obj.__dict__.setdefault("_validated", {})
            tokens = {key: _token(getattr(obj, key))
                      for key in ("vertex_positions", "vertex_normals", "vertex_materials")}
            used = getattr(obj, "_referenced", None)
            if used is None or used[0] is not obj.faces:   # faces never change in place
                used = obj._referenced = (obj.faces, np.unique(obj.faces))
            tokens["vertex_normals"] += (used[0],)          # the zero-normal check reads faces
            todo = [key for key, tok in tokens.items() if not _same(passed.get(key), tok)]
            if todo:
                pending.append((name, passed, tokens, todo, used))
        # one kernel for every tensor to check (e.g. each object's reparameterised
        # materials), not one per object and tensor
        if pending:              # (dr.eval() without arguments would flush everything queued)
            dr.eval(*[tokens[key][0] for _, _, tokens, todo, _ in pending for key in todo])
        for name, passed, tokens, todo, used in pending:
            arrays = {key: np.asarray(tokens[key][0]) for key in todo}
            for key in todo:
                a = arrays[key]
                if not np.isfinite(a).all():
                    bad = np.flatnonzero(~np.isfinite(a).all(axis=-1))[:5].tolist()
                    raise InputValueError(f"object {name!r}: {key} holds NaN/Inf (vertices {bad})")
            if "vertex_normals" in arrays:
                n = arrays["vertex_normals"][used[1]]
                if (np.linalg.norm(n, axis=1) < 1e-12).any():
                    raise InputValueError(f"object {name!r}: zero-length vertex normals")
            if "vertex_materials" in arrays:
                m = arrays["vertex_materials"]
                checks = ((m[:, 0] < 1.0, "eps_real < 1"), (m[:, 1] < 0.0, "eps_imag < 0"),
                          (m[:, 2] < 0.0, "sigma_h < 0"), (m[:, 3] <= 0.0, "l_c <= 0"),
                          ((m[:, 4] < 0.0) | (m[:, 4] > 1.0), "tau outside [0, 1]"),
                          (m[:, 5] < 0.0, "thickness d < 0"))
                for mask, what in checks:
                    if mask.any():
                        raise InputValueError(f"object {name!r}: vertex materials out of physical "
                                              f"bounds ({what}) at vertices "
                                              f"{np.flatnonzero(mask)[:5].tolist()}")
            for key in todo:
                passed[key] = tokens[key]

    # ------------------------------------------------------------------ tracing
    def trace(self, origin, direction, active=True):
        """Trace rays (no AD); returns ``(valid, obj, face, u, v)`` detached.

        ``origin`` ``mi.Point3f`` [m], ``direction`` ``mi.Vector3f`` (unit).
        With :attr:`replay` set, returns the next recorded result instead of
        tracing (frozen samples: the discrete path decisions of an earlier call).
        The outputs are evaluated here (one kernel), so a recorded result never
        re-runs the tracing against a scene whose geometry changed since.
        """
        if self.replay is not None:
            if not self.replay:
                raise RuntimeError("SceneGeometry.trace: replay exhausted (different options?)")
            return self.replay.pop(0)
        out = self._trace(origin, direction, active)
        if self.record is not None:
            self.record.append(out)
        return out

    def _trace(self, origin, direction, active):
        with dr.suspend_grad():
            ray = mi.Ray3f(dr.detach(origin), dr.detach(direction))
            pi = self.scene.mi_scene.ray_intersect_preliminary(ray, coherent=False,
                                                               active=mi.Bool(active))
            valid = pi.is_valid() & mi.Bool(active)
            sid = dr.reinterpret_array(mi.UInt32, pi.shape)
            obj = dr.gather(mi.UInt32, self._shape_table, sid, valid)
            valid &= obj != 0xFFFFFFFF
            face = dr.gather(mi.UInt32, self._face_offset, obj, valid) + pi.prim_index
            u = mi.Float(dr.select(valid, pi.prim_uv.x, 0.0))
            v = mi.Float(dr.select(valid, pi.prim_uv.y, 0.0))
            # one kernel for all five outputs: evaluated one by one (compress,
            # gathers), each would re-run the ray tracing and everything upstream
            dr.eval(valid, obj, face, u, v)
            return valid, obj, face, u, v

    def visible(self, a, b, active=True):
        """``mi.Bool``: segment ``a -> b`` unobstructed (1 mm margins), no AD."""
        with dr.suspend_grad():
            a, b = dr.detach(a), dr.detach(b)
            d = b - a
            dist = dr.norm(d)
            ray = mi.Ray3f(a, d / dr.maximum(dist, 1e-12))
            ray.maxt = dr.maximum(dist - 2e-3, 0.0)
            ray.o = ray.o + ray.d * 1e-3
            out = ~self.scene.mi_scene.ray_test(ray, active=mi.Bool(active))
            dr.schedule(out)      # evaluated with the next trace (one kernel)
            return out

    # --------------------------------------------------------------- AD rebuild
    def _vertex(self, arr, width, idx, k, active):
        return [dr.gather(mi.Float, arr, idx * width + c, active) for c in range(k)]

    def interaction(self, valid, obj, face, u, v, tape: Tape | None = None) -> Interaction:
        """Rebuild the interaction inside AD from ``(face, u, v)``.

        ``tape`` freezes the triangle area at sampling time (the denominator
        of ``area_ratio``).
        """
        i = [dr.gather(mi.UInt32, self.faces, face * 3 + c, valid) for c in range(3)]
        w0, w1, w2 = 1.0 - u - v, u, v
        P = [mi.Point3f(*self._vertex(self.positions, 3, i[c], 3, valid)) for c in range(3)]
        N = [mi.Vector3f(*self._vertex(self.normals, 3, i[c], 3, valid)) for c in range(3)]
        M = [self._vertex(self.materials, 6, i[c], 6, valid) for c in range(3)]
        p = P[0] * w0 + P[1] * w1 + P[2] * w2
        cr = dr.cross(P[1] - P[0], P[2] - P[0])
        area = dr.norm(cr)
        ng = cr / dr.maximum(area, 1e-20)
        n = dr.normalize(N[0] * w0 + N[1] * w1 + N[2] * w2)
        mat = [M[0][c] * w0 + M[1][c] * w1 + M[2][c] * w2 for c in range(6)]
        area0 = tape.freeze(area) if tape is not None else dr.detach(area)
        ratio = area / dr.maximum(area0, 1e-20)
        return Interaction(valid=valid, obj=obj, face=face, p=p, n=n, ng=ng,
                           area_ratio=ratio, mat=mat, tri=tuple(P))


def _token(t):
    """``(detached tensor, JIT variable index, shape)`` of a scene tensor.

    Holding the detached tensor keeps its variable alive, so an equal index
    later means the same (unchanged) variable.  Dr.Jit never updates a
    variable that has other references in place (``t[...] = x`` and
    ``dr.scatter`` give the tensor a new variable).
    """
    d = dr.detach(t)
    return d, d.array.index, tuple(d.shape)


def _same(old, new) -> bool:
    return (old is not None and len(old) == len(new) and old[1] == new[1] and old[2] == new[2]
            and all(a is b for a, b in zip(old[3:], new[3:])))


def _static_tables(scene, names, objs):
    """Face and shape tables of ``scene`` that do not depend on the tensors.

    ``(face_offset [numpy], faces [mi.UInt32, 3 F], F, shape table, face offsets
    [mi.UInt32])``, built once and kept on the scene while the objects, their
    face arrays (never changed in place), vertex counts and Mitsuba meshes
    stay the same.
    """
    meshes = [scene.mesh(n) for n in names]
    key = (list(names), [o.faces for o in objs], [int(o.vertex_positions.shape[0]) for o in objs],
           meshes)
    cached = getattr(scene, "_mmir_geometry_tables", None)
    if cached is not None:
        k = cached[0]
        if (k[0] == key[0] and k[2] == key[2] and all(a is b for a, b in zip(k[1], key[1]))
                and all(a is b for a, b in zip(k[3], key[3]))):
            return cached[1]
    v_off = np.cumsum([0] + key[2])
    f_off = np.cumsum([0] + [len(o.faces) for o in objs])
    faces = np.concatenate([o.faces + v_off[i] for i, o in enumerate(objs)]).astype(np.uint32)
    # Mitsuba shape registry id -> object index
    ids = [int(dr.reinterpret_array(mi.UInt32, mi.ShapePtr(m))[0]) for m in meshes]
    table = np.full(max(ids) + 1, 0xFFFFFFFF, dtype=np.uint32)
    for i, sid in enumerate(ids):
        table[sid] = i
    tables = (f_off, mi.UInt32(faces.ravel()), len(faces), mi.UInt32(table),
              mi.UInt32(f_off[:-1].astype(np.uint32)))
    dr.eval(tables[1], tables[3], tables[4])
    scene._mmir_geometry_tables = (key, tables)
    return tables

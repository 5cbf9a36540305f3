"""0005 (no patch): limits of reverse-mode AD in PathSolver that are by design.

Same floor as 0001 (at z = h), two observations:

1. ``loop_mode="symbolic"`` (the default): ``dr.backward`` through the
   solver raises ``RuntimeError: LoopOp::backward(): reverse-mode
   differentiation of this loop requires a 'max_iterations' hint``.
   ``loop_mode="evaluated"`` differentiates.  (With Dr.Jit 1.5.0 on the LLVM
   backend, a process that ran the solver in symbolic mode on grad-enabled
   geometry also crashes with SIGSEGV at interpreter exit, so this part runs
   in a child process.)
2. Diffuse reflections (``diffuse_reflection=True``, scattering coefficient
   0.7): the diffuse vertices come from the shoot-and-bounce candidates,
   which ``SampleData.insert`` / ``PathsBuffer.detach_geometry`` detach, so
   ``d(sum of delays)/dh`` is exactly 0 although every vertex lies on the
   moving floor.

``--expect bug`` expects both limitations (stock 2.2.0, and also with the
patches of this folder, which leave them alone).
"""
from __future__ import annotations

import os
import subprocess
import sys

import numpy as np

from _common import report, setup

args, rt = setup(__doc__.splitlines()[0])
import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402

V = np.array([[-10, -10, 0], [10, -10, 0], [10, 10, 0], [-10, 10, 0]], np.float32)
F = np.array([[0, 1, 2], [0, 2, 3]], np.uint32)
mat = rt.RadioMaterial("floor-mat", relative_permittivity=5.0, conductivity=0.1,
                       thickness=0.3, scattering_coefficient=0.7)
mesh = mi.Mesh("floor", len(V), len(F), has_vertex_normals=False)
mp = mi.traverse(mesh)
mp["vertex_positions"] = mi.Float(V.ravel())
mp["faces"] = mi.UInt32(F.ravel())
mp.update()
mesh.set_bsdf(mat)
scene = rt.Scene(mi.load_dict({"type": "scene", "floor": mesh}, optimize=False))
scene.tx_array = rt.PlanarArray(num_rows=1, num_cols=1, pattern="iso", polarization="V")
scene.rx_array = scene.tx_array
scene.add(rt.Transmitter("tx", position=[-2.0, 0.3, 1.5]))
scene.add(rt.Receiver("rx", position=[3.0, -0.4, 1.0]))
params = mi.traverse(scene.mi_scene)
key = next(k for k in params.keys() if k.endswith("vertex_positions"))
base = mi.Float(V.ravel())
zmask = mi.Float(np.tile([0.0, 0.0, 1.0], len(V)).astype(np.float32))


def attached_height():
    h = mi.Float(0.0)
    dr.enable_grad(h)
    params[key] = base + zmask * h
    params.update()
    return h


# 1. symbolic loops (child process: see the module docstring)
if os.environ.get("SIONNA_REPRO_0005_CHILD") == "symbolic":
    solver = rt.PathSolver()
    h = attached_height()
    paths = solver(scene, max_depth=1, los=False)
    try:
        dr.backward(dr.sum(dr.square(paths.a[0].array) + dr.square(paths.a[1].array)))
        print(f"SYMBOLIC differentiated (d|a|^2/dh = {h.grad[0]:.3e})", flush=True)
    except RuntimeError as e:
        print(f"SYMBOLIC raised RuntimeError: {str(e)[:90]}...", flush=True)
    sys.exit(0)

child = subprocess.run([sys.executable, os.path.abspath(__file__), "--expect", args.expect],
                       env=dict(os.environ, SIONNA_REPRO_0005_CHILD="symbolic"),
                       capture_output=True, text=True, timeout=300)
lines = [ln for ln in child.stdout.splitlines() if ln.startswith("SYMBOLIC ")]
symbolic = (lines[0][len("SYMBOLIC "):] if lines else "no result") + f" (child exit status {child.returncode})"
symbolic_limited = bool(lines) and "raised RuntimeError" in lines[0]

# 2. diffuse vertices
solver = rt.PathSolver()
solver.loop_mode = "evaluated"
h = attached_height()
paths = solver(scene, max_depth=1, los=False, specular_reflection=False,
               diffuse_reflection=True, samples_per_src=2000, seed=1)
n = dr.width(paths.tau.array)
dr.backward(dr.sum(paths.tau.array))
g = float(h.grad[0])
diffuse_limited = n > 0 and g == 0.0
observed = "bug" if (symbolic_limited and diffuse_limited) else "fixed"
report("0005 detached geometry / symbolic loops (no patch)", args.expect, observed,
       f"{symbolic}; {n} diffuse paths, d(sum tau)/dh = {g}")

"""Knife edge: coherent free-space diffraction (FSD) vs the Fresnel-Kirchhoff closed form.

Reproduce (from the repository root; about half a minute on two cores)::

    /work/main/.venv/bin/python comparisons/fsd_knife_edge.py

writes ``comparisons/fsd_knife_edge.md``.  A metal half-plane screen (3 m
wide, its top edge the knife edge) stands halfway between a unit source and
a receiver 2 m apart at 77 GHz; the edge is raised ``h`` above the line of
sight, ``nu = h sqrt(2 (d1 + d2) / (lambda d1 d2))``.  Columns: the closed
form ``|F(nu)|``, ``F = (1 + j)/2 int_nu^inf exp(-j pi t^2/2) dt``
(``scipy.special.fresnel``), FSD's ``|D|`` (the diffracted field relative
to the unobstructed one, :func:`sionna_mmir.paths.transport.fsd_coherent.edge_field`),
their ratio in dB and phase difference, and ``d|D|^2 / dh`` by AD and by
central finite differences (+-1 mm) of re-evaluated fields (edges found,
nodes placed and visibility traced again).  The timing row: forward +
backward of the solver on a floor-bounce scene whose target's direct
connection a screen blocks (20k rays, depth 2), ``fsd_coherent`` off / on.
"""
from __future__ import annotations

import pathlib
import sys
import time

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

NUS = (0.5, 0.75, 1.0, 1.5, 2.0, 2.5, 3.0)


def main():
    import drjit as dr
    import mitsuba as mi
    import test_fsd_coherent as T

    from sionna_mmir.paths import RadarPathSolver
    from sionna_mmir.scene import load_scene

    lines = ["| nu | h [mm] | closed form abs(F) | FSD abs(D) | ratio [dB] | phase diff [rad] | "
             "d abs(D)^2/dh AD | FD (re-traced) | AD/FD |", "|---|---|---|---|---|---|---|---|---|"]
    for nu in NUS:
        top = nu / T.NU_PER_M
        scene = load_scene({"s": T._screen(top)})
        obj = scene.mesh_objects["s"]
        t = mi.TensorXf(np.array(obj.vertex_positions, dtype=np.float32))
        dr.enable_grad(t)
        obj.vertex_positions = t
        D_re, D_im = T._field(scene)
        D = float(D_re[0]) + 1j * float(D_im[0])
        dr.backward(dr.sum(D_re * D_re + D_im * D_im))
        g = np.array(dr.grad(t)).reshape(-1, 3)
        ad = g[2, 2] + g[3, 2]
        vals = []
        for s in (1, -1):
            a, b = T._field(load_scene({"s": T._screen(top + s * 1e-3)}))
            vals.append(float(a[0]) ** 2 + float(b[0]) ** 2)
        fd = (vals[0] - vals[1]) / 2e-3
        F = T._closed(nu)
        lines.append(f"| {nu} | {top * 1e3:.1f} | {abs(F):.4f} | {abs(D):.4f} | "
                     f"{20 * np.log10(abs(D) / abs(F)):+.2f} | {np.angle(D / F):+.3f} | "
                     f"{ad:.4g} | {fd:.4g} | {ad / fd:.3f} |")
    scene = T._blocked_scene()
    kw = dict(max_depth=2, num_rays=20_000, seed=1, scattering=False, tx_pattern="iso",
              rx_pattern="iso")
    times = {}
    for on in (False, True, False, True, False, True):
        obj = scene.mesh_objects["screen"]
        t = mi.TensorXf(np.array(dr.detach(obj.vertex_positions), dtype=np.float32))
        dr.enable_grad(t)
        obj.vertex_positions = t
        t0 = time.perf_counter()
        p = RadarPathSolver()(scene, fsd_coherent=on, **kw)
        dr.backward(p.power())
        dr.eval(dr.grad(t))
        times[on] = min(times.get(on, np.inf), time.perf_counter() - t0)
    body = "\n".join(lines) + (f"\n\nSolver forward + backward (20k rays, depth 2, best of three): "
                               f"fsd_coherent off {times[False]:.2f} s, on {times[True]:.2f} s "
                               f"(ratio {times[True] / times[False]:.1f}x).\n")
    md = ROOT / "comparisons" / "fsd_knife_edge.md"
    text = md.read_text() if md.exists() else ""
    marker = "<!-- table -->"
    md.write_text(text.split(marker)[0] + marker + "\n" + body if marker in text else body)
    print(body)


if __name__ == "__main__":
    main()

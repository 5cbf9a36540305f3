"""Cost of the boundary term: forward + backward with it on, off, and Sionna RT.

One scene (the pose-fit scene of ``comparisons/pose_fit.py``: a wall, a plate
partly hiding it and two plates), the AWR1843, depth 1, ``RAYS`` random rays.
Each row is the best of ``REPEATS`` interleaved rounds after one warm-up
(kernels compiled):

* mmIR, boundary off / on: solver call, ADC synthesis, ``sum |s|^2`` and its
  backward pass to the radar pose (position and orientation);
* Sionna RT: ``PathSolver`` (``samples_per_src = RAYS``, specular and diffuse
  reflection, depth 1) with ``sum |a|^2`` and its backward pass to the wall's
  material parameters (Sionna RT has no radar-pose gradient to time).

Run ``python benchmarks/bench_boundary.py`` (prints a Markdown table) or
through pytest with ``-m benchmark``.
"""
from __future__ import annotations

import os
import pathlib
import sys
import tempfile
import time

import numpy as np

RAYS = 200_000
REPEATS = 5
HERE = pathlib.Path(__file__).resolve().parent


def _scene():
    sys.path.insert(0, str(HERE.parent / "comparisons"))
    import pose_fit

    return pose_fit.build_scene(), pose_fit


def _best(fns) -> list:
    """Best time [s] of each of ``fns``, run interleaved (one warm-up each,
    then ``REPEATS`` rounds), so that a machine shared with other jobs slows
    all of them alike."""
    for fn in fns:
        fn()
    times = [[] for _ in fns]
    for _ in range(REPEATS):
        for i, fn in enumerate(fns):
            t = time.perf_counter()
            fn()
            times[i].append(time.perf_counter() - t)
    return [min(t) for t in times]


def _mmir(scene, boundary: bool, depth: int = 1, **extra):
    import drjit as dr
    import mitsuba as mi

    from sionna_mmir.paths import RadarPathSolver, SolverOptions

    opts = SolverOptions(num_rays=RAYS, max_depth=depth, scattering=False, boundary=boundary,
                         **extra)
    solver = RadarPathSolver()
    base_p, base_o = np.array(scene.position), np.array(scene.orientation)

    def run():
        p = mi.TensorXf(mi.Float(base_p.astype(np.float32)), (3,))
        o = mi.TensorXf(mi.Float(base_o.astype(np.float32)), (3,))
        dr.enable_grad(p, o)
        scene.position, scene.orientation = p, o
        adc = solver(scene, options=opts).adc(scene.radar)
        loss = dr.sum(dr.square(adc.real.array) + dr.square(adc.imag.array))
        dr.backward(loss)
        dr.eval(dr.grad(p), dr.grad(o))
    return run


def _sionna(meshes, radar, depth: int = 1):
    import drjit as dr
    import mitsuba as mi
    import sionna.rt as rt
    import trimesh

    tmp = tempfile.mkdtemp()
    scene = rt.load_scene()
    scene.frequency = radar.start_frequency
    mats = []
    for name, mesh in meshes.items():
        ply = os.path.join(tmp, f"{name}.ply")
        trimesh.Trimesh(mesh.vertices, mesh.faces, process=False).export(ply)
        mat = rt.ITURadioMaterial(f"m_{name}", "metal", thickness=0.01,
                                  scattering_coefficient=0.1)
        mats.append(mat)
        scene.edit(add=rt.SceneObject(fname=ply, name=name, radio_material=mat))
    c = np.concatenate([radar.tx_positions, radar.rx_positions]).mean(axis=0)
    lam = float(dr.detach(scene.wavelength)[0])
    pattern = rt.antenna_pattern.antenna_pattern_registry.get("iso")(polarization="V")

    def array(pos):
        q = ((pos - c) / lam).astype(np.float32)
        return rt.AntennaArray(pattern, mi.Point3f(q[:, 0], q[:, 1], q[:, 2]))

    scene.tx_array, scene.rx_array = array(radar.tx_positions), array(radar.rx_positions)
    centre = mi.Point3f(*(float(x) for x in c))
    scene.add(rt.Transmitter("radar_tx", position=centre, orientation=mi.Point3f(0, 0, 0)))
    scene.add(rt.Receiver("radar_rx", position=centre, orientation=mi.Point3f(0, 0, 0)))
    solver = rt.PathSolver()
    solver.loop_mode = "evaluated"          # reverse-mode AD through Sionna's loop
    kw = dict(max_depth=depth, samples_per_src=RAYS, max_num_paths_per_src=RAYS, los=False,
              specular_reflection=True, diffuse_reflection=True, refraction=False,
              diffraction=False, synthetic_array=True, seed=0)

    def run():
        params = [m.conductivity for m in mats]
        for p in params:
            dr.enable_grad(p)
        paths = solver(scene, **kw)
        re, im = paths.a
        loss = dr.sum(dr.square(re.array) + dr.square(im.array))
        dr.backward(loss)
        dr.eval([dr.grad(p) for p in params])
        for p in params:
            dr.disable_grad(p)
    return run


def measure() -> dict:
    """Timings [s] and ratios, with a Markdown table under ``"markdown"``."""
    scene, pose_fit = _scene()
    meshes = pose_fit.meshes()
    fns, note = [_mmir(scene, False), _mmir(scene, True)], ""
    try:
        fns.append(_sionna(meshes, scene.radar))
    except Exception as exc:           # Sionna missing or failing: report, do not hide
        note = f" (Sionna RT failed: {type(exc).__name__}: {exc})"
    times = _best(fns) + [float("nan")]
    t_off, t_on, t_sionna = times[:3]
    md = "\n".join([
        f"Speed, forward + backward, depth 1, {RAYS} rays, best of {REPEATS} interleaved rounds "
        f"(`python benchmarks/bench_boundary.py`){note}:", "",
        "| | seconds | vs boundary off | vs Sionna RT |", "|---|---|---|---|",
        f"| mmIR, boundary off | {t_off:.3f} | 1.00 | {t_off / t_sionna:.2f} |",
        f"| mmIR, boundary on | {t_on:.3f} | {t_on / t_off:.2f} | {t_on / t_sionna:.2f} |",
        f"| Sionna RT PathSolver | {t_sionna:.3f} | {t_sionna / t_off:.2f} | 1.00 |"])
    return {"rays": RAYS, "boundary_off_s": t_off, "boundary_on_s": t_on, "sionna_s": t_sionna,
            "on_vs_off": t_on / t_off, "on_vs_sionna": t_on / t_sionna, "markdown": md}


if __name__ == "__main__":
    print(measure()["markdown"])

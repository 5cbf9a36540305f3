"""Curved metal targets: specular manifold sampling vs the image method vs brute-force PO.

Reproduce (from the repository root; about a minute on two cores)::

    /work/main/.venv/bin/python comparisons/sms_curved.py

writes ``comparisons/sms_curved.md`` and ``.json``.  Targets (PEC, one
monostatic isotropic element of ``RadarConfig.dense(1, 1)`` at 77 GHz,
depth 1, ``scattering=False``), their nearest point at range ``R`` on
boresight:

* an open cylinder (side wall only) of radius ``a`` and length ``L``, 256
  sides, axis vertical, smooth vertex normals; the radar faces the centre
  of a facet ("facet") or a vertical edge between two facets ("edge");
* an icosphere of radius ``a`` ("sphere-5": 5 subdivisions, 20 480 faces;
  "sphere-7": 7 subdivisions, 327 680 faces), smooth vertex normals.

Columns (RCS in dBsm, ``|a|^2 (4 pi)^3 R^4 / lambda^2``):

truth
    the independent brute-force physical-optics renderer
    (:func:`sionna_mmir.independent.render_reference`; sub-facets with an
    exact phase integral, shares no code with the solver);
geometric optics
    the near-range closed form of a doubly curved mirror, ``4 pi R^2
    rho_1 rho_2 / ((rho_1 + R)(rho_2 + R))``, ``1 / rho_i = 1 / R + 2 /
    a_i``: ``pi R^2 a^2 / (R + a)^2`` (sphere, ``-> pi a^2``) and ``pi R^2
    a / (R + a)`` (a cylinder longer than its Fresnel zone; the far-field
    ``2 pi a L^2 / lambda`` needs ``L^2 << lambda R`` and is listed for
    reference);
image method
    a specular reflection exists only where the radar's mirror image in a
    flat facet's plane projects inside that facet (the rule of
    Sionna RT's image method), radiating the plane-mirror field
    (``sigma = pi R^2`` per facet);
Sionna RT
    plain Sionna RT's own ``PathSolver`` (image method, specular only, 2M
    rays; :class:`sionna_mmir.baseline.SionnaBaseline`);
PO, random rays
    the solver without SMS (Monte Carlo physical optics over the hit
    triangles), 20k and 200k rays in a cone just covering the target;
SMS
    the solver with ``sms=True`` at the same ray counts.

The timing rows give forward + backward (gradient of the summed power with
respect to the target's vertex positions) with SMS off and on.

A second table: depth 2, the icosphere 0.6 m above a 5.5 m x 4 m metal
floor; the floor-sphere chains (both orders) against twice the
image-source closed form of geometric optics (the radar's image in the
floor lights the sphere; ``tests/test_sms_solver.py``).
"""
from __future__ import annotations

import json
import pathlib
import sys
import time

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

C = 299_792_458.0
F0 = 77e9
LAM = C / F0
SIDES = 256
TARGETS = [("cylinder-facet", 0.2, 0.6, 3.0), ("cylinder-edge", 0.2, 0.6, 3.0),
           ("sphere-5", 0.3, 0.0, 3.0), ("sphere-7", 0.3, 0.0, 3.0)]
RAYS = (20_000, 200_000)


def cylinder(a, L, centre, facet_on_axis: bool):
    """Open 256-sided cylinder (side wall), axis +z through ``centre``."""
    import trimesh

    off = np.pi / SIDES if facet_on_axis else 0.0
    th = 2 * np.pi * np.arange(SIDES) / SIDES + off + np.pi
    ring = np.c_[a * np.cos(th), a * np.sin(th)]
    verts = np.concatenate([np.c_[ring, np.full(SIDES, -L / 2)],
                            np.c_[ring, np.full(SIDES, L / 2)]])
    i = np.arange(SIDES)
    j = (i + 1) % SIDES
    faces = np.concatenate([np.c_[i, j, j + SIDES], np.c_[i, j + SIDES, i + SIDES]])
    m = trimesh.Trimesh(verts + centre, faces, process=False)
    m.fix_normals()
    return m


def target(kind, a, L, point):
    """The mesh of ``kind`` whose nearest point to the radar is ``point``
    (the radar on ``-x``)."""
    import trimesh

    centre = point + np.array([a, 0.0, 0.0])
    if kind.startswith("sphere"):
        m = trimesh.creation.icosphere(subdivisions=int(kind.split("-")[1]), radius=a)
        m.apply_translation(centre)
        return m
    return cylinder(a, L, centre, kind == "cylinder-facet")


def rcs_dbsm(coef, R):
    return float(10 * np.log10(np.abs(coef) ** 2 * (4 * np.pi) ** 3 * R ** 4 / LAM ** 2))


def image_method(mesh, c):
    """Coherent sum of the plane-mirror reflections whose mirror point lies in
    its facet (monostatic at ``c``), as an RCS-normalised amplitude."""
    v = np.asarray(mesh.vertices)[np.asarray(mesh.faces)]
    n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    d = np.sum((c - v[:, 0]) * n, axis=1)                # signed distance to the plane
    foot = c - d[:, None] * n
    # barycentric inside test
    e0, e1, e2 = v[:, 1] - v[:, 0], v[:, 2] - v[:, 0], foot - v[:, 0]
    d00, d01, d11 = (e0 * e0).sum(1), (e0 * e1).sum(1), (e1 * e1).sum(1)
    d20, d21 = (e2 * e0).sum(1), (e2 * e1).sum(1)
    den = d00 * d11 - d01 * d01
    bu = (d11 * d20 - d01 * d21) / den
    bv = (d00 * d21 - d01 * d20) / den
    inside = (bu >= 0) & (bv >= 0) & (bu + bv <= 1) & (d > 0)
    # a mirror point on a shared edge is one reflection, not one per triangle
    _, first = np.unique(np.round(foot[inside], 6), axis=0, return_index=True)
    inside = np.flatnonzero(inside)[first]
    k = 2 * np.pi / LAM
    # plane mirror, PEC: |a| = lambda / (4 pi 2 d), phase of the path 2 d
    amp = LAM / (4 * np.pi * 2 * d[inside]) * np.exp(-2j * k * d[inside])
    return amp.sum() * (4 * np.pi) ** 1.5 / LAM        # sqrt(sigma) / R^2


def solver_rcs(mesh, R, n, sms, grad=False):
    """``(RCS [dBsm], seconds)`` of the solver (forward, or forward + backward)."""
    import drjit as dr

    from sionna_mmir.paths import RadarPathSolver
    from sionna_mmir.radar import RadarConfig
    from sionna_mmir.scene import load_scene

    radar = RadarConfig.dense(1, 1)
    scene = load_scene({"t": mesh}, materials={"t": "metal"}, radar=radar)
    half = 0.5 * float(np.max(np.ptp(mesh.vertices, axis=0)))
    cone = float(np.degrees(np.arctan(1.2 * half / R)))
    pos = scene.mesh_objects["t"].vertex_positions
    if grad:
        dr.enable_grad(pos)
    t0 = time.perf_counter()
    p = RadarPathSolver()(scene, max_depth=1, num_rays=n, seed=1, cone_angle_deg=cone,
                          scattering=False, tx_pattern="iso", rx_pattern="iso", sms=sms)
    if grad:
        dr.backward(p.power())
        dr.eval(dr.grad(pos))
    amp, tau, _ = p.numpy()
    coef = (amp * np.exp(2j * np.pi * F0 * tau)).sum()
    return rcs_dbsm(coef, R), time.perf_counter() - t0


def sionna_rcs(mesh, R):
    """RCS [dBsm] from plain Sionna RT (specular reflection only), or -inf."""
    from sionna_mmir.baseline.sionna_rt import SionnaBaseline
    from sionna_mmir.radar import RadarConfig

    bl = SionnaBaseline({"t": mesh}, {"t": "metal"}, RadarConfig.dense(1, 1), max_depth=1,
                        samples_per_src=2_000_000, diffuse_reflection=False)
    a_re, a_im, tau = bl.pair_paths(bl.trace())
    amp = np.asarray(a_re) + 1j * np.asarray(a_im)
    coef = (amp * np.exp(2j * np.pi * F0 * np.asarray(tau))).sum()
    return rcs_dbsm(coef, R) if abs(coef) > 0 else float("-inf")


def truth_rcs(mesh, R):
    from sionna_mmir.independent import render_reference
    from sionna_mmir.radar import RadarConfig

    radar = RadarConfig.dense(1, 1)
    ref = render_reference({"t": mesh}, {"t": "metal"}, radar, max_depth=1, tx_pattern="iso",
                           rx_pattern="iso", diffuse=False, frequency_hz=F0,
                           merge_fraction=0.0, min_rel_amplitude=0.0)
    coef = (ref.a * np.exp(2j * np.pi * F0 * ref.tau)).sum()
    return rcs_dbsm(coef, R)


def rows():
    from sionna_mmir.radar import RadarConfig

    radar = RadarConfig.dense(1, 1)
    c = np.concatenate([radar.tx_positions, radar.rx_positions]).mean(axis=0)
    out = {}
    for kind, a, L, R in TARGETS:
        mesh = target(kind, a, L, c + np.array([R, 0.0, 0.0]))
        go = (np.pi * R ** 2 * a ** 2 / (R + a) ** 2 if kind.startswith("sphere")
              else np.pi * R ** 2 * a / (R + a))
        row = {"truth": truth_rcs(mesh, R), "go": float(10 * np.log10(go)),
               "far": float(10 * np.log10(np.pi * a * a if kind.startswith("sphere")
                                          else 2 * np.pi * a * L ** 2 / LAM))}
        im = image_method(mesh, c)
        row["image"] = (float(10 * np.log10(abs(im) ** 2 * R ** 4)) if abs(im) > 0
                        else float("-inf"))
        row["sionna"] = sionna_rcs(mesh, R)
        for n in RAYS:
            row[f"po{n}"], _ = solver_rcs(mesh, R, n, False)
            row[f"sms{n}"], _ = solver_rcs(mesh, R, n, True)
        solver_rcs(mesh, R, RAYS[0], False, grad=True)            # compile
        solver_rcs(mesh, R, RAYS[0], True, grad=True)
        row["t_off"] = min(solver_rcs(mesh, R, RAYS[0], False, grad=True)[1] for _ in range(3))
        row["t_on"] = min(solver_rcs(mesh, R, RAYS[0], True, grad=True)[1] for _ in range(3))
        out[kind] = row
        print(kind, row, flush=True)
    return out


def floor_rows():
    """Depth-2 floor-sphere chains: ``{closed, po20000, ..., sms200000}``
    [dB re the closed form]."""
    sys.path.insert(0, str(ROOT / "tests"))
    import trimesh

    import test_sms_solver as T
    from sionna_mmir.paths import RadarPathSolver
    from sionna_mmir.radar import RadarConfig
    from sionna_mmir.scene import load_scene

    radar = RadarConfig.dense(1, 1)
    c = np.concatenate([radar.tx_positions, radar.rx_positions]).mean(axis=0)
    a, hf, R = 0.3, 0.6, 3.0
    centre = c + np.array([R + a, 0, 0])
    fz = c[2] - hf
    floor = trimesh.Trimesh(np.array([[c[0] + 0.5, -2, fz], [c[0] + 6, -2, fz],
                                      [c[0] + 6, 2, fz], [c[0] + 0.5, 2, fz]]),
                            [[0, 1, 2], [0, 2, 3]], process=False)
    scene = load_scene({"sphere": T._sphere(a, centre, 5), "floor": floor},
                       materials={"sphere": "metal", "floor": "metal"}, radar=radar)
    image = c.copy()
    image[2] = 2 * fz - c[2]
    ref = 2 * LAM / (4 * np.pi) * T._bistatic_sphere_go(a, centre, image, c)
    out = {"closed": float(20 * np.log10(ref))}
    for n in RAYS:
        for sms in (False, True):
            p = RadarPathSolver()(scene, max_depth=2, num_rays=n, seed=1, cone_angle_deg=20,
                                  scattering=False, tx_pattern="iso", rx_pattern="iso", sms=sms)
            amp, tau, _ = p.numpy()
            coef = (amp[0, 0] * np.exp(2j * np.pi * F0 * tau[0, 0]))[p.depth == 2].sum()
            out[f"{'sms' if sms else 'po'}{n}"] = float(20 * np.log10(abs(coef) / ref))
    print("floor", out, flush=True)
    return out


def floor_table(r) -> str:
    return ("\n\nDepth 2, sphere (a = 0.3 m, R = 3 m) 0.6 m above a metal floor: the "
            "floor-sphere chains' amplitude, dB re twice the image-source closed form "
            f"({r['closed']:.1f} dB re 1).\n\n"
            "| mirror chains 20k | mirror chains 200k | SMS 20k | SMS 200k |\n"
            "|---|---|---|---|\n"
            f"| {r['po20000']:+.2f} | {r['po200000']:+.2f} | {r['sms20000']:+.2f} | "
            f"{r['sms200000']:+.2f} |\n")


def table(res) -> str:
    head = ("| target | a [m] | L [m] | R [m] | truth (brute-force PO) | geometric optics | "
            "far-field closed form | image method | Sionna RT | PO 20k | PO 200k | SMS 20k | "
            "SMS 200k | "
            "fwd+bwd 20k off / on [s] (ratio) |\n|---|---|---|---|---|---|---|---|---|---|---|"
            "---|---|---|\n")
    lines = []
    for kind, a, L, R in TARGETS:
        r = res[kind]
        t = r["truth"]

        def cell(v):
            return "none" if not np.isfinite(v) else f"{v:.2f} ({v - t:+.2f})"

        lines.append(f"| {kind} | {a} | {L if L else '-'} | {R} | {t:.2f} | {cell(r['go'])} | "
                     f"{cell(r['far'])} | {cell(r['image'])} | {cell(r['sionna'])} | "
                     f"{cell(r['po20000'])} | "
                     f"{cell(r['po200000'])} | {cell(r['sms20000'])} | {cell(r['sms200000'])} | "
                     f"{r['t_off']:.2f} / {r['t_on']:.2f} ({r['t_on'] / r['t_off']:.1f}x) |")
    return head + "\n".join(lines) + "\n"


def main():
    res = rows()
    res["floor"] = floor_rows()
    out = ROOT / "comparisons" / "sms_curved"
    out.with_suffix(".json").write_text(json.dumps(res, indent=1))
    md = out.with_suffix(".md")
    text = md.read_text() if md.exists() else ""
    marker = "<!-- table -->"
    body = table(res) + floor_table(res["floor"])
    md.write_text(text.split(marker)[0] + marker + "\n" + body if marker in text else body)
    print(body)


if __name__ == "__main__":
    main()

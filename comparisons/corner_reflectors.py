"""Corner reflectors: closed form, brute-force PO and the radar path solver, before and after.

Reproduce (from the repository root; about five minutes on two cores)::

    /work/main/.venv/bin/python comparisons/corner_reflectors.py

writes ``comparisons/corner_reflectors.md`` and ``.json``.  "before" is the
solver at ``--before`` (default ``7e57589``, extracted with ``git archive``
into a temporary folder), "after" the working tree.  Targets (PEC, depth 3,
``scattering=False``, isotropic V-polarised elements at 77 GHz): a triangular
trihedral of edge ``a`` on its symmetry axis, a right-angled dihedral of two
``a x a`` plates along its bisector (fold vertical), a square ``a x a`` plate
at normal incidence, with their boresight on the array centre at range
``R`` (apex, fold midpoint, plate centre).  Radars: ``RadarConfig.dense(1, 1)``
(one monostatic element) and ``RadarConfig.mmwcas(num_chirps=1)`` (12 x 16,
the RCS is the mean over the Tx-Rx pairs of ``|a|^2 (4 pi)^3 R_t^2 R_r^2 /
lambda^2``, ``R_t``, ``R_r`` the element ranges).  Random rays are
cosine-weighted in a cone of half-angle ``atan(1.2 a / R)`` (seed 1).

Columns: the far-field closed form (trihedral ``4 pi a^4 / (3 lambda^2)``,
dihedral ``8 pi a^4 / lambda^2``, plate ``4 pi a^4 / lambda^2``); the
brute-force physical-optics sum of ``tests/corner_po.py`` (image theory, all
chains up to the target's bounce count, 1 mm cells), which holds in the near
field where the closed form does not; the solver's RCS.
"""
from __future__ import annotations

import argparse
import json
import os
import pathlib
import subprocess
import sys
import tempfile

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
import corner_po  # noqa: E402

C = 299_792_458.0
F0 = 77e9
LAM = C / F0
TARGETS = [("trihedral", 0.1, 2.0), ("trihedral", 0.1, 5.0), ("dihedral", 0.1, 2.0),
           ("dihedral", 0.1, 5.0), ("plate", 0.1, 2.0), ("plate", 0.1, 5.0),
           ("trihedral", 0.2, 4.0)]
BOUNCES = {"trihedral": 3, "dihedral": 2, "plate": 1}
RUNS = [("random", 20_000), ("random", 200_000), ("facets", 0)]


def radar_config(name):
    """The radar ``name`` ("dense" or "mmwcas") at the origin, boresight +x."""
    from sionna_mmir.radar import RadarConfig

    return RadarConfig.dense(1, 1) if name == "dense" else RadarConfig.mmwcas(num_chirps=1)


def _centre(radar):
    return np.concatenate([radar.tx_positions, radar.rx_positions]).mean(axis=0)


def mean_rcs_dbsm(coef, tx, rx, ref_point):
    """Mean over the pairs of ``|a|^2 (4 pi)^3 R_t^2 R_r^2 / lambda^2`` [dBsm]
    of the coefficients ``coef [T, R]``."""
    Rt = np.linalg.norm(tx - ref_point, axis=1)[:, None]
    Rr = np.linalg.norm(rx - ref_point, axis=1)[None, :]
    sigma = np.abs(coef) ** 2 * (4 * np.pi) ** 3 * Rt ** 2 * Rr ** 2 / LAM ** 2
    return float(10 * np.log10(sigma.mean()))


def solver_rows():
    """``{key: RCS [dBsm]}`` of the solver in this interpreter's ``sionna_mmir``."""
    from sionna_mmir.paths import RadarPathSolver
    from sionna_mmir.scene import load_scene

    out = {}
    for radar_name in ("dense", "mmwcas"):
        radar = radar_config(radar_name)
        c = _centre(radar)
        for kind, a, R in TARGETS:
            point = c + np.array([R, 0.0, 0.0])
            _, meshes = corner_po.corner_target(kind, a, point)
            scene = load_scene(meshes, materials={k: "metal" for k in meshes}, radar=radar)
            cone = float(np.degrees(np.arctan(1.2 * a / R)))
            for sampling, n in RUNS:
                p = RadarPathSolver()(scene, max_depth=3, sampling=sampling, num_rays=max(n, 1),
                                      seed=1, cone_angle_deg=cone, scattering=False,
                                      tx_pattern="iso", rx_pattern="iso")
                amp, tau, _ = p.numpy()
                coef = (amp * np.exp(2j * np.pi * F0 * tau)).sum(axis=2)
                out[_key(radar_name, kind, a, R, sampling, n)] = mean_rcs_dbsm(
                    coef, radar.tx_positions, radar.rx_positions, point)
    return out


def _key(radar, kind, a, R, sampling, n):
    return f"{radar}|{kind}|{a}|{R}|{sampling}|{n}"


def references():
    """``{radar|kind|a|R: (closed form, brute-force PO)}`` [dBsm]."""
    out = {}
    for radar_name in ("dense", "mmwcas"):
        radar = radar_config(radar_name)
        c = _centre(radar)
        for kind, a, R in TARGETS:
            point = c + np.array([R, 0.0, 0.0])
            plates, _ = corner_po.corner_target(kind, a, point)
            chains = [ch for d in range(1, BOUNCES[kind] + 1)
                      for ch in corner_po.chains(len(plates), d)]
            coef = np.array([[sum(corner_po.chain_field(plates, ch, rx, tx, LAM, 1e-3)
                                  for ch in chains) for rx in radar.rx_positions]
                             for tx in radar.tx_positions])
            closed = {"trihedral": 4 * np.pi * a ** 4 / (3 * LAM ** 2),
                      "dihedral": 8 * np.pi * a ** 4 / LAM ** 2,
                      "plate": 4 * np.pi * a ** 4 / LAM ** 2}[kind]
            out[f"{radar_name}|{kind}|{a}|{R}"] = (
                float(10 * np.log10(closed)),
                mean_rcs_dbsm(coef, radar.tx_positions, radar.rx_positions, point))
    return out


def run_version(src: pathlib.Path) -> dict:
    """The solver rows of the package in ``src`` (a subprocess)."""
    env = dict(os.environ, PYTHONPATH=str(src))
    res = subprocess.run([sys.executable, __file__, "--worker"], env=env, cwd=str(src),
                         check=True, capture_output=True, text=True)
    return json.loads(res.stdout.strip().splitlines()[-1])


def table(refs, before, after) -> str:
    """The Markdown table of the comparison."""
    head = ("| radar | target | a [m] | R [m] | closed form | brute-force PO | "
            + " | ".join(f"{s} {n // 1000}k" if n else s for s, n in RUNS) + " |\n")
    head += "|---|---|---|---|---|---|" + "---|" * len(RUNS) + "\n"
    rows = []
    for radar_name in ("dense", "mmwcas"):
        for kind, a, R in TARGETS:
            closed, po = refs[f"{radar_name}|{kind}|{a}|{R}"]
            cells = [f"{before[_key(radar_name, kind, a, R, s, n)]:.1f} / "
                     f"{after[_key(radar_name, kind, a, R, s, n)]:.1f}" for s, n in RUNS]
            rows.append(f"| {'dense 1x1' if radar_name == 'dense' else 'mmwcas'} | {kind} | {a} "
                        f"| {R} | {closed:.1f} | {po:.1f} | " + " | ".join(cells) + " |")
    return head + "\n".join(rows) + "\n"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--before", default="7e57589", help="commit of the 'before' solver")
    args = ap.parse_args(argv)
    if args.worker:
        print(json.dumps(solver_rows()))
        return
    with tempfile.TemporaryDirectory() as tmp:
        archive = subprocess.run(["git", "archive", args.before], cwd=ROOT, check=True,
                                 capture_output=True).stdout
        subprocess.run(["tar", "-x", "-C", tmp], input=archive, check=True)
        before = run_version(pathlib.Path(tmp))
    after = run_version(ROOT)
    refs = references()
    out = ROOT / "comparisons" / "corner_reflectors"
    out.with_suffix(".json").write_text(json.dumps({"before": before, "after": after,
                                                    "references": refs}, indent=1))
    md = out.with_suffix(".md")
    text = md.read_text() if md.exists() else ""
    marker = "<!-- table -->"
    body = table(refs, before, after)
    md.write_text(text.split(marker)[0] + marker + "\n" + body if marker in text else body)
    print(body)


if __name__ == "__main__":
    main()

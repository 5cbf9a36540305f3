"""``loop`` end to end on a capture of the independent generator, and its
first adoption on a measured capture.

Truth: the planted effect of :mod:`sionna_mmir.independent.undeclared` (plain
NumPy point scatterers, clutter, exact per-pair delays; no code shared with
the solver or the effects library).  The full suite is a comparison script
(``comparisons/run_undeclared_suite.py``); this is its smallest case: a
single-chip run with per-channel gains planted, a short candidate list.
The measured case (corner_4m7, skipped without the shared data) checks
where the first adoption's joint refit lands.
"""
from __future__ import annotations

import json
import os

import pytest

from sionna_mmir.independent.undeclared import make_case, write_coloradar_run
from sionna_mmir.pipeline import LoopRequest, run_loop


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    work = tmp_path_factory.mktemp("loop")
    case = make_case("channel_gain", seed=1, radar="awr1843", num_chirps=2, num_samples=64)
    run = str(write_coloradar_run(case, str(work / "run")))
    mesh_dir = os.path.join(run, "mesh")
    meshes = {f[:-4]: os.path.join(mesh_dir, f) for f in sorted(os.listdir(mesh_dir))}
    out = str(work / "report")
    doc = run_loop(LoopRequest(capture=run, out=out, meshes=meshes, materials=case.materials,
                               sensor="single_chip", fit_iterations=2, progress=False,
                               effects="channel_gain,dc_offset,object_shift,object_pattern"))
    return doc, out


def test_01_planted_gains_adopted_and_reported(report):
    doc, out = report
    assert doc["sensor_effects"][:1] == ["channel_gain"], doc["sensor_effects"]
    assert doc["final"]["residual_energy_db"] < doc["first"]["residual_energy_db"] - 3
    for name in ("report.json", "report.md", "model.h5", "scene_mmir.ply"):
        assert os.path.exists(os.path.join(out, name)), name
    with open(os.path.join(out, "report.json")) as f:
        saved = json.load(f)
    assert {"first", "final", "adoptions", "scene_mismatch", "unexplained",
            "stop_reason", "vetoed"} <= set(saved)
    # the RA fit's target: calibrated per channel or not, and why
    cal = saved["info"]["target_calibration"]
    assert {"applied", "ra_corr_raw", "ra_corr_calibrated", "phases_deg"} <= set(cal)
    a = saved["adoptions"][0]
    assert {"name", "side", "verdict", "before", "after", "unexplained"} <= set(a)
    # every adopted mean-only effect lowered the held-out residual energy
    chosen = next(c for c in a["candidates"] if c["name"] == a["name"])
    assert chosen["energy_change_db"] < 0, chosen
    # where the time went: the round's wall seconds and each candidate's fold fits
    assert a["seconds"]["rank"] > 0 and a["seconds"]["adopt"] > 0
    # and the adoption's stages, which lie within it
    stages = {k: v for k, v in a["seconds"].items() if k.startswith("adopt_")}
    assert "adopt_joint" in stages and sum(stages.values()) <= a["seconds"]["adopt"] + 0.1
    assert all(c["fit_s"] > 0 for c in a["candidates"])
    assert sum(c["fit_s"] for c in a["candidates"]) < saved["timings"]["diagnose_s"] * 2
    with open(os.path.join(out, "report.md")) as f:
        assert "| fit [s] |" in f.read()


def test_02_overlap_warning_needs_both_the_adc_residual_and_the_ra_map():
    from sionna_mmir.pipeline.loop import overlap_warning

    wrong_frame = {"residual_energy_db": -0.01, "ra_correlation": 0.001}
    sensor_effect = {"residual_energy_db": -0.12, "ra_correlation": 0.72}
    good = {"residual_energy_db": -12.0, "ra_correlation": 0.05}
    msg = overlap_warning(wrong_frame, "run")
    assert msg is not None and msg.startswith("run: the scene explains only 0 %")
    assert "barely overlap" in msg
    assert overlap_warning(sensor_effect, "run") is None
    delay_offset = {"residual_energy_db": -0.07, "ra_correlation": 0.35}
    assert overlap_warning(delay_offset, "run") is None
    assert overlap_warning(good, "run") is None


def test_03_an_adoption_refits_jointly_from_the_candidates_own_fit(measured_dir, monkeypatch,
                                                                   tmp_path):
    """Truth: the measured corner_4m7 capture.  Its first adoption, per-Tx /
    per-Rx delays, fitted jointly with the nuisance gain and the pose offset
    straight from its data-driven start, stopped 1.9 dB above the basin that
    the delays reach when fitted alone first (-4.15 against -6.02 dB of the
    capture energy).  The backfitting trials are switched off here: they
    rescued the good basin in some runs and not in others."""
    from conftest import measured_file
    from sionna_mmir.effects.library.delay_offset import DelayOffset
    from sionna_mmir.pipeline.loop import Loop
    from sionna_mmir.residual import adoption
    from sionna_mmir.residual.diagnosis import _current_metrics

    mat = measured_file(measured_dir, "mmwcas_corner/corner_4m7_slope79.mat")
    loop = Loop(LoopRequest(capture=str(mat), out=str(tmp_path / "out"), scene="corner",
                            progress=False))
    loop.prepare()
    loop.fit_scene()
    loop.base()
    model = loop.run.model.copy()
    first = _current_metrics(model)["residual_energy_db"]
    monkeypatch.setattr(adoption, "_backfit", lambda work, comp, maxiter, pool: comp)
    adoption._adopt(model, DelayOffset(), 150)
    after = _current_metrics(model)["residual_energy_db"]
    assert first > -1.5, first
    assert after < -5.8, (first, after)

"""Benchmarks (``make bench``): timings printed, never asserted as tests."""
import pytest

pytestmark = pytest.mark.benchmark


def test_bench_adc_synthesis():
    import bench_adc

    rows = bench_adc.run((1000, 10000))
    print("\n" + bench_adc.to_markdown(rows))
    print("\n" + bench_adc.to_markdown_vs_sionna(bench_adc.run_vs_sionna((1000, 10000))))


@pytest.mark.benchmark
def test_bench_path_solver_vs_sionna_quick():
    """Quick mode of ``bench_paths``: both solvers ran every stage; structure only, no timing asserts."""
    import math

    import bench_paths

    res = bench_paths.run(quick=True)
    print("\n" + bench_paths.to_markdown(res))
    assert set(res) >= {"meta", "jobs", "rows", "ratios", "breakdown", "memory"}
    assert res["meta"]["quick"] is True and res["memory"] == []
    rows = {r["solver"]: r for r in res["rows"]}
    assert set(rows) == {"mmir", "sionna"}
    for solver, r in rows.items():
        assert r["paths"] > 0 and r["pair_paths"] == 192 * r["paths"], (solver, r)
        for st in ("fwd_paths", "fb_paths", "fwd_signal", "fb_signal"):
            assert r[st + "_status"] == "ok", (solver, st, res["jobs"])
            assert r[st + "_s"] > 0 and r[st + "_peak_gib"] > 0
    assert rows["sionna"]["fwd_paths_symbolic_status"] == "ok"
    (ratio,) = res["ratios"]
    for key in ("fwd_paths", "fb_paths", "fwd_signal", "fb_signal", "fb_adc_vs_sionna_paths"):
        assert math.isfinite(ratio[key]) and ratio[key] > 0
    stages = {(b["solver"], b["stage"]) for b in res["breakdown"]}
    assert ("mmir", "fb_signal") in stages and ("sionna", "fb_paths") in stages
    fb = next(j for j in res["jobs"] if j["job"]["solver"] == "mmir")["stages"]["fb_paths"]
    assert fb["info"]["grad_abs_sum"] > 0            # gradients reached the vertex tensors
    md = bench_paths.to_markdown(res)
    assert "sionna_mmir" in md and "Sionna RT" in md and "fwd+bwd" in md


@pytest.mark.benchmark
def test_bench_boundary_term_cost():
    """Forward + backward with the boundary term on / off and Sionna RT (timings printed)."""
    import math

    import bench_boundary

    res = bench_boundary.measure()
    print("\n" + res["markdown"])
    assert res["boundary_on_s"] > 0 and res["boundary_off_s"] > 0
    assert math.isfinite(res["on_vs_off"])


@pytest.mark.benchmark
def test_bench_sms_fsd_cost():
    """Forward + backward with SMS / coherent FSD on and off, and Sionna RT (timings printed)."""
    import bench_sms_fsd

    res = bench_sms_fsd.measure()
    print("\n" + res["markdown"])
    assert all(t > 0 for t in res["seconds"].values())


@pytest.mark.benchmark
def test_bench_effects_evaluation():
    """One loss-and-gradient evaluation of the effect model, basis kept per
    chirp loop vs the full-size reference twin (timings printed)."""
    import bench_effects_eval

    res = bench_effects_eval.run(repeat=3)
    print("\n" + bench_effects_eval.to_markdown(res))
    assert res["kept_s"] > 0 and res["full_s"] > 0
    assert res["grad_rel_diff"] < 1e-4

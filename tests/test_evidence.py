"""Pieces of the evidence experiments: the block-pair ADC synthesis against the
plain reference twin, the shared-shape beam pattern, per-object materials,
the co-located sensor pose and the cross-truth cells' bookkeeping."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from helpers import square_plate

from sionna_mmir import RadarConfig, SPEED_OF_LIGHT
from sionna_mmir.errors import ConfigError, InputValueError
from sionna_mmir.fmcw import synthesize_adc_basic
from sionna_mmir.fmcw.synthesize_blocks import (BlockSpreadSynthesis, synthesize_adc_blocks,
                                                taylor_bound)
from sionna_mmir.fmcw.synthesize_factorised import check_factor_inputs


def _near_field(radar, P=40, seed=1):
    """Point scatterers 1-6 m away: exact per-element delays (near field), random gains."""
    rng = np.random.default_rng(seed)
    pts = np.stack([rng.uniform(1.0, 6.0, P), rng.uniform(-2, 2, P), rng.uniform(-1, 1, P)], 1)
    tau_t = np.linalg.norm(pts[None] - radar.tx_positions[:, None], axis=-1) / SPEED_OF_LIGHT
    tau_r = np.linalg.norm(pts[None] - radar.rx_positions[:, None], axis=-1) / SPEED_OF_LIGHT
    g_t = rng.uniform(0.5, 1.5, tau_t.shape)
    g_r = rng.uniform(0.5, 1.5, tau_r.shape)
    c = rng.normal(size=P) + 1j * rng.normal(size=P)
    x = check_factor_inputs(radar, c, g_t, tau_t, g_r, tau_r)
    ref = synthesize_adc_basic(radar, c[None, None] * g_t[:, None] * g_r[None],
                               tau_t[:, None] + tau_r[None])
    return x, ref


def _err(a, b):
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


@pytest.fixture(scope="module")
def dense():
    radar = RadarConfig.dense(16, 16, num_samples=64)
    return (radar,) + _near_field(radar)


def test_01_block_spread_matches_the_reference_twin(dense):
    radar, x, ref = dense
    # one element per block: only the kernel's error is left
    one = BlockSpreadSynthesis(radar, x, blocks=(16, 16), order=0, width=8).forward()
    assert _err(one, ref) < 1e-5
    # larger blocks: the Taylor series closes the gap order by order, within its bound
    errs = [_err(BlockSpreadSynthesis(radar, x, blocks=(2, 2), order=k, width=8).forward(), ref)
            for k in (0, 1, 2)]
    assert errs[0] > errs[1] > errs[2] and errs[2] < 1e-4
    for k, e in enumerate(errs):
        assert e < taylor_bound(radar, x, (2, 2), k) + 1e-5


def test_02_default_settings_and_general_layouts():
    # the cascade's irregular layout (12 x 16), 3 chirp loops, default blocks / order / width
    radar = dataclasses.replace(RadarConfig.mmwcas(num_chirps=3), num_samples=64)
    x, ref = _near_field(radar, P=30, seed=2)
    s = synthesize_adc_blocks(radar, x.c, x.g_t, x.tau_t, x.g_r, x.tau_r)
    assert s.shape == radar.adc_shape and s.dtype == np.complex64
    syn = BlockSpreadSynthesis(radar, x)
    assert syn.tx_blocks and len(syn.tx_blocks) > 1          # blocks by length, not by count
    assert _err(s, ref) < taylor_bound(radar, x, (len(syn.tx_blocks), len(syn.rx_blocks)), 0) + 1e-2
    s2 = synthesize_adc_blocks(radar, x.c, x.g_t, x.tau_t, x.g_r, x.tau_r, blocks=(3, 4),
                               order=2, width=8)
    assert _err(s2, ref) < 1e-4


def test_03_block_spread_bad_input(dense):
    radar, x, _ = dense
    moving = dataclasses.replace(x, rho=np.zeros(x.num_paths))
    with pytest.raises(InputValueError, match="static"):
        BlockSpreadSynthesis(radar, moving)
    with pytest.raises(InputValueError, match="order"):
        BlockSpreadSynthesis(radar, x, order=3)
    empty = synthesize_adc_blocks(radar, np.zeros(0), np.zeros((16, 0)), np.zeros((16, 0)),
                                  np.zeros((16, 0)), np.zeros((16, 0)))
    assert empty.shape == radar.adc_shape and not empty.any()


def test_04_shared_shape_pattern():
    from sionna_mmir.radio_devices import CosinePowerPattern, SharedShapePattern

    p = SharedShapePattern(3.0, 8.0, n_elements=4, log_gain=[0.0, 0.1, 0.2, -0.3])
    rng = np.random.default_rng(0)
    d = rng.normal(size=(6, 3))
    d[:, 0] = np.abs(d[:, 0])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    e = np.array([0, 1, 2, 3, 1, 0])
    shape = CosinePowerPattern(3.0, 8.0).gain_np(d)
    g = np.asarray(p.gain(d, e), dtype=np.float64)
    np.testing.assert_allclose(g, shape * np.exp([0.0, 0.1, 0.2, -0.3, 0.1, 0.0]), rtol=1e-5)
    np.testing.assert_allclose(p.gain_np(d, e), g, rtol=1e-5)
    assert set(p.params()) == {"log_q_az", "log_q_el", "log_gain"}
    t = p.transfer(3)              # the shape carries over, the residuals do not
    assert t.n_elements == 3 and np.allclose(t.q_np(), ([3.0], [8.0]))
    assert not np.asarray(t.log_gain).any()
    with pytest.raises(ConfigError):
        p.set_params({"log_gain": np.zeros(3)})


def test_05_per_object_materials_tie_the_vertices():
    import drjit as dr

    from sionna_mmir.fit import MMIRModel
    from sionna_mmir.scene import load_scene

    radar = dataclasses.replace(RadarConfig.awr1843(), num_samples=64)
    meshes = {"plate": square_plate([1.5, 0.0, 0.0], 0.6, 0, 2)}
    scene = load_scene(meshes, materials={"plate": "concrete"}, radar=radar)
    model = MMIRModel(scene, learn=("materials",), materials_per="object",
                      solver_options=dict(num_rays=2000, max_depth=1))
    z = model.latents()
    assert z["plate.materials"].shape == (1, 6)
    adc, handles = model.render(z, seed=0)
    dr.backward(dr.sum(dr.square(adc.real.array)) + dr.sum(dr.square(adc.imag.array)))
    grad = np.asarray(dr.grad(handles["plate.materials"].array))
    assert grad.shape == (6,) and np.abs(grad).max() > 0
    mats = np.asarray(scene.mesh_objects["plate"].vertex_materials)
    assert np.allclose(mats, mats[:1])
    with pytest.raises(ConfigError, match="materials_per"):
        MMIRModel(scene, materials_per="face")


def test_06_colocated_pose(tmp_path):
    from sionna_mmir.captures.coloradar_calib import colocated_pose

    tr = tmp_path / "transforms"
    tr.mkdir()
    q = "0.0 0.0 0.706825181105 0.707388269167"          # both sensors yawed ~90 deg
    (tr / "base_to_cascade.txt").write_text(f"0.03 0.12 -0.09\n{q}\n")
    (tr / "base_to_single_chip.txt").write_text(f"-0.145 0.09 -0.025\n{q}\n")
    p, o = colocated_pose([0, 0, 1], [0, 0, 0], tmp_path)
    # in the cascade's frame the single chip sits 3 cm behind, 17.5 cm left, 6.5 cm up
    np.testing.assert_allclose(p, [-0.03, 0.175, 1.065], atol=2e-4)
    np.testing.assert_allclose(o, [0, 0, 0], atol=1e-9)
    p2, o2 = colocated_pose([1, 2, 1], [np.pi / 2, 0, 0], tmp_path)
    np.testing.assert_allclose(p2, [1 - 0.175, 2 - 0.03, 1.065], atol=2e-4)
    np.testing.assert_allclose(o2, [np.pi / 2, 0, 0], atol=1e-9)
    with pytest.raises(ConfigError, match="not found"):
        colocated_pose([0, 0, 0], [0, 0, 0], tmp_path / "nowhere")


def test_07_sensor_radar_and_cell_stems(tmp_path):
    from sionna_mmir.benchmark_scenes import build_scene
    from sionna_mmir.compare.evidence import VARIANTS, Budget, cell_stem, load_cell
    from sionna_mmir.compare.truths import sensor_radar

    tr = tmp_path / "transforms"
    tr.mkdir()
    for name in ("cascade", "single_chip"):
        (tr / f"base_to_{name}.txt").write_text("0 0 0\n0 0 0 1\n")
    spec = build_scene("parking_lot", seed=0)
    awr = sensor_radar(spec, "awr1843", calib_dir=tmp_path)
    assert (awr.num_tx, awr.num_rx) == (3, 4)
    np.testing.assert_allclose(awr.position, spec.radar_position)
    with pytest.raises(ConfigError):
        sensor_radar(spec, "lidar", calib_dir=tmp_path)
    stem = cell_stem(tmp_path, "fit", "independent", "lab", "full", Budget(iterations=5))
    assert stem.endswith("fit_independent_lab_full_it5")
    assert load_cell(stem) == (None, None)
    assert {"table2", "full", "no_beam", "no_normals", "no_fsd", "single_bounce",
            "per_object"} <= set(VARIANTS)
    # the Sionna truth (true materials) does not read the nominal-material files
    from sionna_mmir.compare.truths import truth_path

    assert truth_path(tmp_path, "mmir", "lab", "cascade").endswith("mmir_lab_cascade.h5")
    assert not truth_path(tmp_path, "sionna", "lab", "cascade").endswith("/sionna_lab_cascade.h5")
    assert not cell_stem(tmp_path, "fit", "sionna", "lab", "sionna",
                         Budget(iterations=6)).endswith("/fit_sionna_lab_sionna_it6")
    # nor those of the one with one true material per object
    assert "truemat" not in truth_path(tmp_path, "sionna", "lab", "cascade")


def test_07b_sionna_truth_gets_the_true_per_object_materials():
    from sionna_mmir.benchmark_scenes import build_scene, true_object_materials
    from sionna_mmir.compare.truths import sionna_material_values
    from sionna_mmir.radio_materials import eps_imag_from_conductivity, itu_material

    spec = build_scene("street", seed=0)
    vals = sionna_material_values(spec)
    red = true_object_materials(spec)
    assert set(vals) == {f"{o}.{p}" for o in spec.objects
                         for p in ("relative_permittivity", "conductivity", "thickness")}
    for name, p in red.items():
        assert vals[f"{name}.relative_permittivity"] == pytest.approx(p[0])
        assert eps_imag_from_conductivity(vals[f"{name}.conductivity"], 77e9) \
            == pytest.approx(p[1])
        assert vals[f"{name}.thickness"] == pytest.approx(p[5])
    # not the nominal classes the fitters start from
    nominal = np.array([itu_material(spec.materials[o], 77e9).conductivity
                        for o in spec.objects])
    got = np.array([vals[f"{o}.conductivity"] for o in spec.objects])
    assert np.abs(np.log(got / nominal)).max() > 0.1


def test_07c_sionna_truth_renders_one_object_per_material_region():
    from sionna_mmir.benchmark_scenes import build_scene, true_region_materials
    from sionna_mmir.compare.truths import sionna_truth
    from sionna_mmir.radio_materials import eps_imag_from_conductivity

    spec = build_scene("hallway", seed=0)
    radar = RadarConfig.awr1843(num_chirps=1, position=tuple(spec.radar_position))
    cap = sionna_truth(spec, radar, samples_per_src=2000)
    regions = true_region_materials(spec)
    assert cap.metadata["regions"] == len(regions) > len(spec.objects)
    vals = cap.metadata["material_values"]
    assert {k.split(".")[0] for k in vals} == set(regions)
    for name, (_, _, p) in regions.items():
        assert eps_imag_from_conductivity(vals[f"{name}.conductivity"], 77e9) \
            == pytest.approx(p[1], rel=1e-6)
    assert np.isfinite(cap.adc).all() and np.abs(cap.adc).max() > 0


def _plate_spec():
    import types

    return types.SimpleNamespace(materials={"plate": "concrete"}), \
        {"plate": square_plate([2.0, 0.0, 0.0], 0.6, 0, 1)}


def test_08_transfer_carries_the_shape_not_the_residuals():
    from sionna_mmir.compare.evidence import TABLE2, _transfer_mmir, mmir_model

    spec, meshes = _plate_spec()
    cascade = dataclasses.replace(RadarConfig.mmwcas(), num_samples=64)
    awr = dataclasses.replace(RadarConfig.awr1843(), num_samples=64)
    fitted = mmir_model(spec, meshes, cascade, TABLE2)
    z = fitted.latents()
    assert z["beam.tx.log_gain"].shape == (12,) and z["beam.rx.log_gain"].shape == (16,)
    z["beam.tx.log_q_az"] = np.log([3.5])             # a fitted shape ...
    z["beam.tx.log_gain"] = np.linspace(-0.5, 0.5, 12)  # ... and cascade-specific residuals
    z["plate.materials"] = z["plate.materials"] + 0.3
    before, z0, after, z1 = _transfer_mmir(spec, meshes, awr, TABLE2, z)
    assert z0["beam.tx.log_q_az"] == pytest.approx(np.log(2.0))   # nominal shape before
    assert z1["beam.tx.log_q_az"] == pytest.approx(np.log(3.5))   # the shape transfers
    assert z1["beam.tx.log_gain"].shape == (3,) and not z1["beam.tx.log_gain"].any()
    assert z1["beam.rx.log_gain"].shape == (4,) and not z1["beam.rx.log_gain"].any()
    np.testing.assert_allclose(z1["plate.materials"], z["plate.materials"])   # scene physics
    assert not np.allclose(z0["plate.materials"], z1["plate.materials"])
    assert after.radar is awr and before.radar is awr


def test_09_ablation_switches_change_the_model():
    from sionna_mmir.compare.evidence import ABLATIONS, FULL, VARIANTS, mmir_model

    spec, meshes = _plate_spec()
    radar = dataclasses.replace(RadarConfig.awr1843(), num_samples=64)
    models = {v.name: mmir_model(spec, meshes, radar, v) for v in ABLATIONS}
    keys = {n: set(m.latents()) for n, m in models.items()}
    full = models["full"]
    assert full.options.diffraction and full.options.max_depth == 3
    assert {"plate.normals", "plate.materials", "beam.tx.log_q_az"} <= keys["full"]
    assert not any(k.startswith("beam.") for k in keys["no_beam"])
    assert "plate.normals" not in keys["no_normals"]
    assert not models["no_fsd"].options.diffraction
    assert models["single_bounce"].options.max_depth == 1
    n_vert = full.latents()["plate.materials"].shape[0]
    assert n_vert > 1 and models["per_object"].latents()["plate.materials"].shape == (1, 6)
    # every ablation is exactly one change away from the full model
    for v in ABLATIONS[1:]:
        diff = [f.name for f in dataclasses.fields(FULL)
                if f.name != "name" and getattr(v, f.name) != getattr(FULL, f.name)]
        assert len(diff) == 1, (v.name, diff)
    assert VARIANTS["table2"].learn == ("materials", "beam")


def _fake_results():
    rows = []
    for t, gap in (("mmir", 0.2), ("independent", -0.05)):
        for i, s in enumerate(("a", "b")):
            for m, base in (("table2", 0.7), ("sionna", 0.7)):
                after = base + (gap if m == "table2" else 0.0) + 0.01 * i
                rows.append({"truth": t, "scene": s, "model": m,
                             "before": {"ra_correlation": 0.5}, "after": {"ra_correlation": after}})
    return rows


def test_10_evidence_tables_name_the_truth(tmp_path):
    from sionna_mmir.compare.evidence_report import (cell_value, leader_notes, mean_std,
                                                     summary_lines, write_rows)

    res = _fake_results()
    lines = summary_lines(res, ["table2", "sionna"], ["mmir", "independent", "sionna"],
                          row_key="model", col_key="truth", col_label=lambda t: f"truth: {t}")
    assert lines[0] == "| | truth: mmir | truth: independent | truth: sionna |"
    assert "0.905 +/- 0.005 (n=2)" in lines[2] and "not run" in lines[2]
    notes = leader_notes(res, ["mmir", "independent"])
    assert "mmIR leads" in notes[0] and "Sionna RT leads" in notes[1]
    assert "2 paired scenes" in notes[0] and "mmIR 0.905, best on 2" in notes[0]
    assert cell_value(res, "after", truth="independent", scene="b", model="table2") == "0.660"
    assert cell_value(res, "after", truth="sionna", scene="b", model="table2") == "-"
    assert mean_std([1.0, float("nan"), 3.0]) == (2.0, 1.0, 2)
    csv_path, json_path = write_rows(res, tmp_path, "t")
    text = open(csv_path).read().splitlines()
    assert text[0].startswith("truth,scene,model,before_ra_correlation") and len(text) == 9


def test_11_model_truth_columns_and_markdown(tmp_path, capsys):
    from sionna_mmir.compare.evidence_report import model_truth_columns, write_markdown

    cols = model_truth_columns(["mmir", "independent"], "{label} [truth: {truth}]",
                               lambda sel, t, m: f"{t}/{m}/{len(sel)}")
    assert [c[0] for c in cols] == ["mmIR [truth: mmir]", "Sionna RT [truth: mmir]",
                                    "mmIR [truth: independent]", "Sionna RT [truth: independent]"]
    assert [fn([1, 2]) for _, fn in cols] == ["mmir/table2/2", "mmir/sionna/2",
                                             "independent/table2/2", "independent/sionna/2"]
    path = write_markdown(["# t", "| a |"], str(tmp_path / "o"), "x")
    assert open(path).read() == "# t\n| a |\n" and "| a |" in capsys.readouterr().out


def test_12_table_scripts_refuse_an_unknown_model(capsys):
    """``--models`` of the evidence table scripts takes ``sionna`` and the
    variant names; anything else is a usage error (exit 2, the names listed)."""
    from sionna_mmir.compare.evidence_report import table_parser

    p = table_parser("doc", "/tmp", "stem")
    assert p.parse_args(["--models", "table2_smooth,sionna"]).models == "table2_smooth,sionna"
    for bad in ("table2,bogus", ""):
        with pytest.raises(SystemExit) as exc:
            p.parse_args(["--models", bad])
        assert exc.value.code == 2
        err = capsys.readouterr().err
        assert "error: argument --models: unknown model" in err and "table2_smooth" in err

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

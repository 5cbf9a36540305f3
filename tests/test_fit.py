"""The fit loop: loss decreases, checkpoints resume to the same result, bad input."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from helpers import square_plate

from sionna_mmir.errors import ConfigError, InputValueError
from sionna_mmir.fit import MMIRModel, fit, load_checkpoint
from sionna_mmir.fit import reparam
from sionna_mmir.paths import render, to_numpy
from sionna_mmir.radar import RadarConfig
from sionna_mmir.scene import load_scene

OPTS = dict(num_rays=4000, max_depth=1)


def _plate(c, size, yaw, n=1):
    return square_plate(c, size, yaw, n)


@pytest.fixture(scope="module")
def problem():
    radar = dataclasses.replace(RadarConfig.awr1843(), num_samples=64)
    meshes = {"near": _plate([1.4, 0.3, 0], 0.6, -6), "far": _plate([2.2, -0.4, 0], 0.8, 5)}
    truth = load_scene(meshes, materials={"near": "metal", "far": "glass"}, radar=radar)
    target = to_numpy(render(truth, seed=99, **OPTS))
    return radar, meshes, target


def _model(problem):
    radar, meshes, _ = problem
    sc = load_scene(meshes, materials={"near": "concrete", "far": "concrete"}, radar=radar)
    return MMIRModel(sc, solver_options=OPTS)


def test_01_reparameterisation_round_trip_and_bounds():
    rng = np.random.default_rng(0)
    mat = np.column_stack([1 + rng.uniform(0.01, 9, 50), rng.uniform(1e-4, 3, 50),
                           rng.uniform(1e-5, 3e-3, 50), rng.uniform(1e-3, 0.05, 50),
                           rng.uniform(0.01, 0.99, 50), rng.uniform(1e-3, 0.3, 50)])
    np.testing.assert_allclose(reparam.to_physical(reparam.to_latent(mat)), mat, rtol=1e-12)
    z = rng.normal(scale=20, size=(200, 6))
    m = reparam.to_physical(z)
    assert (m[:, 0] >= 1).all() and (m[:, [1, 2, 3, 5]] >= 0).all()
    assert ((m[:, 4] >= 0) & (m[:, 4] <= 1)).all()


def _eval_loss(model, target, seeds=(1001, 1002, 1003)):
    """Mean RA loss over fixed evaluation sample sets (MC noise averaged)."""
    from sionna_mmir.metrics.ra import ra_loss
    from sionna_mmir.processing.imaging import range_azimuth

    z = model.latents()
    radar = model.radar
    out = []
    for s in seeds:
        adc, _ = model.render(z, seed=s)
        out.append(ra_loss(range_azimuth(to_numpy(adc), radar)[0],
                           range_azimuth(target, radar)[0]))
    return float(np.mean(out))


def test_02_fit_reduces_the_ra_loss(problem):
    model = _model(problem)
    before = _eval_loss(model, problem[2])
    fit(model, problem[2], iterations=15, lr=0.08, progress=False)
    after = _eval_loss(model, problem[2])
    assert after < 0.85 * before, (before, after)


def test_03_killed_fit_resumes_to_the_same_result(problem, tmp_path):
    full = fit(_model(problem), problem[2], iterations=6, lr=0.05, progress=False,
               checkpoint=str(tmp_path / "a.h5"), checkpoint_every=2)
    ck = str(tmp_path / "b.h5")
    part = fit(_model(problem), problem[2], iterations=6, lr=0.05, progress=False,
               checkpoint=ck, checkpoint_every=2, stop_after=3)     # "killed" after 3 steps
    assert part.iterations == 3 and load_checkpoint(ck)["step"] == 2
    resumed = fit(_model(problem), problem[2], iterations=6, lr=0.05, progress=False,
                  checkpoint=ck, checkpoint_every=2)
    assert resumed.resumed_from == 2 and resumed.iterations == 6
    # identical up to float32 rounding: Dr.Jit accumulates gather adjoints with
    # multi-threaded atomics, whose summation order is not fixed (two fresh
    # runs differ at the same ~1e-7 level)
    np.testing.assert_allclose(resumed.history, full.history, rtol=1e-4)
    for k in full.latents:
        np.testing.assert_allclose(resumed.latents[k], full.latents[k], rtol=1e-4, atol=1e-6)


def test_04_checkpoint_from_other_settings_is_refused(problem, tmp_path):
    ck = str(tmp_path / "c.h5")
    fit(_model(problem), problem[2], iterations=2, lr=0.05, progress=False, checkpoint=ck)
    with pytest.raises(ConfigError, match="other settings"):
        fit(_model(problem), problem[2], iterations=3, lr=0.05, progress=False, checkpoint=ck)


def test_05_bad_inputs(problem, tmp_path):
    radar = problem[0]
    m = _model(problem)
    with pytest.raises(InputValueError, match="NaN"):
        bad = problem[2].copy()
        bad[0, 0, 0, 0] = np.nan
        fit(m, bad, iterations=1, progress=False)
    with pytest.raises(InputValueError, match="constant"):
        fit(m, np.zeros((64, 32)), iterations=1, progress=False)
    with pytest.raises(InputValueError, match="target must be"):
        fit(m, np.zeros((2, 3, 4), complex), iterations=1, progress=False)
    with pytest.raises(ConfigError):
        fit(m, problem[2], iterations=0, progress=False)
    junk = tmp_path / "junk.h5"
    junk.write_bytes(b"not hdf5")
    with pytest.raises(InputValueError, match="checkpoint"):
        load_checkpoint(str(junk))
    with pytest.raises(ConfigError, match="cannot learn"):
        MMIRModel(load_scene(problem[1], radar=radar), learn=("colour",))


def test_06_pose_fit_moves_only_the_chosen_degrees_of_freedom(problem):
    radar, meshes, target = problem
    sc = load_scene(meshes, materials={"near": "metal", "far": "glass"}, radar=radar)
    with pytest.raises(ConfigError):
        MMIRModel(sc, learn=("pose",), pose_dofs=("x", "tilt"))
    model = MMIRModel(sc, learn=("pose",), solver_options=dict(OPTS, boundary=True),
                      pose_dofs=("x", "y", "yaw"))
    res = fit(model, target, iterations=2, lr=0.05, progress=False)
    pos, ori = res.latents["pose.position"], res.latents["pose.orientation"]
    assert pos[2] == 0.0 and ori[1] == 0.0 and ori[2] == 0.0
    assert np.any(pos[:2] != 0.0) and ori[0] != 0.0

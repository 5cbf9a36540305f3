"""Laplacian ("large steps") parameterisation of the learned normals
(sionna_mmir.fit.smooth_param; Nicolet et al. 2021)."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from helpers import square_plate

from sionna_mmir.errors import ConfigError
from sionna_mmir.fit import MMIRModel, fit
from sionna_mmir.fit.smooth_param import LaplacianParam, graph_laplacian
from sionna_mmir.radar import RadarConfig
from sionna_mmir.scene import load_scene


def _grid(n):
    """(n+1)^2-vertex planar grid mesh, 2 n^2 triangles."""
    xs = np.arange(n + 1)
    X, Y = np.meshgrid(xs, xs, indexing="ij")
    v = np.column_stack([X.ravel(), Y.ravel(), np.zeros(X.size)]).astype(float)
    idx = lambda i, j: i * (n + 1) + j  # noqa: E731
    f = []
    for i in range(n):
        for j in range(n):
            f += [[idx(i, j), idx(i + 1, j), idx(i + 1, j + 1)],
                  [idx(i, j), idx(i + 1, j + 1), idx(i, j + 1)]]
    return v, np.array(f)


def test_01_laplacian_of_a_triangle_and_a_quad():
    # closed form: a triangle is K3 (degree 2); a quad split along 0-2 has
    # degrees (3, 2, 3, 2) and no edge 1-3
    L = graph_laplacian(np.array([[0, 1, 2]]), 3).toarray()
    np.testing.assert_array_equal(L, [[2, -1, -1], [-1, 2, -1], [-1, -1, 2]])
    L = graph_laplacian(np.array([[0, 1, 2], [0, 2, 3]]), 5).toarray()
    np.testing.assert_array_equal(np.diag(L), [3, 2, 3, 2, 0])     # vertex 4: unused
    assert L[1, 3] == 0 and L[0, 2] == -1
    np.testing.assert_array_equal(L, L.T)
    np.testing.assert_array_equal(L.sum(axis=1), 0)


def test_02_constant_fields_pass_and_round_trip():
    v, f = _grid(12)
    par = LaplacianParam(f, len(v), lam=40.0)
    tilt = np.tile([0.01, -0.02, 1.0], (len(v), 1))          # a whole surface tilting
    np.testing.assert_allclose(par.from_latent(par.to_latent(tilt)), tilt, atol=1e-12)
    np.testing.assert_allclose(par.to_latent(tilt), tilt, atol=1e-12)   # L 1 = 0
    x = np.random.default_rng(0).normal(size=(len(v), 3))
    np.testing.assert_allclose(par.from_latent(par.to_latent(x)), x, atol=1e-10)
    # lam = 0 is the identity
    np.testing.assert_array_equal(LaplacianParam(f, len(v), 0.0).from_latent(x), x)


def test_03_pullback_matches_finite_differences():
    """d/du f(A^-1 u) by the pull-back vs central differences (quadratic f)."""
    rng = np.random.default_rng(1)
    v, f = _grid(5)
    n = len(v)
    par = LaplacianParam(f, n, lam=7.0)
    B = rng.normal(size=(20, n))
    c = rng.normal(size=(20, 3))

    def loss(u):
        r = B @ par.from_latent(u) - c
        return 0.5 * np.sum(r * r)

    u = rng.normal(size=(n, 3))
    g_x = B.T @ (B @ par.from_latent(u) - c)
    g_u = par.pullback(g_x)
    for _ in range(4):
        d = rng.normal(size=u.shape)
        h = 1e-4
        fd = (loss(u + h * d) - loss(u - h * d)) / (2 * h)
        np.testing.assert_allclose(np.sum(g_u * d), fd, rtol=1e-7)


def test_04_per_vertex_step_noise_is_averaged():
    """Adam's first step (every latent moves by +-step) on a 41 x 41 grid: with
    lam = 50 (smoothing length ~7 edges, ~150 vertices averaged) the normals move
    > 5x less than the raw parameterisation; a uniform step passes whole."""
    v, f = _grid(40)
    par = LaplacianParam(f, len(v), lam=50.0)
    step = 1e-3 * np.sign(np.random.default_rng(2).normal(size=(len(v), 3)))
    moved = par.from_latent(step)
    assert np.sqrt(np.mean(moved ** 2)) < np.sqrt(np.mean(step ** 2)) / 5
    np.testing.assert_allclose(par.from_latent(np.full((len(v), 3), 1e-3)), 1e-3, rtol=1e-9)


def test_05_bad_inputs():
    v, f = _grid(2)
    for lam in (-1.0, np.nan, np.inf):
        with pytest.raises(ConfigError, match="lam"):
            LaplacianParam(f, len(v), lam)
    with pytest.raises(ConfigError, match=r"\(F, 3\)"):
        graph_laplacian(np.zeros((3, 4), int), 9)
    with pytest.raises(ConfigError, match="outside"):
        graph_laplacian(np.array([[0, 1, 9]]), 3)
    with pytest.raises(ConfigError, match="rows"):
        LaplacianParam(f, len(v), 1.0).from_latent(np.zeros((len(v) + 1, 3)))
    radar = dataclasses.replace(RadarConfig.awr1843(), num_samples=64)
    sc = load_scene({"p": square_plate([1.5, 0, 0], 0.5, 0, 2)}, radar=radar)
    with pytest.raises(ConfigError, match="normals_smoothing"):
        MMIRModel(sc, normals_smoothing=-2.0)


@pytest.fixture(scope="module")
def plate_model():
    radar = dataclasses.replace(RadarConfig.awr1843(), num_samples=64)
    meshes = {"p": square_plate([1.6, 0.2, 0], 0.5, -8, 3)}
    sc = load_scene(meshes, materials={"p": "metal"}, radar=radar)
    # no relative-power pruning: a hard threshold is discontinuous in the
    # normals, so finite differences would see paths enter and leave the sum
    return MMIRModel(sc, learn=("normals",), normals_smoothing=20.0,
                     solver_options=dict(max_depth=1, sampling="facets", min_rel_power=0.0))


def test_06_model_latents_round_trip(plate_model):
    m = plate_model
    n0 = np.array(m.scene.mesh_objects["p"].vertex_normals)
    z = m.latents()
    np.testing.assert_allclose(m.physical(z)["p.normals"], n0, atol=1e-6)
    m.apply(z)
    np.testing.assert_allclose(np.array(m.scene.mesh_objects["p"].vertex_normals), n0, atol=1e-6)


def _ra_loss(m, tmap, z, grad=False):
    """RA loss of ``m`` at latents ``z`` (seed 5); with ``grad`` the pulled-back
    gradients w.r.t. the latents instead."""
    import drjit as dr

    from sionna_mmir.processing.drjit_ra import ra_loss_from_adc

    adc, h = m.render(z, seed=5)
    L = ra_loss_from_adc(adc, m.radar, tmap)
    if not grad:
        return float(np.asarray(dr.detach(L))[0])
    dr.backward(L)
    return m.pullback({k: np.asarray(dr.grad(v), dtype=np.float64).reshape(z[k].shape)
                       for k, v in h.items()})


def test_07_render_gradient_wrt_latents_matches_finite_differences(plate_model):
    """dL/du (handles' AD gradient, pulled back) vs central differences of the RA
    loss in u, along random directions (deterministic facet quadrature)."""
    from sionna_mmir.paths import to_numpy
    from sionna_mmir.processing.imaging import range_azimuth

    m = plate_model
    radar = m.radar
    z0 = m.latents()
    rng = np.random.default_rng(3)
    # target: the plate with smoothly tilted normals
    tilt = np.zeros_like(z0["p.normals"])
    tilt[:, 1] = 0.05
    adc_t, _ = m.render({"p.normals": z0["p.normals"] + tilt}, seed=5)
    tmap = range_azimuth(to_numpy(adc_t), radar)[0]

    def loss(z, grad=False):
        return _ra_loss(m, tmap, z, grad)

    g = loss(z0, grad=True)["p.normals"]
    assert np.abs(g).max() > 0
    for _ in range(3):
        d = rng.normal(size=g.shape) * 0.02 + tilt * rng.uniform(0.5, 1.0)
        h = 0.05
        fd = (loss({"p.normals": z0["p.normals"] + h * d})
              - loss({"p.normals": z0["p.normals"] - h * d})) / (2 * h)
        np.testing.assert_allclose(np.sum(g * d), fd, rtol=0.05, atol=1e-6 * abs(fd) + 1e-9)
    m.apply(z0)


def test_08_fit_with_smoothed_normals_resumes(plate_model, tmp_path):
    """The latents in the checkpoint are the smoothed ones; a killed fit resumes."""
    m = plate_model
    z0 = m.latents()
    from sionna_mmir.paths import to_numpy

    tilt = np.zeros_like(z0["p.normals"])
    tilt[:, 2] = 0.04
    target, _ = m.render({"p.normals": z0["p.normals"] + tilt}, seed=1)
    target = to_numpy(target)
    m.apply(z0)                    # render() leaves the scene at the latents it was given
    full = fit(m, target, iterations=4, lr=0.05, progress=False)
    m.apply(z0)
    ck = str(tmp_path / "n.h5")
    fit(m, target, iterations=4, lr=0.05, progress=False, checkpoint=ck, checkpoint_every=1,
        stop_after=2)
    m.apply(z0)
    resumed = fit(m, target, iterations=4, lr=0.05, progress=False, checkpoint=ck)
    assert resumed.resumed_from == 2
    np.testing.assert_allclose(resumed.latents["p.normals"], full.latents["p.normals"],
                               rtol=1e-4, atol=1e-6)
    m.apply(z0)
    assert np.abs(full.latents["p.normals"] - z0["p.normals"]).max() > 1e-3   # it moved


def test_09_smoothed_materials_round_trip_and_gradient():
    """materials_smoothing: physical(latents()) is the scene's materials; the RA-loss
    gradient w.r.t. the smoothed material latents matches central differences."""
    from sionna_mmir.paths import to_numpy
    from sionna_mmir.processing.imaging import range_azimuth

    radar = dataclasses.replace(RadarConfig.awr1843(), num_samples=64)
    sc = load_scene({"p": square_plate([1.6, 0.2, 0], 0.5, -8, 3)}, materials={"p": "concrete"},
                    radar=radar)
    m = MMIRModel(sc, learn=("materials",), materials_smoothing=10.0,
                  solver_options=dict(max_depth=1, sampling="facets", min_rel_power=0.0))
    mat0 = np.array(sc.mesh_objects["p"].vertex_materials, dtype=np.float64)
    z0 = m.latents()
    np.testing.assert_allclose(m.physical(z0)["p.materials"], mat0, rtol=1e-5)
    k = "p.materials"
    shift = np.zeros_like(z0[k])
    shift[:, 0] = 0.3                                      # a uniform change of eps'
    adc_t, _ = m.render({k: z0[k] + shift}, seed=5)
    tmap = range_azimuth(to_numpy(adc_t), radar)[0]

    def loss(z, grad=False):
        out = _ra_loss(m, tmap, z, grad)
        return out[k] if grad else out

    g = loss(z0, grad=True)
    assert np.abs(g).max() > 0
    rng = np.random.default_rng(4)
    for _ in range(2):
        d = rng.normal(size=g.shape) * 0.05 + shift
        h = 0.05
        fd = (loss({k: z0[k] + h * d}) - loss({k: z0[k] - h * d})) / (2 * h)
        np.testing.assert_allclose(np.sum(g * d), fd, rtol=0.05, atol=1e-9)
    with pytest.raises(ConfigError, match="materials_smoothing"):
        MMIRModel(sc, materials_smoothing=np.nan)

"""Corner reflectors (multi-bounce specular chains) against closed forms and brute-force PO.

References (independent of the solver):

* triangular trihedral of edge ``a`` on its symmetry axis:
  ``sigma = 4 pi a^4 / (3 lambda^2)`` (physical optics; Knott, Shaeffer &
  Tuley, *Radar Cross Section*, Table 6.1)
* right-angled dihedral of two ``a x b`` plates seen along its bisector at
  normal incidence to the fold: ``sigma = 8 pi a^2 b^2 / lambda^2`` (same table)
* in the near field, where those far-field forms do not hold: a brute-force
  physical-optics sum over the first plate of every chain with image theory
  (:mod:`corner_po`, NumPy, a midpoint rule on 0.5 mm cells)

The sizes of the closed-form cases keep the brute-force sum within 0.12 dB
of the closed form (a trihedral of 0.07 m at 2 m, 0.1 m at 5 m; a dihedral
of 0.035 m at 2 m, 0.05 m at 5 m); the near-field cases (0.1 m at 2 m) sit
0.6 dB (trihedral) and 8.4 dB (dihedral) under it.  Every case runs at depth
3, for an unsubdivided mesh and one whose triangles are split twice 4:1,
with the facet quadrature and with random rays in a cone about the target.
"""
from __future__ import annotations

import functools

import numpy as np
import pytest

import sionna_mmir  # noqa: F401
from sionna_mmir.radar import RadarConfig
from sionna_mmir.scene import load_scene

import corner_po
from sionna_mmir.paths import RadarPathSolver  # noqa: E402
from helpers import assert_same_paths  # noqa: E402

C = 299_792_458.0
F0 = 77e9
LAM = C / F0
DOMINANT = {"trihedral": 3, "dihedral": 2}


def _closed_form_dbsm(kind, a):
    sigma = (4 * np.pi * a ** 4 / (3 * LAM ** 2) if kind == "trihedral"
             else 8 * np.pi * a ** 4 / LAM ** 2)
    return 10 * np.log10(sigma)


def _dbsm(value, R):
    return 10 * np.log10(np.abs(value) ** 2 * (4 * np.pi) ** 3 * R ** 4 / LAM ** 2)


@functools.lru_cache(maxsize=None)
def _po_reference(kind, a, R):
    """Brute-force PO coefficient of the dominant depth (radar at the origin)."""
    plates, _ = corner_po.corner_target(kind, a, [R, 0.0, 0.0])
    d = DOMINANT[kind]
    return corner_po.corner_field(plates, np.zeros(3), np.zeros(3), LAM, depths=(d,), h=5e-4)[d]


def _render(kind, a, R, subdiv, sampling):
    """The target with its boresight on the 1 x 1 radar at the origin:
    ``(all paths' coefficient, the dominant depth's)`` at 77 GHz."""
    _, meshes = corner_po.corner_target(kind, a, [R, 0.0, 0.0], subdiv=subdiv)
    scene = load_scene(meshes, materials={k: "metal" for k in meshes},
                       radar=RadarConfig.dense(1, 1))
    p = RadarPathSolver()(scene, max_depth=3, sampling=sampling, num_rays=200_000, seed=11,
                          cone_angle_deg=float(np.degrees(np.arctan(1.2 * a / R))),
                          scattering=False, tx_pattern="iso", rx_pattern="iso")
    amp, tau, _ = p.numpy()
    terms = amp[0, 0] * np.exp(2j * np.pi * F0 * tau[0, 0])
    return terms.sum(), terms[p.depth == DOMINANT[kind]].sum()


CASES = [(kind, a, R, subdiv, sampling)
         for kind, sizes in (("trihedral", ((0.07, 2.0), (0.1, 5.0))),
                             ("dihedral", ((0.035, 2.0), (0.05, 5.0))))
         for a, R in sizes for subdiv in (0, 2) for sampling in ("facets", "random")]


@pytest.mark.parametrize("kind,a,R,subdiv,sampling", CASES)
def test_01_corner_reflectors_match_their_closed_forms(kind, a, R, subdiv, sampling):
    """Trihedral on its axis and dihedral along its bisector: RCS within 1 dB
    of the closed form, the dominant chain within 1 dB of brute-force PO."""
    total, dominant = _render(kind, a, R, subdiv, sampling)
    expected = _closed_form_dbsm(kind, a)
    assert abs(_dbsm(total, R) - expected) < 1.0, (_dbsm(total, R), expected)
    ref = _po_reference(kind, a, R)
    assert abs(20 * np.log10(abs(dominant) / abs(ref))) < 1.0, (abs(dominant), abs(ref))


@pytest.mark.parametrize("kind", ["trihedral", "dihedral"])
@pytest.mark.parametrize("subdiv", [0, 2])
@pytest.mark.parametrize("sampling", ["facets", "random"])
def test_02_corner_reflectors_in_their_near_field_match_brute_force_physical_optics(
        kind, subdiv, sampling):
    """0.1 m corners at 2 m: the Fresnel zones across the aperture take the
    far-field forms 0.6 dB (trihedral) and 8.4 dB (dihedral) away; the chain
    matches the brute-force PO sum within 1 dB."""
    a, R = 0.1, 2.0
    _, dominant = _render(kind, a, R, subdiv, sampling)
    ref = _po_reference(kind, a, R)
    assert abs(20 * np.log10(abs(dominant) / abs(ref))) < 1.0, (abs(dominant), abs(ref))
    assert _dbsm(ref, R) < _closed_form_dbsm(kind, a) - 0.4          # (a near-field case)


def test_03_facet_chain_is_independent_of_the_seed_and_replays():
    """The facet quadrature's chains are deterministic (no seed) and a replay
    of their frozen samples (lit footprints, re-aimed corners) reproduces
    them, to float32 rounding."""
    _, meshes = corner_po.corner_target("trihedral", 0.1, [2.0, 0.0, 0.0])
    scene = load_scene(meshes, materials={k: "metal" for k in meshes},
                       radar=RadarConfig.dense(1, 1))
    opts = dict(max_depth=3, sampling="facets", cone_angle_deg=4.0, scattering=False,
                tx_pattern="iso", rx_pattern="iso")
    s = RadarPathSolver()
    p, q = s(scene, seed=0, **opts), s(scene, seed=5, **opts)
    r = s(scene, samples=list(p.samples), **opts)
    assert_same_paths(p, q, r)

"""Sionna RT scenes in (objects, XML paths, built-in scenes), the 77 GHz material
policy, Transmitter <-> RadarConfig, and scenes to PLY and back."""
import warnings

import numpy as np
import pytest

import sionna_mmir
from sionna_mmir.errors import ConfigError, InputValueError
from sionna_mmir.paths.render import to_numpy
from sionna_mmir.radar.config import RadarConfig
from sionna_mmir.radio_materials import SURFACE_DEFAULTS, itu_material

rt = pytest.importorskip("sionna.rt")

from sionna_mmir.radar.sionna_devices import radar_from_sionna, radar_to_sionna  # noqa: E402
from sionna_mmir.fit.export import fitted_scene  # noqa: E402
from sionna_mmir.scene.ply_export import (is_scene_ply,  # noqa: E402
                                          save_scene_ply)
from sionna_mmir.scene.sionna_import import OutOfBandMaterialWarning  # noqa: E402

BUILT_IN = ["simple_street_canyon", "floor_wall", "box", "simple_reflector", "box_one_screen"]

TWO_PLATES = """<scene version="2.1.0">
  <bsdf type="itu-radio-material" id="wallmat">
    <string name="type" value="{wall}"/> <float name="thickness" value="0.25"/>
  </bsdf>
  <bsdf type="radio-material" id="custom">
    <float name="relative_permittivity" value="3.5"/> <float name="conductivity" value="0.02"/>
    <float name="thickness" value="0.03"/>
  </bsdf>
  <shape type="ply" id="wall">
    <string name="filename" value="square.ply"/>
    <transform name="to_world"><rotate y="1" angle="-90"/><translate x="{x}" y="0.5"/></transform>
    <ref id="wallmat" name="bsdf"/>
  </shape>
  <shape type="ply" id="panel">
    <string name="filename" value="square.ply"/>
    <transform name="to_world"><scale value="0.5"/><translate z="-1"/></transform>
    <ref id="custom" name="bsdf"/>
  </shape>
</scene>"""


def _quiet_load(src, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OutOfBandMaterialWarning)
        return sionna_mmir.load_scene(src, **kw)


def _arrays(scene):
    return {n: (np.array(o.vertex_positions), np.array(o.vertex_normals),
                np.array(o.vertex_materials), np.asarray(o.faces), o.material)
            for n, o in scene.mesh_objects.items()}


def _write(tmp_path, name, text):
    """Write ``text`` to ``tmp_path/name`` beside ``square.ply`` (the 2 m square
    ``z = 0``, ``|x|, |y| <= 1`` that the XML scenes reference)."""
    import trimesh

    square = trimesh.Trimesh([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]],
                             [[0, 1, 2], [0, 2, 3]], process=False)
    square.export(str(tmp_path / "square.ply"))
    p = tmp_path / name
    p.write_text(text)
    return str(p)


def test_01_built_in_scenes_listed():
    for name in BUILT_IN:
        assert str(getattr(rt.scene, name)).endswith(".xml")


def test_02_sionna_scene_object_renders_a_cascade_frame():
    radar = RadarConfig.mmwcas(num_chirps=1, position=(0.0, 0.0, 1.5))
    scene = _quiet_load(rt.load_scene(rt.scene.simple_street_canyon), radar=radar)
    assert isinstance(scene, sionna_mmir.RadarScene)
    adc = to_numpy(sionna_mmir.render(scene, num_rays=2000, max_depth=2, seed=1))
    assert adc.shape == radar.adc_shape
    assert np.isfinite(adc).all() and np.abs(adc).max() > 0


@pytest.mark.parametrize("name", BUILT_IN)
def test_03_xml_path_equals_scene_object(name):
    a = _arrays(_quiet_load(getattr(rt.scene, name)))
    b = _arrays(_quiet_load(rt.load_scene(getattr(rt.scene, name))))
    assert a.keys() == b.keys()
    for k in a:
        for x, y in zip(a[k], b[k]):
            assert np.array_equal(x, y) if isinstance(x, np.ndarray) else x == y


@pytest.mark.parametrize("name", BUILT_IN)
def test_04_meshes_match_sionna(name):
    import mitsuba as mi

    sc = rt.load_scene(getattr(rt.scene, name))
    shared = _quiet_load(sc, shading="shared")
    flat = _quiet_load(sc)          # default "sionna": face_normals=true -> flat
    assert len(shared.mesh_objects) == len(sc.objects)
    for obj in sc.objects.values():
        key = obj.name if not obj.name.startswith("no-name-") else \
            f"merged-{obj.radio_material.name}"
        v = np.array(mi.traverse(obj.mi_mesh)["vertex_positions"]).reshape(-1, 3)
        mine = np.array(shared.mesh_objects[key].vertex_positions)
        assert mine.shape[0] == obj.mi_mesh.vertex_count() and np.array_equal(mine, v)
        assert len(shared.mesh_objects[key].faces) == obj.mi_mesh.face_count()
        f = flat.mesh_objects[key]
        assert np.array(f.vertex_positions).shape[0] == 3 * obj.mi_mesh.face_count()
        bb = np.array(f.vertex_positions)
        assert np.allclose([bb.min(0), bb.max(0)], [v.min(0), v.max(0)], atol=0)
        tri = bb[f.faces]
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        assert np.allclose(np.array(f.vertex_normals)[f.faces[:, 0]], n, atol=1e-5)


def test_05_world_transform_applied(tmp_path):
    path = _write(tmp_path, "plates.xml", TWO_PLATES.format(wall="concrete", x=4.0))
    scene = sionna_mmir.load_scene(path)
    wall = np.array(scene.mesh_objects["wall"].vertex_positions)
    assert np.allclose(wall[:, 0], 4.0, atol=1e-6)            # rotated into the y-z plane
    assert np.allclose(sorted(set(np.round(wall[:, 1], 5))), [-0.5, 1.5])
    sc = rt.load_scene(path)
    sc.get("panel").position = [1.0, 2.0, 3.0]              # moved after loading
    panel = np.array(sionna_mmir.load_scene(sc).mesh_objects["panel"].vertex_positions)
    assert np.allclose(panel.mean(0), [1.0, 2.0, 3.0], atol=1e-6)


def test_06_material_mapping_in_band_and_custom(tmp_path):
    path = _write(tmp_path, "plates.xml", TWO_PLATES.format(wall="concrete", x=4.0))
    with warnings.catch_warnings():
        warnings.simplefilter("error", OutOfBandMaterialWarning)   # concrete is in band
        scene = sionna_mmir.load_scene(path)
    wall = np.array(scene.mesh_objects["wall"].vertex_materials)[0]
    m, s = itu_material("concrete", 77e9), SURFACE_DEFAULTS["concrete"]
    assert scene.mesh_objects["wall"].material == "concrete"
    assert np.allclose(wall, [m.eps_real, m.eps_imag, s.sigma_h, s.l_c, s.tau, 0.25], rtol=1e-6)
    panel = np.array(scene.mesh_objects["panel"].vertex_materials)[0]
    eps_imag = 0.02 / (2 * np.pi * 77e9 * 8.8541878128e-12)
    assert np.allclose(panel[[0, 1, 5]], [3.5, eps_imag, 0.03], rtol=1e-6)


def test_07_77ghz_policy_extrapolates_with_warning(tmp_path):
    path = _write(tmp_path, "plates.xml", TWO_PLATES.format(wall="brick", x=4.0))
    with pytest.warns(OutOfBandMaterialWarning, match=r"object 'wall'.*'brick'.*1-40 GHz.*77 GHz"):
        scene = sionna_mmir.load_scene(path)
    brick = np.array(scene.mesh_objects["wall"].vertex_materials)[0]
    sigma = 0.0238 * 77.0 ** 0.16                              # the 1-40 GHz power law at 77
    assert brick[0] == pytest.approx(3.91, rel=1e-6)
    assert brick[1] == pytest.approx(17.975 * sigma / 77.0, rel=1e-3)
    with warnings.catch_warnings():
        warnings.simplefilter("error", OutOfBandMaterialWarning)
        sionna_mmir.load_scene(path, allow_out_of_band=True)  # silent
    with pytest.raises(ConfigError, match=r"object 'wall'.*'brick'.*1-40 GHz.*materials="):
        sionna_mmir.load_scene(path, allow_out_of_band=False)
    # override by object name, by material name, or with six values
    for key in ("wall", "wallmat"):
        sc = sionna_mmir.load_scene(path, allow_out_of_band=False, materials={key: "concrete"})
        assert sc.mesh_objects["wall"].material == "concrete"
    six = [4.0, 0.1, 1e-4, 5e-3, 0.6, 0.1]
    sc = sionna_mmir.load_scene(path, materials={"wall": six}, allow_out_of_band=False)
    assert np.allclose(np.array(sc.mesh_objects["wall"].vertex_materials)[0], six, rtol=1e-6)


def test_08_p2040_4_types_and_street_canyon_policy():
    with pytest.warns(OutOfBandMaterialWarning) as rec:
        scene = sionna_mmir.load_scene(rt.scene.simple_street_canyon)
    named = sorted({str(w.message).split("material '")[1].split("'")[0] for w in rec})
    assert named == ["brick", "marble"]
    assert {o.material for o in scene.mesh_objects.values()} == {
        "concrete", "brick", "marble", "wood", "glass"}
    mat = rt.ITURadioMaterial("asphalt", "asphalt_concrete", thickness=0.05)
    from sionna_mmir.scene.sionna_import import material_parameters

    with pytest.warns(OutOfBandMaterialWarning, match="asphalt_concrete.*1-40 GHz"):
        label, vals = material_parameters(mat, 77e9)
    assert label == "asphalt_concrete" and vals[0] == pytest.approx(4.83)
    assert vals[5] == pytest.approx(0.05, rel=1e-6)
    assert vals[2] == SURFACE_DEFAULTS["concrete"].sigma_h


def test_09_transmitter_to_radar_pose_round_trip():
    radar = RadarConfig.awr1843(position=(1.0, -2.0, 1.5), orientation=(0.4, -0.1, 0.05))
    sc = rt.load_scene(rt.scene.floor_wall)
    radar_to_sionna(radar, sc)
    back = radar_from_sionna(sc, base="awr1843")
    assert np.allclose(back.position, radar.position, atol=1e-6)
    assert np.allclose(back.orientation, radar.orientation, atol=1e-6)
    assert np.allclose(back.tx_positions, radar.tx_positions, rtol=1e-6, atol=1e-9)
    assert np.allclose(back.rx_positions, radar.rx_positions, rtol=1e-6, atol=1e-9)
    assert back.slope == radar.slope and back.adc_shape == radar.adc_shape
    # a plain transmitter (no arrays): pose only, the base's layout; load_scene picks it up
    sc = rt.load_scene(rt.scene.floor_wall)
    sc.add(rt.Transmitter("tx", position=[0.5, 0.0, 1.0], orientation=[np.pi / 2, 0.0, 0.0]))
    scene = _quiet_load(sc)
    assert np.allclose(scene.radar.position, [0.5, 0.0, 1.0])
    assert np.allclose(np.array(scene.orientation), [np.pi / 2, 0, 0], atol=1e-6)
    assert scene.radar.tx_positions.shape == RadarConfig.mmwcas().tx_positions.shape


def test_10_receiver_offset_and_bad_devices():
    sc = rt.load_scene()
    sc.tx_array = rt.PlanarArray(num_rows=1, num_cols=2, pattern="iso", polarization="cross")
    sc.rx_array = rt.PlanarArray(num_rows=2, num_cols=2, pattern="iso", polarization="V")
    with pytest.raises(ConfigError, match="no Transmitter"):
        radar_from_sionna(sc)
    sc.add(rt.Transmitter("tx", position=[0.0, 0.0, 1.0], orientation=[np.pi / 2, 0, 0]))
    sc.add(rt.Receiver("rx", position=[-0.1, 0.0, 1.0], orientation=[np.pi / 2, 0, 0]))
    r = radar_from_sionna(sc, base="awr1843")
    assert r.num_tx == 2 and r.num_rx == 4                  # dual-polarised positions once
    lam = 2 * r.half_wavelength
    assert np.allclose(np.ptp(r.tx_positions[:, 1]), 0.5 * lam)
    assert np.allclose(r.rx_positions.mean(0), [0.0, 0.1, 0.0], atol=1e-7)  # -x world = +y radar
    sc.add(rt.Transmitter("tx2", position=[0.0, 0.0, 1.0]))
    with pytest.raises(ConfigError, match="name one with transmitter="):
        radar_from_sionna(sc)
    sc.get("rx").orientation = [0.0, 0.0, 0.0]
    with pytest.raises(ConfigError, match="oriented"):
        radar_from_sionna(sc, transmitter="tx")
    with pytest.raises(ConfigError, match="unknown radar preset"):
        radar_from_sionna(sc, base="nope", transmitter="tx")


def test_11_bad_inputs(tmp_path):
    missing = str(tmp_path / "nope.xml")
    with pytest.raises(InputValueError, match=r"nope\.xml: scene file does not exist"):
        sionna_mmir.load_scene(missing)
    empty = _write(tmp_path, "empty.xml", '<scene version="2.1.0"></scene>')
    rect = _write(tmp_path, "rect.xml", TWO_PLATES.format(wall="concrete", x=1).replace(
        '<shape type="ply" id="wall">\n    <string name="filename" value="square.ply"/>',
        '<shape type="rectangle" id="wall">'))
    wall = np.array(sionna_mmir.load_scene(rect).mesh_objects["wall"].vertex_positions)
    assert np.allclose([wall.min(0), wall.max(0)], [[1, -0.5, -1], [1, 1.5, 1]], atol=1e-6)
    with pytest.raises(InputValueError, match=r"empty\.xml: the scene has no shapes"):
        sionna_mmir.load_scene(empty)
    bad = _write(tmp_path, "bad.xml", TWO_PLATES.format(wall="unobtainium", x=4.0))
    with pytest.raises(ConfigError, match=r"bad\.xml: .*unobtainium"):
        sionna_mmir.load_scene(bad)
    broken = _write(tmp_path, "broken.xml", "<scene version='2.1.0'><shape")
    with pytest.raises(InputValueError, match=r"broken\.xml: Sionna cannot load"):
        sionna_mmir.load_scene(broken)
    ok = _write(tmp_path, "ok.xml", TWO_PLATES.format(wall="concrete", x=4.0))
    sc = rt.load_scene(ok)
    sc.get("wall").radio_material = rt.AbsorberRadioMaterial("absorber")
    with pytest.raises(ConfigError, match="object 'wall'.*absorber.*materials="):
        sionna_mmir.load_scene(sc)
    assert sionna_mmir.load_scene(sc, materials={"absorber": "metal"}).mesh_objects[
        "wall"].material == "metal"
    with pytest.raises(ConfigError, match="unknown objects / materials"):
        sionna_mmir.load_scene(ok, materials={"roof": "metal"})
    with pytest.raises(ConfigError, match="shading"):
        sionna_mmir.load_scene(ok, shading="gouraud")
    with pytest.raises(ConfigError, match="Sionna scenes only"):
        sionna_mmir.load_scene({"m": str(tmp_path / "x.ply")}, shading="flat")


def test_12_scene_ply_round_trip_exact(tmp_path):
    scene = _quiet_load(rt.scene.simple_street_canyon)
    obj = scene.mesh_objects["floor"]
    mats = np.array(obj.vertex_materials)
    mats[:, 0] = np.linspace(2.0, 9.0, len(mats))            # per-vertex values survive
    from sionna_mmir.scene.scene import _tensor

    obj.vertex_materials = _tensor(mats)
    path = save_scene_ply(scene, tmp_path / "canyon.ply")
    assert is_scene_ply(path) and not is_scene_ply(rt.scene.low_poly_car)
    with pytest.raises(FileExistsError):
        save_scene_ply(scene, path)
    back = sionna_mmir.load_scene(path)
    a, b = _arrays(scene), _arrays(back)
    assert list(a) == list(b)
    for k in a:
        for x, y in zip(a[k], b[k]):
            assert np.array_equal(x, y) if isinstance(x, np.ndarray) else x == y
    import trimesh

    viewed = trimesh.load(path, process=False)               # an ordinary PLY to viewers
    assert len(viewed.faces) == sum(len(o.faces) for o in scene.mesh_objects.values())
    radar = RadarConfig.awr1843(position=(0.0, 0.0, 1.5))
    r1 = to_numpy(sionna_mmir.render(scene, radar, num_rays=500, max_depth=1, seed=3))
    r2 = to_numpy(sionna_mmir.render(back, radar, num_rays=500, max_depth=1, seed=3))
    assert np.array_equal(r1, r2)


def test_13_scene_ply_bad_files(tmp_path):
    scene = _quiet_load(rt.scene.floor_wall)
    path = str(save_scene_ply(scene, tmp_path / "fw.ply"))
    data = open(path, "rb").read()
    cut = tmp_path / "cut.ply"
    cut.write_bytes(data[:-10])
    with pytest.raises(InputValueError, match=r"cut\.ply: truncated"):
        sionna_mmir.load_scene(str(cut))
    with pytest.raises(ConfigError, match="carries per-vertex materials"):
        sionna_mmir.load_scene(path, materials={"wall": "metal"})


def test_14_fitted_scene_to_ply(tmp_path):
    from sionna_mmir.fit import MMIRModel, fit
    from sionna_mmir.fit.fitter import save_checkpoint  # noqa: F401  (format of fit --out)

    radar = RadarConfig.awr1843(position=(0.0, 0.0, 1.0))
    truth = _quiet_load(rt.scene.floor_wall, radar=radar, materials={"wall": "metal"})
    target = to_numpy(sionna_mmir.render(truth, radar, num_rays=3000, max_depth=1, seed=0))
    scene = _quiet_load(rt.scene.floor_wall, radar=radar)
    model = MMIRModel(scene, learn=("materials", "normals"),
                      solver_options=dict(num_rays=3000, max_depth=1))
    ck = tmp_path / "fit_mmir.h5"
    res = fit(model, target, iterations=2, progress=False, checkpoint=str(ck))
    out = fitted_scene(model, str(ck))
    expect = model.physical(res.latents)
    for name in ("wall", "floor"):
        got = np.array(out.mesh_objects[name].vertex_materials)
        assert np.allclose(got, expect[f"{name}.materials"], rtol=1e-6)
    path = save_scene_ply(out, tmp_path / "fitted.ply")
    back = sionna_mmir.load_scene(path, radar=radar)
    for name in ("wall", "floor"):
        assert np.array_equal(np.array(back.mesh_objects[name].vertex_materials),
                              np.array(out.mesh_objects[name].vertex_materials))
    r1 = to_numpy(sionna_mmir.render(out, radar, num_rays=800, max_depth=1, seed=5))
    r2 = to_numpy(sionna_mmir.render(back, radar, num_rays=800, max_depth=1, seed=5))
    assert np.array_equal(r1, r2)
    with pytest.raises(ConfigError, match="do not belong"):
        fitted_scene(model, {"roof.materials": np.zeros((4, 6))})

"""Scene loading by path: OBJ, PLY and glTF/GLB written with trimesh, Mitsuba XML, and
every failure mode raising one DyngiError that names the file and the problem."""
from __future__ import annotations

import numpy as np
import pytest

from conftest import shared_scene
from dyngi.backend import mi
from dyngi.errors import DyngiError
from dyngi.scene import builtin_names, load_scene
from dyngi.techniques.base import to_image
from dyngi.techniques.path import render_paths

RES = (32, 24)


def render(sc, res=RES, spp=4):
    sc.at(0.0)
    L, _ = render_paths(sc, sc.camera(0.0), res, spp=spp, seed=0, frame_index=0, max_depth=4, rr_depth=3)
    return to_image(L, res)


def write_box(path):
    import trimesh

    m = trimesh.creation.box(extents=(1.0, 2.0, 0.5))
    m.apply_translation((3.0, 1.0, -2.0))
    m.export(str(path))
    return m


@pytest.mark.parametrize("ext", ["obj", "ply", "glb"])
def test_mesh_files_load_and_render(tmp_path, ext):
    path = tmp_path / f"box.{ext}"
    m = write_box(path)
    sc = load_scene(str(path))
    assert sc.name == "box" and sc.source == str(path)
    lo, hi = (np.asarray(a) for a in sc.meta.bounds)
    np.testing.assert_allclose(lo, m.bounds[0], atol=1e-5)
    np.testing.assert_allclose(hi, m.bounds[1], atol=1e-5)
    assert len(sc.meta.emitters) >= 1  # the white sky added for unlit files
    assert not sc.is_animated
    plo, phi = (np.asarray(a) for a in sc.meta.probe_box)
    assert np.all(plo >= lo) and np.all(phi <= hi) and np.all(plo < phi)
    img = render(sc)
    assert np.all(np.isfinite(img)) and img.min() >= 0.0
    assert img.mean() > 0.05
    # the box is in the middle of the default camera's view: centre pixels see it, lit by the sky
    # (grey albedo 0.6, or 0.8 for glTF without material, under a unit white sky: radiance <= albedo)
    centre = img[RES[1] // 2 - 2:RES[1] // 2 + 2, RES[0] // 2 - 2:RES[0] // 2 + 2].mean()
    assert 0.05 < centre < (0.85 if ext == "glb" else 0.65)
    corner = img[0, 0].mean()  # background: the white sky itself
    assert corner == pytest.approx(1.0, abs=1e-5)


def test_gltf_emissive_material_becomes_area_light(tmp_path):
    import trimesh

    box = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    lamp = trimesh.creation.box(extents=(0.2, 0.2, 0.2))
    lamp.apply_translation((0.0, 1.5, 0.0))
    lamp.visual = trimesh.visual.TextureVisuals(
        material=trimesh.visual.material.PBRMaterial(baseColorFactor=[0, 0, 0, 255], emissiveFactor=[5.0, 4.0, 3.0]))
    path = tmp_path / "lit.glb"
    trimesh.Scene([box, lamp]).export(str(path))
    sc = load_scene(str(path))
    assert [e["type"] for e in sc.meta.emitters] and len(sc.meta.emitters) == 1  # the lamp, no sky
    assert any(k.endswith("emitter.radiance.value") for k in sc.params.keys())


# -- failures --------------------------------------------------------------------------
def _raises(target, *fragments):
    with pytest.raises(DyngiError) as ei:
        load_scene(target)
    msg = str(ei.value)
    assert "\n" not in msg.strip(), "error must be one line"
    for f in fragments:
        assert f.lower() in msg.lower(), f"'{f}' not in: {msg}"
    return msg


def test_missing_file(tmp_path):
    p = tmp_path / "nothere.obj"
    _raises(str(p), str(p), "does not exist")


def test_unknown_name_lists_valid_scenes():
    msg = _raises("no-such-scene", "no-such-scene")
    for name in builtin_names():
        assert name in msg


def test_bad_extension(tmp_path):
    p = tmp_path / "scene.txt"
    p.write_text("hello")
    _raises(str(p), str(p), ".obj", ".xml")


@pytest.mark.parametrize("ext, data", [
    ("ply", bytes(range(256)) * 2),
    ("glb", b"glTF" + bytes(range(200))),
    ("xml", b"<scene version='3.0.0'><shape type="),
    ("obj", b"v 0 0 0\nv 1 0 0\nf 1 2 7\n"),
])
def test_corrupt_file(tmp_path, ext, data):
    p = tmp_path / f"broken.{ext}"
    p.write_bytes(data)
    _raises(str(p), str(p))


def test_obj_with_nan_vertex(tmp_path):
    p = tmp_path / "nan.obj"
    p.write_text("v 0 0 0\nv 1 0 0\nv nan 1 0\nv 0 0 1\nf 1 2 3\nf 1 3 4\n")
    msg = _raises(str(p), "nan.obj")
    assert any(w in msg.lower() for w in ("nan", "invalid vertex")), msg


def test_gltf_with_nan_vertex(tmp_path):
    import trimesh

    m = trimesh.Trimesh(vertices=[[0, 0, 0], [1, 0, 0], [np.nan, 1, 0]], faces=[[0, 1, 2]], process=False)
    p = tmp_path / "nan.glb"
    m.export(str(p))
    _raises(str(p), "nan.glb", "NaN")


# -- real scene (optional) -----------------------------------------------------------------
def test_real_cornell_box_xml():
    path = shared_scene("cornell-box/scene_mi3.xml")
    sc = load_scene(path)
    assert len(sc.meta.emitters) >= 1
    # the camera taken from the XML sensor generates the sensor's own rays
    sensor = sc.mi_scene.sensors()[0]
    w, h = (int(v) for v in sensor.film().crop_size())
    res = (w, h)
    px = np.array([0, w - 1, (h // 2) * w + w // 2, (h - 1) * w, h * w - 1], np.int64)
    jitter = mi.Point2f(0.5, 0.5)
    ours = sc.camera(0.0).sample_rays(res, mi.UInt32(px.astype(np.uint32)), jitter)
    film_pos = mi.Point2f(mi.Float(((px % w) + 0.5) / w), mi.Float(((px // w) + 0.5) / h))
    theirs, _ = sensor.sample_ray(0.0, 0.5, film_pos, mi.Point2f(0.5, 0.5))
    # Mitsuba starts its rays on the near-clip plane: same line, origins within the clip distance
    d_ours = np.broadcast_to(np.array(ours.d), (3, len(px)))
    np.testing.assert_allclose(d_ours, np.array(theirs.d), atol=1e-4)
    np.testing.assert_allclose(np.broadcast_to(np.array(ours.o), (3, len(px))), np.array(theirs.o), atol=0.02)
    img = render(sc, res=(24, 24), spp=4)
    assert np.all(np.isfinite(img)) and img.mean() > 0.05


def test_bounds_include_shapes_mitsuba_merged(backend, tmp_path):
    """Mitsuba merges rectangles that share a BSDF into one mesh whose bbox() is invalid, so the scene's
    own bbox() misses them; the probe volume must still span the room (it sat inside the cube before)."""
    from dyngi.scene import load_scene

    rect = ('<shape type="rectangle"><transform name="to_world"><scale x="2" y="2"/>{}</transform>'
            '<ref id="w"/></shape>')
    xml = ('<scene version="3.0.0"><bsdf type="diffuse" id="w"/>'
           + rect.format('<rotate x="1" angle="-90"/>')
           + rect.format('<translate y="2" z="-2"/>')
           + '<shape type="cube"><transform name="to_world"><scale value="0.2"/><translate x="1" y="0.2"/>'
             '</transform><ref id="w"/></shape>'
           + '<emitter type="constant"/></scene>')
    p = tmp_path / "room.xml"
    p.write_text(xml)
    lo, hi = load_scene(str(p)).meta.bounds
    assert lo[0] == pytest.approx(-2.0, abs=1e-5) and hi[0] == pytest.approx(2.0, abs=1e-5)
    assert lo[2] == pytest.approx(-2.0, abs=1e-5) and hi[1] == pytest.approx(4.0, abs=1e-5)


# -- keyframe sidecars of XML scenes (dyngi.scene.keyframes), found or given ---------------------------------
XML = """<scene version="3.0.0">
  <shape type="rectangle" id="floor"><transform name="to_world"><rotate x="1" angle="-90"/><scale value="3"/></transform>
    <bsdf type="diffuse"/></shape>
  <shape type="cube" id="box"><transform name="to_world"><scale value="0.3"/><translate y="0.3"/></transform>
    <bsdf type="diffuse"/></shape>
  <emitter type="constant"/>
  <sensor type="perspective" id="cam"><float name="fov" value="50"/>
    <transform name="to_world"><lookat origin="0, 2, 5" target="0, 0, 0" up="0, 1, 0"/></transform></sensor>
</scene>
"""
TOML = """[shapes.box]
keys = [ { t = 0.0, translate = [0.0, 0.0, 0.0] }, { t = 1.0, translate = [%s, 0.0, 0.0] } ]
"""


def test_xml_sidecar_found_beside_the_file_or_given(tmp_path, capsys):
    xml = tmp_path / "room.xml"
    xml.write_text(XML)
    sc = load_scene(str(xml))
    assert not sc.is_animated and "animation:" not in capsys.readouterr().out
    (tmp_path / "room.anim.toml").write_text(TOML % "1.0")
    sc = load_scene(str(xml), fps=12)
    assert capsys.readouterr().out.strip() == f"animation: {tmp_path / 'room.anim.toml'}"
    assert sc.is_animated and sc.fps == 12 and sc.frame_time(6) == 0.5
    x0 = np.asarray(sc.at(0.0).params["box.vertex_positions"]).reshape(-1, 3)[:, 0].mean()
    x1 = np.asarray(sc.at(1.0).params["box.vertex_positions"]).reshape(-1, 3)[:, 0].mean()
    assert x1 - x0 == pytest.approx(1.0, abs=1e-5)
    other = tmp_path / "other.toml"
    other.write_text(TOML % "-2.0")
    sc = load_scene(str(xml), animation=str(other))
    assert "animation:" not in capsys.readouterr().out       # given, not found: nothing to announce
    x1 = np.asarray(sc.at(1.0).params["box.vertex_positions"]).reshape(-1, 3)[:, 0].mean()
    assert x1 - x0 == pytest.approx(-2.0, abs=1e-5)
    _raises_kw(str(xml), "does not exist", animation=str(tmp_path / "nope.toml"))
    _raises_kw(str(xml), "no sensor with id 'x'", camera="x")
    _raises_kw("cornell-static", "--animation applies to Mitsuba XML", animation=str(other))


def _raises_kw(target, fragment, **kw):
    with pytest.raises(DyngiError) as ei:
        load_scene(target, **kw)
    assert "\n" not in str(ei.value).strip() and fragment in str(ei.value), str(ei.value)


def test_fps_given_wins_over_the_sidecars_own(tmp_path):
    """A sidecar may name its fps; --fps on the command line (load_scene's fps) overrides it."""
    xml = tmp_path / "room.xml"
    xml.write_text(XML)
    side = tmp_path / "room.anim.toml"
    side.write_text("fps = 10\n" + TOML % "1.0")
    assert load_scene(str(xml)).fps == 10
    assert load_scene(str(xml), fps=24).fps == 24

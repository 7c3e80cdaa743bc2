"""Keyframe sidecars (dyngi.scene.keyframes): poses at chosen times agree with Mitsuba renders of the
XML edited by the test to those poses; every kind of bad sidecar gives one line."""
import math
import os

import numpy as np
import pytest

from stats import z_test_images

# -- a small XML: a floor and a box sharing one BSDF (Mitsuba merges them on load), a sphere, a sun --

XML = """<scene version="3.0.0">
  <sensor type="perspective">
    <float name="fov" value="50"/>
    <transform name="to_world"><lookat origin="0, 2.6, 3.6" target="0, 0.3, 0" up="0, 1, 0"/></transform>
  </sensor>
  <bsdf type="diffuse" id="grey"><rgb name="reflectance" value="0.6, 0.6, 0.6"/></bsdf>
  <bsdf type="diffuse" id="red"><rgb name="reflectance" value="0.7, 0.2, 0.1"/></bsdf>
  <shape type="rectangle" id="floor">
    <transform name="to_world"><scale value="2.5"/><rotate x="1" angle="-90"/></transform>
    <ref id="grey"/>
  </shape>
  <shape type="cube" id="box">
    <transform name="to_world">{box}</transform>
    <ref id="grey"/>
  </shape>
  <shape type="sphere" id="ball">
    <point name="center" x="{cx}" y="{cy}" z="{cz}"/><float name="radius" value="{radius}"/>
    <ref id="red"/>
  </shape>
  <emitter type="directional" id="sun">
    <vector name="direction" x="{dx}" y="{dy}" z="{dz}"/>
    <rgb name="irradiance" value="{irr}, {irr}, {irr}"/>
  </emitter>
  <emitter type="constant" id="sky"><rgb name="radiance" value="0.25, 0.3, 0.4"/></emitter>
</scene>
"""

SIDECAR = """
[shapes.box]
interpolation = "smooth"
keys = [
  { t = 0.0, translate = [0.0, 0.0, 0.0], rotate = 0.0 },
  { t = 2.0, translate = [0.8, 0.0, -0.4], rotate = 120.0 },
]

[shapes.ball]
keys = [
  { t = 0.0, translate = [0.0, 0.0, 0.0], scale = 1.0 },
  { t = 2.0, translate = [0.3, 0.4, 0.2], scale = 1.6 },
]

[emitters.sun]
keys = [
  { t = 0.0, elevation = 60.0, azimuth = 0.0 },
  { t = 2.0, elevation = 30.0, azimuth = 90.0 },
]

[emitters.sky]
interpolation = "step"
keys = [
  { t = 0.0, scale = 1.0 },
  { t = 1.0, scale = 2.0 },
]
"""

BOX_C = np.array([0.0, 0.35, 0.0])
BALL_C, BALL_R = np.array([-0.8, 0.25, 0.5]), 0.25
IRR = 3.0


def _pose_xml(t: float, wrong: str = "") -> str:
    """The XML edited to the sidecar's pose at ``t``, computed here from the documented conventions;
    ``wrong`` names one deliberate error (to show the comparison sees it)."""
    a = min(max(t / 2.0, 0.0), 1.0)
    s = a * a * (3.0 - 2.0 * a)                  # smooth (box)
    d = s * np.array([0.8, 0.0, -0.4])
    p = BOX_C + d
    angle = 120.0 * (a if wrong == "box_linear" else s) * (0.0 if wrong == "box_rotate" else 1.0)
    box = (f'<scale value="0.35"/><rotate y="1" angle="{angle:.9g}"/>'
           f'<translate x="{p[0]:.9g}" y="{p[1]:.9g}" z="{p[2]:.9g}"/>')
    c = BALL_C + a * np.array([0.3, 0.4, 0.2])   # linear (ball)
    r = BALL_R * (1.0 + (0.0 if wrong == "ball_scale" else 0.6) * a)
    el = math.radians(60.0 - 30.0 * a + (4.0 if wrong == "sun_elevation" else 0.0))
    az = math.radians(90.0 * a * (-1.0 if wrong == "sun_azimuth" else 1.0))   # linear (sun)
    to_sun = np.array([math.cos(el) * math.sin(az), math.sin(el), math.cos(el) * math.cos(az)])
    sky = 2.0 if t >= 1.0 else 1.0              # step (sky)
    if wrong == "sky_linear":
        sky = 1.0 + min(t, 1.0)
    f = [f"{float(v):.9g}" for v in (*c, r, *(-to_sun))]
    xml = XML.format(box=box, cx=f[0], cy=f[1], cz=f[2], radius=f[3], dx=f[4], dy=f[5], dz=f[6], irr=IRR)
    return xml.replace('value="0.25, 0.3, 0.4"', f'value="{0.25 * sky}, {0.3 * sky}, {0.4 * sky}"')


def _write(tmp_path, name, text):
    p = tmp_path / name
    p.write_text(text)
    return str(p)


@pytest.fixture
def animated(backend, tmp_path):
    from dyngi.scene.keyframes import attach
    from dyngi.scene.loaders import load_scene

    xml = _write(tmp_path, "scene.xml", _pose_xml(0.0))
    toml = _write(tmp_path, "poses.toml", SIDECAR)
    return attach(load_scene(xml), toml), tmp_path


def _ours(scene, t, res, spp, k):
    from dyngi.techniques.base import to_image
    from dyngi.techniques.path import render_paths

    scene.at(t)
    L, _ = render_paths(scene, scene.camera(t), res, spp, seed=1000 + k, frame_index=0, max_depth=6, rr_depth=5)
    return to_image(L, res)


def _mitsuba_xml(path, camera, res, spp, k):
    from dyngi.backend import mi

    mis = mi.load_file(path)
    integ = mi.load_dict({"type": "path", "max_depth": 6, "rr_depth": 5})
    return np.asarray(mi.render(mis, sensor=camera.to_sensor(res, spp), integrator=integ, spp=spp, seed=5000 + k),
                      np.float32)


def _agree(a, b):
    """z_test_images on the stacks, after checking the noise-free pixels (the sky seen directly: both
    stacks constant to float round-off) agree to 1e-5 relative; those pixels are then left out (a Welch
    statistic over round-off noise is meaningless)."""
    la, lb = a.mean(-1), b.mean(-1)
    still = (la.std(0) <= 1e-6 * np.abs(la.mean(0)) + 1e-9) & (lb.std(0) <= 1e-6 * np.abs(lb.mean(0)) + 1e-9)
    diff = np.abs(a.mean(0) - b.mean(0))[still]
    if diff.size and np.max(diff) > 1e-5 * max(float(np.abs(b).max()), 1e-6):
        return False, {"noise_free_pixels_differ": float(np.max(diff))}
    b = np.where(still[None, ..., None], a, b)
    return z_test_images(a, b)


def test_sidecar_found_beside_xml(tmp_path):
    from dyngi.scene.keyframes import sidecar_for

    xml = _write(tmp_path, "room.xml", "<scene version='3.0.0'/>")
    assert sidecar_for(xml) is None
    toml = _write(tmp_path, "room.anim.toml", "")
    assert sidecar_for(xml) == toml


def test_merged_shape_keeps_its_id_and_scene_metadata(animated):
    """The box shares the floor's BSDF (Mitsuba merges such meshes on load); the sidecar still moves it."""
    sc, _ = animated
    assert {"box", "ball", "floor"} <= {sh.id() for sh in sc.mi_scene.shapes()}
    assert sc.duration == 2.0 and sc.is_animated
    assert sc.meta.dynamic_shapes == ["ball", "box"]
    # probe box and bounds cover the box's and the ball's end poses (box corner reaches x = 0.7 + 0.3*...)
    lo, hi = (np.asarray(v) for v in sc.meta.bounds)
    assert hi[1] >= BALL_C[1] + 0.4 + BALL_R * 1.6 - 1e-4
    assert hi[0] >= 0.8 + 0.35 - 1e-4
    assert sc.state_hash(0.0) != sc.state_hash(1.3) and sc.state_hash(2.0) == sc.state_hash(3.0)


WRONG = ("box_linear", "box_rotate", "ball_scale", "sun_elevation", "sun_azimuth", "sky_linear")


def test_poses_match_mitsuba_renders_of_edited_xml(animated):
    """dyngi's path tracer on the animated scene at t and Mitsuba's path on the XML the test edited to the
    pose at t estimate the same image (per-pixel Welch/Sidak, binomial count, mean; alpha 0.01, 16 renders
    of 16 spp each); and the comparison sees each single wrong detail (the box interpolated linearly or not
    rotated, the ball not scaled, the sun 4 degrees low or mirrored in azimuth, the sky's step interpolated
    linearly) at one of the two times at least."""
    sc, tmp = animated
    res, spp, k = (32, 24), 16, 16
    cam = sc.camera(0.0)
    seen = {w: False for w in WRONG}
    for t in (0.5, 1.5):
        a = np.stack([_ours(sc, t, res, spp, i) for i in range(k)])
        for wrong in ("",) + WRONG:
            edited = _write(tmp, "pose.xml", _pose_xml(t, wrong))
            b = np.stack([_mitsuba_xml(edited, cam, res, spp, i) for i in range(k)])
            ok, info = _agree(a, b)
            if not wrong:
                assert ok, f"t={t}: the animated scene and the edited XML disagree: {info}"
            else:
                seen[wrong] |= not ok
    assert all(seen.values()), f"the comparison cannot see these pose errors: {[w for w in seen if not seen[w]]}"


# -- bad sidecars: one line each, naming the problem and the valid choices --

BAD = {
    "unknown_id": ("[shapes.crate]\nkeys = [{ t = 0.0, rotate = 0.0 }, { t = 1.0, rotate = 9.0 }]\n",
                   ["unknown shape id 'crate'", "box", "ball", "floor"]),
    "unknown_emitter": ("[emitters.moon]\nkeys = [{ t = 0.0, scale = 1.0 }, { t = 1.0, scale = 2.0 }]\n",
                        ["unknown emitter id 'moon'", "sun", "sky"]),
    "unknown_property": ("[shapes.box]\nkeys = [{ t = 0.0, spin = 0.0 }, { t = 1.0, rotate = 9.0 }]\n",
                         ["unknown property 'spin'", "translate, rotate, scale"]),
    "emitter_property": ("[emitters.sky]\nkeys = [{ t = 0.0, elevation = 10.0 }, { t = 1.0, scale = 2.0 }]\n",
                         ["unknown property 'elevation'", "scale"]),
    "times": ("[shapes.box]\nkeys = [{ t = 0.0, rotate = 0.0 }, { t = 2.0, rotate = 9.0 }, { t = 1.0, rotate = 1.0 }]\n",
              ["strictly increasing", "0, 2, 1"]),
    "nan": ("[shapes.box]\nkeys = [{ t = 0.0, translate = [0.0, nan, 0.0] }, { t = 1.0, rotate = 9.0 }]\n",
            ["'translate' has NaN or infinite values"]),
    "inf_time": ("[emitters.sun]\nkeys = [{ t = 0.0, elevation = 10.0 }, { t = inf, elevation = 20.0 }]\n",
                 ["t = inf is not finite"]),
    "interpolation": ("[shapes.box]\ninterpolation = 'cubic'\nkeys = [{ t = 0.0, rotate = 0.0 }, { t = 1.0, rotate = 9.0 }]\n",
                      ["unknown interpolation 'cubic'", "linear, smooth, step"]),
    "sphere_scale": ("[shapes.ball]\nkeys = [{ t = 0.0, scale = 1.0 }, { t = 1.0, scale = [1.0, 2.0, 1.0] }]\n",
                     ["sphere", "uniformly"]),
    "top_level": ("duration = 3\n[shapes.box]\nkeys = [{ t = 0.0, rotate = 0.0 }, { t = 1.0, rotate = 9.0 }]\n",
                  ["unknown setting 'duration'", "fps, loop"]),
    "toml_syntax": ("[shapes.box\n", ["not valid TOML"]),
    "static": ("[shapes.box]\nkeys = [{ t = 0.0, rotate = 0.0 }]\n", ["nothing moves"]),
}


@pytest.mark.parametrize("kind", sorted(BAD))
def test_bad_sidecar_one_line(backend, tmp_path, kind):
    from dyngi.errors import DyngiError
    from dyngi.scene.keyframes import attach
    from dyngi.scene.loaders import load_scene

    text, needles = BAD[kind]
    sc = load_scene(_write(tmp_path, "scene.xml", _pose_xml(0.0)))
    toml = _write(tmp_path, "bad.anim.toml", text)
    with pytest.raises(DyngiError) as e:
        attach(sc, toml)
    msg = str(e.value)
    assert "\n" not in msg, msg
    assert msg.startswith(toml), msg
    for n in needles:
        assert n in msg, (n, msg)


def test_problems_are_reported_together_one_line_each(backend, tmp_path):
    from dyngi.errors import DyngiError
    from dyngi.scene.keyframes import attach
    from dyngi.scene.loaders import load_scene

    sc = load_scene(_write(tmp_path, "scene.xml", _pose_xml(0.0)))
    toml = _write(tmp_path, "bad.anim.toml", BAD["unknown_id"][0] + BAD["unknown_emitter"][0])
    with pytest.raises(DyngiError) as e:
        attach(sc, toml)
    lines = str(e.value).splitlines()
    assert len(lines) == 2 and "'crate'" in lines[0] and "'moon'" in lines[1]


def test_shape_that_cannot_move_in_place(backend, tmp_path):
    """A curve exposes neither vertex positions nor to_world to mi.traverse."""
    from dyngi.errors import DyngiError
    from dyngi.scene.keyframes import attach
    from dyngi.scene.loaders import load_scene

    pts = _write(tmp_path, "c.txt", "0 0 0 0.05\n0 1 0 0.05\n")
    xml = _pose_xml(0.0).replace("</scene>", f'<shape type="linearcurve" id="rope"><string name="filename" '
                                            f'value="{pts}"/></shape></scene>')
    sc = load_scene(_write(tmp_path, "scene.xml", xml))
    toml = _write(tmp_path, "bad.anim.toml", "[shapes.rope]\nkeys = [{ t = 0.0, rotate = 0.0 }, "
                                             "{ t = 1.0, rotate = 9.0 }]\n")
    with pytest.raises(DyngiError) as e:
        attach(sc, toml)
    msg = str(e.value)
    assert "\n" not in msg and "cannot be transformed in place" in msg and "'rope'" in msg, msg


def test_camera_path(backend, tmp_path):
    from dyngi.scene.keyframes import attach
    from dyngi.scene.loaders import load_scene

    sc = load_scene(_write(tmp_path, "scene.xml", _pose_xml(0.0)))
    toml = _write(tmp_path, "cam.anim.toml", """
[camera]
keys = [
  { t = 0.0, position = [0.0, 2.0, 4.0], target = [0.0, 0.0, 0.0], fov = 40.0 },
  { t = 1.0, position = [4.0, 2.0, 0.0], fov = 60.0, up = [0.0, 1.0, 0.0] },
]
""")
    a = attach(sc, toml)
    c = a.camera(0.5)
    assert np.allclose(c.origin, (2.0, 2.0, 2.0)) and np.allclose(c.target, 0.0) and c.fov == pytest.approx(50.0)
    assert a.duration == 1.0 and a.is_animated and a.state_hash(0.0) != a.state_hash(0.5)
    # position alone: the XML camera's view direction is kept
    b = attach(sc, _write(tmp_path, "pan.anim.toml", "[camera]\nkeys = [{ t = 0.0, position = [0.0, 2.6, 3.6] }, "
                                                     "{ t = 1.0, position = [1.0, 2.6, 3.6] }]\n"))
    c0, c1 = sc.camera(0.0), b.camera(1.0)
    assert np.allclose(np.subtract(c1.target, c1.origin), np.subtract(c0.target, c0.origin))
    assert np.allclose(c1.origin, (1.0, 2.6, 3.6))


def test_example_sidecars_load(backend):
    """The shipped examples attach to their scenes (ids checked against the real XML files)."""
    from conftest import ROOT, shared_scene
    from dyngi.scene.keyframes import attach
    from dyngi.scene.loaders import load_scene

    for xml, toml in (("cornell-box/scene_mi3.xml", "cornell-light-moves.anim.toml"),
                      ("veach-ajar/scene_nopots.xml", "veach-ajar.anim.toml")):
        sc = attach(load_scene(shared_scene(xml)), os.path.join(ROOT, "examples", toml))
        assert sc.is_animated and sc.duration > 0
        sc.at(0.5 * sc.duration)
        ids = {sh.id() for sh in sc.mi_scene.shapes()}
        if xml.startswith("cornell"):
            # the named TallBox is kept out of Mitsuba's mesh merging; the static ShortBox is still merged
            assert "TallBox" in ids and "ShortBox" not in ids, ids


# -- skies: a sunsky's sun and an envmap's rotation ---------------------------------------------------

SKY_XML = """<scene version="3.0.0">
  <sensor type="perspective">
    <float name="fov" value="50"/>
    <transform name="to_world"><lookat origin="0, 2.6, 3.6" target="0, 0.3, 0" up="0, 1, 0"/></transform>
  </sensor>
  <bsdf type="diffuse" id="grey"><rgb name="reflectance" value="0.6, 0.6, 0.6"/></bsdf>
  <shape type="rectangle" id="floor">
    <transform name="to_world"><scale value="2.5"/><rotate x="1" angle="-90"/></transform><ref id="grey"/>
  </shape>
  <shape type="cube" id="box">
    <transform name="to_world"><scale value="0.35"/><translate y="0.35"/></transform><ref id="grey"/>
  </shape>
  <emitter type="{kind}" id="sky">{body}</emitter>
</scene>
"""
SKIES = {
    # Mitsuba's sunsky is +Z up in its own frame; rotated here so that its up is world +Y
    "sunsky": ("[emitters.sky]\nkeys = [{ t = 0.0, elevation = 60.0, azimuth = 0.0 },"
               " { t = 2.0, elevation = 20.0, azimuth = 100.0 }]\n"),
    "envmap": "[emitters.sky]\naxis = [0.0, 1.0, 0.0]\nkeys = [{ t = 0.0, rotate = 0.0 }, { t = 2.0, rotate = 180.0 }]\n",
}


def _sky_xml(kind, t, tmp, wrong=False):
    a = min(t / 2.0, 1.0)
    if kind == "sunsky":
        el = math.radians(60.0 - 40.0 * a + (4.0 if wrong else 0.0))
        az = math.radians(100.0 * a)
        d = [math.cos(el) * math.sin(az), math.sin(el), math.cos(el) * math.cos(az)]    # world, +Y up
        body = (f"<vector name='sun_direction' x='{d[0]:.9g}' y='{d[1]:.9g}' z='{d[2]:.9g}'/>"
                "<float name='sun_scale' value='0.02'/><float name='sky_scale' value='0.3'/>"
                "<transform name='to_world'><rotate x='1' angle='-90'/></transform>")
    else:
        env = str(tmp / "sky.exr")
        if not os.path.exists(env):
            from dyngi.backend import mi

            img = np.zeros((16, 32, 3), np.float32)
            img[:, :8] = [8.0, 6.0, 3.0]      # a bright quarter of the sky
            img[:, 8:] = [0.2, 0.3, 0.5]
            mi.Bitmap(img).write(env)
        angle = 180.0 * a + (20.0 if wrong else 0.0)
        body = f"<string name='filename' value='{env}'/><transform name='to_world'><rotate y='1' angle='{angle:.9g}'/></transform>"
    return _write(tmp, f"{kind}.xml", SKY_XML.format(kind=kind, body=body))


@pytest.mark.parametrize("kind", sorted(SKIES))
def test_sky_matches_mitsuba_render_of_edited_xml(backend, tmp_path, kind):
    """A sunsky's sun moved by elevation / azimuth, an envmap rotated: dyngi's path tracer on the animated
    scene agrees with Mitsuba's path on the XML edited to that time; 4 degrees of sun elevation (20 of
    envmap rotation) too few or many is seen."""
    from dyngi.scene.keyframes import attach
    from dyngi.scene.loaders import load_scene

    sc = attach(load_scene(_sky_xml(kind, 0.0, tmp_path)), _write(tmp_path, "sky.toml", SKIES[kind]))
    res, spp, k, t = (32, 24), 16, 16, 1.3
    cam = sc.camera(0.0)
    a = np.stack([_ours(sc, t, res, spp, i) for i in range(k)])
    b = np.stack([_mitsuba_xml(_sky_xml(kind, t, tmp_path), cam, res, spp, i) for i in range(k)])
    ok, info = _agree(a, b)
    assert ok, f"{kind}: the animated scene and the edited XML disagree at t={t}: {info}"
    b = np.stack([_mitsuba_xml(_sky_xml(kind, t, tmp_path, wrong=True), cam, res, spp, i) for i in range(k)])
    ok, info = _agree(a, b)
    assert not ok, f"{kind}: the comparison did not see a wrong sky: {info}"


def test_sunsky_up_must_match(backend, tmp_path):
    """A sunsky left +Z up (Mitsuba's default frame) under the default 'up = +Y' is one clear line."""
    from dyngi.errors import DyngiError
    from dyngi.scene.keyframes import attach
    from dyngi.scene.loaders import load_scene

    xml = _write(tmp_path, "s.xml", SKY_XML.format(kind="sunsky", body="<vector name='sun_direction' x='0' y='0.5' "
                                                                     "z='0.866'/>"))
    with pytest.raises(DyngiError) as e:
        attach(load_scene(xml), _write(tmp_path, "s.toml", SKIES["sunsky"]))
    msg = str(e.value)
    assert "\n" not in msg and "up = [0.0, 0.0, 1.0]" in msg, msg
    sc = attach(load_scene(xml), _write(tmp_path, "s2.toml", "up = [0.0, 0.0, 1.0]\n" + SKIES["sunsky"]))
    timed = _write(tmp_path, "timed.xml", SKY_XML.format(kind="sunsky", body="<float name='hour' value='11'/>"))
    with pytest.raises(DyngiError) as e:
        attach(load_scene(timed), _write(tmp_path, "s3.toml", "up = [0.0, 0.0, 1.0]\n" + SKIES["sunsky"]))
    assert "\n" not in str(e.value) and "date, time and location" in str(e.value), str(e.value)
    sc.at(1.0)
    d = np.asarray(sc.params["sky.sun_direction"], np.float64).ravel()
    assert d[2] == pytest.approx(math.sin(math.radians(40.0)), abs=1e-5)   # elevation above the XY plane


# -- shapes moved through to_world: rectangle, disk, cylinder, an instance ---------------------------

TO_WORLD_SHAPES = {     # id: (XML with a {} for the moved part of to_world, XML base position)
    "rect": ('<shape type="rectangle" id="rect"><transform name="to_world"><scale value="0.3"/>{}</transform>'
             '<ref id="red"/></shape>', (-1.2, 0.5, 0.0)),
    "disk": ('<shape type="disk" id="disk"><transform name="to_world"><scale value="0.3"/><rotate x="1" angle="-60"/>'
             '{}</transform><ref id="red"/></shape>', (0.4, 0.5, -0.8)),
    "cyl": ('<shape type="cylinder" id="cyl"><float name="radius" value="0.15"/><transform name="to_world">'
            '<scale z="0.6"/><rotate x="1" angle="-90"/>{}</transform><ref id="red"/></shape>', (-0.4, 0.0, -0.8)),
    "inst": ('<shape type="shapegroup" id="g"><shape type="cube"><transform name="to_world"><scale value="0.3"/>'
             '</transform><ref id="red"/></shape></shape><shape type="instance" id="inst"><ref id="g"/>'
             '<transform name="to_world">{}</transform></shape>', (0.9, 0.3, 0.3)),
}


def test_to_world_shapes_move_in_place(backend, tmp_path):
    """Analytic shapes (rectangle, disk, cylinder) and an instance moved by the sidecar render as the XML with
    the moved to_world (Mitsuba's path on both: what is tested is the in-place update; alpha 0.01 as above);
    the unmoved XML is told apart."""
    from dyngi.backend import mi
    from dyngi.scene.keyframes import attach
    from dyngi.scene.loaders import load_scene

    xml = SKY_XML.replace('<emitter type="{kind}" id="sky">{body}</emitter>',
                          '<bsdf type="diffuse" id="red"><rgb name="reflectance" value="0.8, 0.1, 0.1"/></bsdf>'
                          '{shapes}<emitter type="directional" id="sun"><vector name="direction" x="0.3" y="-1" '
                          'z="-0.4"/><rgb name="irradiance" value="3"/></emitter>'
                          '<emitter type="constant"><rgb name="radiance" value="0.3"/></emitter>')

    def pose(moved):
        parts = []
        for sid, (tpl, p) in TO_WORLD_SHAPES.items():
            at = f'<translate x="{p[0]}" y="{p[1]}" z="{p[2]}"/>'
            if moved:   # 40 degrees about y through the base position, then up 0.2 and along x 0.3
                at += (f'<translate x="{-p[0]}" y="{-p[1]}" z="{-p[2]}"/><rotate y="1" angle="40"/>'
                       f'<translate x="{p[0] + 0.3}" y="{p[1] + 0.2}" z="{p[2]}"/>')
            parts.append(tpl.format(at))
        return xml.format(shapes="".join(parts))

    toml = "".join(f"[shapes.{sid}]\npivot = [{p[0]}, {p[1]}, {p[2]}]\nkeys = [{{ t = 0.0, rotate = 0.0 }}, "
                   f"{{ t = 1.0, translate = [0.3, 0.2, 0.0], rotate = 40.0 }}]\n"
                   for sid, (_, p) in TO_WORLD_SHAPES.items())
    sc = attach(load_scene(_write(tmp_path, "a.xml", pose(False))), _write(tmp_path, "a.toml", toml))
    cam, res, spp, k = sc.camera(0.0), (32, 24), 16, 8
    sc.at(1.0)
    integ = mi.load_dict({"type": "path", "max_depth": 4})
    a = np.stack([np.asarray(mi.render(sc.mi_scene, sensor=cam.to_sensor(res, spp), integrator=integ, spp=spp,
                                       seed=100 + i)) for i in range(k)])
    b = np.stack([_mitsuba_xml(_write(tmp_path, "e.xml", pose(True)), cam, res, spp, i) for i in range(k)])
    ok, info = _agree(a, b)
    assert ok, f"moved in place and the edited XML disagree: {info}"
    b = np.stack([_mitsuba_xml(_write(tmp_path, "w.xml", pose(False)), cam, res, spp, i) for i in range(k)])
    ok, info = _agree(a, b)
    assert not ok, f"the unmoved shapes were not told apart: {info}"


# -- emitter scales: every emitter type -------------------------------------------------------------

EMIT_XML = """<scene version="3.0.0">
  <sensor type="perspective"><float name="fov" value="50"/>
    <transform name="to_world"><lookat origin="0, 2.6, 3.6" target="0, 0.3, 0" up="0, 1, 0"/></transform></sensor>
  <bsdf type="diffuse" id="grey"><rgb name="reflectance" value="0.6, 0.6, 0.6"/></bsdf>
  <shape type="rectangle" id="floor"><transform name="to_world"><scale value="2.5"/><rotate x="1" angle="-90"/></transform>
    <ref id="grey"/></shape>
  <shape type="rectangle" id="lamp"><transform name="to_world"><scale value="0.2"/><rotate x="1" angle="90"/>
    <translate y="1.5"/></transform><emitter type="area"><rgb name="radiance" value="{lamp}"/></emitter></shape>
  <emitter type="point" id="pt"><point name="position" x="0.5" y="1" z="0"/><rgb name="intensity" value="{pt}"/></emitter>
  <emitter type="spot" id="spot"><transform name="to_world"><lookat origin="-1, 2, 0" target="0, 0, 0"/></transform>
    <rgb name="intensity" value="{spot}"/></emitter>
  <emitter type="directional" id="sun"><vector name="direction" x="0.3" y="-1" z="-0.4"/>
    <rgb name="irradiance" value="{sun}"/></emitter>
  {env}
</scene>"""
EMIT_BASE = {"lamp": 5.0, "pt": 3.0, "spot": 6.0, "sun": 1.0}
EMIT_ENVS = {
    "constant": '<emitter type="constant" id="env"><rgb name="radiance" value="{0}"/></emitter>',
    "envmap": '<emitter type="envmap" id="env"><string name="filename" value="{2}"/><float name="scale" value="{0}"/>'
              '</emitter>',
    "sunsky": '<emitter type="sunsky" id="env"><vector name="sun_direction" x="0" y="0.6" z="0.8"/>'
              '<float name="sun_scale" value="{1}"/><float name="sky_scale" value="{0}"/></emitter>',
}


@pytest.mark.parametrize("env", sorted(EMIT_ENVS))
def test_emitter_scales(backend, tmp_path, env):
    """Area, point, spot and directional lights and a constant / envmap / sunsky environment scaled by the
    sidecar render as the XML with the scaled values (Mitsuba's path, same seed: equal to round-off); the
    unscaled XML differs."""
    from dyngi.backend import mi
    from dyngi.scene.keyframes import attach
    from dyngi.scene.loaders import load_scene

    exr = str(tmp_path / "sky.exr")
    mi.Bitmap(np.full((8, 16, 3), 0.5, np.float32)).write(exr)
    factors = {eid: 2.0 + i for i, eid in enumerate(EMIT_BASE)}

    def xml(mult, env_mult):
        vals = {eid: f"{v * mult.get(eid, 1.0):.9g}" for eid, v in EMIT_BASE.items()}
        return EMIT_XML.format(env=EMIT_ENVS[env].format(0.3 * env_mult, 0.01 * env_mult, exr), **vals)

    toml = "".join(f"[emitters.{eid}]\nkeys = [{{ t = 0.0, scale = 1.0 }}, {{ t = 1.0, scale = {f} }}]\n"
                   for eid, f in factors.items()) + "[emitters.env]\nkeys = [{ t = 0.0, scale = 1.0 }, { t = 1.0, scale = 0.5 }]\n"
    sc = attach(load_scene(_write(tmp_path, "a.xml", xml({}, 1.0))), _write(tmp_path, "a.toml", toml))
    cam = sc.camera(0.0)
    sc.at(1.0)
    integ = mi.load_dict({"type": "path", "max_depth": 3})

    def render(mis):
        return np.asarray(mi.render(mis, sensor=cam.to_sensor((16, 12), 64), integrator=integ, spp=64, seed=1))

    a = render(sc.mi_scene)
    e = render(mi.load_file(_write(tmp_path, "e.xml", xml(factors, 0.5))))
    w = render(mi.load_file(_write(tmp_path, "w.xml", xml({}, 1.0))))
    assert np.abs(a - e).mean() <= 1e-4 * e.mean(), (np.abs(a - e).mean(), e.mean())
    assert np.abs(a - w).mean() >= 0.1 * e.mean()


def test_steady_frames_compile_nothing(animated):
    """Animated values reach the kernels as data, not literals: after the first frames, frames at new times
    (every track of the sidecar changing: mesh, sphere, sun, sky) launch only kernels launched before."""
    from helpers import assert_steady_state_compiles_nothing

    sc, _ = animated

    def step(f):
        _ours(sc, 0.1 + 0.3 * f, (8, 6), 1, f)     # the sky steps at t = 1

    assert_steady_state_compiles_nothing(step, frames=6, warmup=2, nonempty=True)


# -- every technique on a keyframed XML scene ---------------------------------------------------------

def _run_technique(scene, spec):
    from dyngi.experiments.runner import run_sequence
    from dyngi.techniques.base import create_technique

    scene.fps = 2.0                              # frames 0, 1, 2 are t = 0, 0.5, 1 s: everything moves
    seq = run_sequence(scene, create_technique(spec, scene), 3, (16, 12), seed=0)
    imgs = np.stack(seq.images)
    assert np.all(np.isfinite(imgs)) and imgs.min() >= 0.0, spec
    assert np.abs(imgs[0] - imgs[-1]).mean() > 0.0, spec


def test_ddgi_runs_on_a_keyframed_scene(animated):
    _run_technique(animated[0], "ddgi")


def _technique_names():
    from dyngi.techniques.base import technique_names

    return technique_names()


@pytest.mark.slow
@pytest.mark.parametrize("name", _technique_names())
def test_every_technique_runs_on_a_keyframed_scene(animated, name):
    """Every registered technique runs unchanged on the keyframed XML scene (a merged box moved, a sphere
    moved and scaled, the sun turned, the sky stepped): finite, non-negative frames that change."""
    _run_technique(animated[0], name)


def test_viewer_plays_a_keyframed_scene(animated):
    """`dyngi view`'s render loop plays the sidecar's animation: playing from the start, over its
    duration, its time advancing frame to frame."""
    import time

    from dyngi.viewer.session import RenderSession

    sc, _ = animated
    got = []
    s = RenderSession(sc, ["path:spp=1"], (16, 9), lambda kind, payload: got.append((kind, payload)), still_frames=4)
    s.start()
    try:
        assert s.ready.wait(60) and s.startup_error is None
        st = s.state()
        assert st["animated"] and st["playing"] and st["duration"] == 2.0
        end = time.monotonic() + 60
        while time.monotonic() < end and s.t <= 0.0:
            time.sleep(0.05)
        assert s.t > 0.0, "the viewer's time did not advance"
        assert any(kind == "frame" for kind, _ in got)
    finally:
        assert s.stop(60)


def test_point_and_spot_lights_move(backend, tmp_path):
    """A point and a spot light translated by the sidecar render as the XML with the moved position /
    spot frame (Mitsuba's path, same seed: equal to round-off); the unmoved XML differs."""
    from dyngi.backend import mi
    from dyngi.scene.keyframes import attach
    from dyngi.scene.loaders import load_scene

    vals = {eid: f"{v:.9g}" for eid, v in EMIT_BASE.items()}
    base = EMIT_XML.format(env="", **vals)
    moved = (base.replace('<point name="position" x="0.5" y="1" z="0"/>', '<point name="position" x="-0.3" y="1.2" z="0.4"/>')
             .replace('origin="-1, 2, 0" target="0, 0, 0"', 'origin="-0.5, 2, -0.5" target="0.5, 0, -0.5"'))
    assert moved.count("-0.3") == 1 and moved.count("0.5, 0, -0.5") == 1
    toml = ("[emitters.pt]\nkeys = [{ t = 0.0, translate = [0.0, 0.0, 0.0] }, { t = 2.0, translate = [-1.6, 0.4, 0.8] }]\n"
            "[emitters.spot]\nkeys = [{ t = 0.0, translate = [0.0, 0.0, 0.0] }, { t = 2.0, translate = [1.0, 0.0, -1.0] }]\n")
    sc = attach(load_scene(_write(tmp_path, "a.xml", base)), _write(tmp_path, "a.toml", toml))
    cam = sc.camera(0.0)
    sc.at(1.0)                                       # halfway: linear
    integ = mi.load_dict({"type": "path", "max_depth": 3})

    def render(mis):
        return np.asarray(mi.render(mis, sensor=cam.to_sensor((16, 12), 64), integrator=integ, spp=64, seed=1))

    a = render(sc.mi_scene)
    e = render(mi.load_file(_write(tmp_path, "e.xml", moved)))
    w = render(mi.load_file(_write(tmp_path, "w.xml", base)))
    assert np.abs(a - e).mean() <= 1e-4 * e.mean(), (np.abs(a - e).mean(), e.mean())
    assert np.abs(a - w).mean() >= 0.05 * e.mean()

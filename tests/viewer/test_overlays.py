"""The viewer's overlays draw where the technique has the data (probes, VPLs, octree leaves, guide chains)."""
import numpy as np
import pytest

from dyngi.scene import load_scene
from dyngi.techniques import Frame, create_technique
from dyngi.viewer import overlays

RES = (32, 18)


# the probe spheres are checked in the browser (tests/viewer/test_browser.py)
@pytest.mark.parametrize("spec, name", [("ir", "vpls"), ("nee-pt:lights=vlc", "octree"), ("adgi", "guide")])
def test_overlay_is_offered_and_drawn(backend, spec, name):
    scene = load_scene("cornell-moving-light")
    tech = create_technique(spec, scene)
    overlays.capture_vpls(tech)
    t = 0.0
    scene.at(t)
    r = tech.step(Frame(0, t, scene.camera(t), RES))
    assert name in overlays.available(tech)
    others = set(overlays.OVERLAYS) - set(overlays.available(tech))
    assert "none" not in others
    base = np.full((RES[1], RES[0], 3), 128, np.uint8)
    out = overlays.draw(name, tech, scene, scene.camera(t), RES, base)
    assert out.shape == base.shape and out.dtype == np.uint8
    changed = np.any(out != base, axis=-1).mean()
    assert changed > 0.005, f"{name} overlay drew nothing ({changed:.4f} of the pixels)"
    assert r.image.shape == (RES[1], RES[0], 3)


def test_unsupported_overlay_leaves_the_frame(backend):
    scene = load_scene("cornell-static")
    tech = create_technique("path:spp=1", scene)
    assert overlays.available(tech) == ["none"]
    base = np.zeros((9, 16, 3), np.uint8)
    assert overlays.draw("probes", tech, scene, scene.camera(0.0), (16, 9), base) is base

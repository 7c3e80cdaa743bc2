"""The viewer's orbit/fly camera (dyngi.viewer.camera): each move does what its docstring says."""
import math

import numpy as np
import pytest

from dyngi.scene.camera import Camera
from dyngi.viewer.camera import ViewCamera


def _cam():
    return ViewCamera(Camera((0.0, 1.0, 5.0), (0.0, 1.0, 0.0), (0.0, 1.0, 0.0), 45.0), scene_size=3.0)


def test_orbit_keeps_target_and_distance_and_turns():
    v = _cam()
    o0 = v.origin.copy()
    v.orbit(100, 0)
    assert np.allclose(v.target, (0, 1, 0))
    assert v.distance == pytest.approx(5.0)
    assert not np.allclose(v.origin, o0)
    assert v.origin[1] == pytest.approx(1.0)          # a horizontal drag turns about the up axis


def test_orbit_stops_short_of_the_pole():
    v = _cam()
    v.orbit(0, 10000)
    d = (v.target - v.origin) / v.distance
    assert abs(float(np.dot(d, (0, 1, 0)))) < math.cos(math.radians(1.0))
    assert v.distance == pytest.approx(5.0)


def test_pan_moves_origin_and_target_together():
    v = _cam()
    off = v.target - v.origin
    v.pan(50, -20, 400)
    assert np.allclose(v.target - v.origin, off)
    assert v.target[0] < 0                            # dragging right moves the scene right: camera left


def test_zoom_scales_distance_and_fly_moves_both():
    v = _cam()
    v.zoom(1.0)
    assert v.distance == pytest.approx(5.0 * math.exp(0.1))
    o, t = v.origin.copy(), v.target.copy()
    v.fly(1, 0, 0, 0.5)
    step = 3.0 / 3.0 * 0.5
    assert np.allclose(v.origin - o, (0, 0, -step)) and np.allclose(v.target - t, (0, 0, -step))


def test_look_keeps_origin():
    v = _cam()
    o = v.origin.copy()
    v.look(80, 30)
    assert np.allclose(v.origin, o)
    assert v.distance == pytest.approx(5.0)
    assert not np.allclose(v.target, (0, 1, 0))


def test_bad_moves_raise_and_leave_the_camera_unchanged():
    v = _cam()
    o, t = v.origin.copy(), v.target.copy()
    for msg in ({"op": "spin"}, {"op": "orbit", "dx": "x"}, {"op": "set", "origin": [0, 0, 0], "target": [0, 0, 0]},
                {"op": "pan", "dx": float("nan"), "dy": 0}):
        with pytest.raises(Exception):
            v.apply(msg)
        assert np.allclose(v.origin, o) and np.allclose(v.target, t)

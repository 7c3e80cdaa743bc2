"""The device paths of the SMC-IR baselines (issue 29): ``mir`` and ``tcas`` build their VPL sets on the
device and ``ir`` draws a new photon set per frame; a steady frame of each compiles no new kernel (the
frame index and seeds enter as opaque values), and ``mir``/``tcas`` hand the shader Dr.Jit arrays."""
from __future__ import annotations

import pytest

from dyngi.scene import load_scene
from dyngi.techniques import Frame, create_technique
from tests.helpers import assert_steady_state_compiles_nothing


@pytest.mark.parametrize("spec, params", [("mir", {"vpls": 32, "resampling_rate": 16}),
                                          ("tcas", {"vpls": 32, "iterations": 4, "view_samples": 16}),
                                          ("ir", {"vpls": 32})])
def test_steady_frames_compile_nothing(backend, spec, params):
    sc = load_scene("maze")
    tech = create_technique(spec, sc, params)

    def step(i):
        t = sc.frame_time(i)
        sc.at(t)
        r = tech.step(Frame(i, t, sc.camera(t), (16, 12), seed=1))
        assert r.indirect.max() > 0.0 and r.stats["vpls_used"] > 0

    assert_steady_state_compiles_nothing(step, frames=4, warmup=2, nonempty=True)


def test_device_vpl_sets_stay_on_the_device(backend):
    from dyngi.backend import mi
    from dyngi.techniques.base import StageTimer

    sc = load_scene("cornell-static")
    sc.at(0.0)
    for spec, params in (("mir", {"vpls": 32, "resampling_rate": 8}), ("tcas", {"vpls": 32, "iterations": 2})):
        tech = create_technique(spec, sc, params)
        pos, nrm, flux, _ = tech.update_vpls(Frame(0, 0.0, sc.camera(0.0), (16, 12), seed=0), StageTimer())
        assert isinstance(pos, mi.Point3f) and isinstance(flux, mi.Color3f), (spec, type(pos))

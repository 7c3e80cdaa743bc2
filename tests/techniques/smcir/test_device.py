"""The device paths of SMC-IR and its baselines: ``smcir`` (``impl='device'``, the default),
``mir`` and ``tcas`` build their VPL sets on the device and ``ir`` draws a new photon set per frame; a
steady frame of each compiles no new kernel (the frame index, seeds and camera enter as opaque values),
``smcir``/``mir``/``tcas`` hand the shader Dr.Jit arrays, and a steady ``smcir`` frame's VPL update
(Algorithm 1, lines 3-19) reads nothing back to the host."""
from __future__ import annotations

import pytest

from dyngi.scene import load_scene
from dyngi.techniques import Frame, create_technique
from tests.helpers import HostRead, assert_steady_state_compiles_nothing, no_host_reads


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


@pytest.mark.slow
def test_steady_smcir_frame_compiles_nothing_and_reads_nothing_back(backend):
    """maze (a walking camera), 32 VPLs: after frame 0, each frame's VPL update (candidates, k-NN
    densities, resampling, visibility, Eq. 9, replacement, re-estimate, flux) runs without one host read
    and launches only kernels launched before; the guard itself catches a read (the host impl's
    selection steps read back)."""
    import drjit as dr

    from dyngi.backend import mi
    from dyngi.techniques.base import StageTimer
    from tests.helpers import jit_kernel_hashes

    sc = load_scene("maze")
    params = {"vpls": 32, "warmup": 2, "radiosity_spp": 2}
    tech = create_technique("smcir", sc, params)
    host = create_technique("smcir", sc, {**params, "impl": "host"})
    seen = set()
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        for i in range(4):
            t = sc.frame_time(i)
            sc.at(t)
            f = Frame(i, t, sc.camera(t), (16, 12), seed=1)
            dr.kernel_history()     # clears
            if i == 0:
                tech.update_vpls(f, StageTimer())
            else:
                with no_host_reads():
                    pos, nrm, flux, info = tech.update_vpls(f, StageTimer())
            hashes = jit_kernel_hashes()
            if i >= 2:
                assert hashes and hashes <= seen, f"frame {i} compiled {len(hashes - seen)} new kernels"
            seen |= hashes
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    assert isinstance(pos, mi.Point3f) and isinstance(flux, mi.Color3f)
    assert int(info["vpls_used"][0]) == 32
    t = sc.frame_time(0)
    host.update_vpls(Frame(0, t, sc.camera(t), (16, 12), seed=1), StageTimer())
    with pytest.raises(HostRead):
        with no_host_reads():
            host.update_vpls(Frame(1, t, sc.camera(t), (16, 12), seed=1), StageTimer())

"""The light tree built on the device: ``build="device"`` runs the binned-SAH levels and the 8-wide
collapse as Dr.Jit passes (:func:`dyngi.lights.lighttree._collapse_device`) and must give exactly the tree the
host collapse makes from the same binary tree (the host collapse is the reference; the binary levels of the two
builds may differ at float32-vs-float64 SAH ties, so both collapses here start from the device's binary tree)."""
from __future__ import annotations

import numpy as np
import pytest


@pytest.mark.slow
@pytest.mark.parametrize("scene", ["warehouse-lights", "warehouse-rooms"])
def test_device_collapse_equals_host_collapse(backend, monkeypatch, scene):
    from dyngi.lights import lighttree as lt
    from dyngi.lights.emitter_table import EmitterTable
    from dyngi.scene.library import make_builtin

    sc = make_builtin(scene)
    sc.at(0.0)
    tris = EmitterTable(sc.mi_scene)
    dev = lt.LightTreeSelector(tris, build="device")
    assert dev._host_tree is None                      # nothing read back by the build itself
    monkeypatch.setattr(lt, "_build_binary", lambda *a: lt._build_binary_device(*a, read_back=True))
    host = lt.LightTreeSelector(tris, build="host")    # host collapse of the device's binary tree
    assert (dev.nodes, dev.leaves, dev.depth) == (host.nodes, host.leaves, host.depth)
    a, b = dev._host, host._host
    for k in b:
        x, y = np.asarray(a[k]), np.asarray(b[k])
        assert x.shape == y.shape, k
        if y.dtype.kind == "f":    # float32 on the device, the host keeps float64 copies of float32 values
            assert np.allclose(x, y, rtol=1e-6, atol=1e-30), k
        else:
            assert np.array_equal(x, y), k
    ll = a["leaf_lights"]
    assert np.array_equal(np.sort(ll[ll != lt.INVALID]), np.arange(tris.count))


@pytest.mark.slow
def test_steady_device_builds_compile_nothing(backend):
    """A rebuild every frame (the paper's baseline) on the device launches only kernels it launched before (the
    level inputs are evaluated up front: without that, kernel fusion varied between builds and every build
    compiled anew)."""
    from helpers import assert_steady_state_compiles_nothing

    from dyngi.lights.emitter_table import EmitterTable
    from dyngi.lights.lighttree import LightTreeSelector
    from dyngi.scene.library import make_builtin

    sc = make_builtin("warehouse-rooms")
    sc.at(0.0)
    tree = LightTreeSelector(EmitterTable(sc.mi_scene), build="device")
    assert_steady_state_compiles_nothing(lambda f: tree.build(), frames=4, warmup=2, nonempty=True)

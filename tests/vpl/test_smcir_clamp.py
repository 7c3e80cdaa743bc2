"""The geometry-term clamp of the VPL techniques (SMC-IR Sec. 2.1, 5.4): G_max = 1 / (c D)^2 with D the
scene's bounding-box diagonal and c = ``clamp_distance`` (0.05, chosen at 2048 VPLs), the same for every
VPL budget (the paper clamps "to a value suitable for 2048 VPLs" per scene and keeps it in Fig. 10)."""
from __future__ import annotations

import math

import numpy as np

from dyngi.techniques import create_technique
from dyngi.vpl.shading import clamp_value


def _plane(scale: float):
    from dyngi.scene.builder import SceneBuilder
    from dyngi.scene.camera import Camera
    from dyngi.scene.geometry import diffuse, quad

    s = float(scale)
    b = SceneBuilder(f"clamp-plane-{s:g}")
    b.mesh("floor", quad((0, 0, 0), (0, 0, 4 * s), (4 * s, 0, 0)), diffuse((0.5, 0.5, 0.5)))
    b.add("lamp", {"type": "point", "position": [0.0, s, 0.0], "intensity": {"type": "rgb", "value": [2.0] * 3}})
    return b.build(Camera((0, 2 * s, 3 * s), (0, 0, 0), (0, 1, 0), 50.0), "plane", duration=1.0)


def test_clamp_follows_the_diagonal_not_the_budget(backend):
    a, b = _plane(1.0), _plane(10.0)
    lo, hi = (np.asarray(v, float) for v in a.meta.bounds)
    d = float(np.linalg.norm(hi - lo))
    assert math.isclose(clamp_value(a, 0.05), 1.0 / (0.05 * d) ** 2, rel_tol=1e-12)
    assert math.isclose(clamp_value(b, 0.05) * 100.0, clamp_value(a, 0.05), rel_tol=1e-6)   # 1 / D^2
    assert clamp_value(a, 0.0) == math.inf
    g = {n: create_technique("smcir", a, {"vpls": n}).gmax for n in (512, 2048, 8192)}
    assert g[512] == g[2048] == g[8192] == clamp_value(a, 0.05)
    assert create_technique("ir", a).gmax == create_technique("mir", a).gmax == g[2048]


def test_clamped_shading_is_scale_invariant(backend):
    """A scene scaled by s (its VPL s times as high, its flux s^2 times larger, so the unclamped
    irradiance is unchanged) gives the same clamped irradiance: the clamp scales with the diagonal."""
    from dyngi.backend import mi
    from dyngi.vpl.points import to_numpy3, to_point, to_vector
    from dyngi.vpl.shading import VPLShader

    out = {}
    for s in (1.0, 10.0):
        sc = _plane(s)
        sc.at(0.0)
        p = to_point([[s, 0.0, s]] * 2)
        n = to_vector([[0.0, 1.0, 0.0]] * 2)
        gmax = clamp_value(sc, 0.2)
        E = {}
        far = math.sqrt(2.0 / (gmax * s * s))     # G = 1 / (far s)^2 = G_max / 2: unclamped
        for h in (0.05, far):                     # close: clamped; far: unclamped
            pos = np.array([[s, h * s, s]], np.float32)
            flux = np.array([[0.3, 0.2, 0.1]], np.float32) * s * s
            sh = VPLShader(sc, (2, 1), sc.camera(0.0), pos, np.array([[0.0, -1.0, 0.0]], np.float32), flux,
                           "exhaustive", gmax)
            E[h] = to_numpy3(sh.irradiance(p, n, None, mi.Bool(True)))[0]
        assert np.allclose(E[0.05], np.array([0.3, 0.2, 0.1]) * s * s * gmax, rtol=1e-4)    # the clamp bites
        assert np.allclose(E[far], np.array([0.3, 0.2, 0.1]) / far ** 2, rtol=1e-4)          # G = 1 / (h s)^2
        out[s] = E[0.05]
    assert np.allclose(out[1.0], out[10.0], rtol=1e-4), out

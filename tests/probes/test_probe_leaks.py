"""Probe leaks through thick two-sided geometry, for **every probe technique**.

The techniques are the registry's probe techniques (``PROBE_TECHNIQUE``,
:func:`dyngi.techniques.base.probe_technique_names`), not a hand list; ``ddgi``
and ``qddgi`` run in the fast suite, the others are ``slow``. Each renders
64x36 for 12 frames and averages frames 6-11:

* ``sealed-rooms``: the sealed room's mean is below 1% of the open room's
  (Mitsuba: exactly 0). Before the fix 0.70-0.80 for the DDGI-style techniques,
  0.38 for ddgi-secondary/-resampling (docs/techniques/ddgi.md);
* ``stair-hall``: the mean is within 10% of Mitsuba's ``path`` (1024 spp).
  Before the fix +42% to +62% (ddgi +53%), probes-reference -14%;
* veach-bidir (``../shared/scenes``, skipped when absent): the gain of the
  two-sided rule over the geometric one (ddgi 0.36 of Mitsuba's mean with
  ``two_sided='back'``) is kept: at least :data:`VEACH_FLOOR` (0.79, or the
  technique's own recorded floor where its other biases hold it lower --
  every figure is identical before and after the fix).

* the sealed room on every frame from frame 0: on ``sealed_rooms_dim`` (the same building,
  white, under a dimmer sun) and ``sealed_rooms_midslab`` (1.2 m slabs, probe layers on their mid-planes;
  both :mod:`dyngi.scene.builtin_probe_leaks`), sealed/open below 1% on each of frames 0-19, and no
  back-and-forth of that ratio between consecutive frames above 0.002 (before the fixes: ``adgi`` 0.043 /
  0.018 on even / odd frames of 'dim'; ``isddgi`` 0.11-0.12 from frame 0 on 'midslab').

Settings: ``probes-reference`` at fewer texels and rays (its default costs
minutes here); ``ddgi-secondary``/``ddgi-resampling`` in the hall without
Sec. 3.3's emission heuristic (``emission_attenuation='none'``): the
heuristic ``(t/(t+d))^2`` is a deliberate bias of the paper that holds them at
0.85-0.88 of the reference on this 3-layer grid with or without any leak
(1.06 / 1.04 without it; 0.99 / 0.96 with the heuristic on a 4-layer grid).

Unit tests below check the pieces: the two-sided rule on a slab and on a room
of outward-facing planes, relocation that never crosses a surface, and the
fallback that never reads a probe behind a wall.
"""
from __future__ import annotations

import functools
import os

import numpy as np
import pytest

from dyngi.backend import dr, mi
from dyngi.scene import builtin_names, load_scene
from dyngi.techniques import Frame, create_technique
from dyngi.techniques.base import get_technique, probe_technique_names, technique_names

RES = (64, 36)
FRAMES = 12
SETTLED = 6
FAST = ("ddgi", "qddgi")
SETTINGS = {"probes-reference": {"texels": 16, "rays_per_texel": 32}}
HALL_SETTINGS = {"ddgi-secondary": {"emission_attenuation": "none"},
                 "ddgi-resampling": {"emission_attenuation": "none"}}
VEACH_SETTINGS = {"probes-reference": {"texels": 8, "rays_per_texel": 16}}
VEACH_FLOOR = 0.79
"""veach-bidir mean / Mitsuba's at least this (ddgi 0.79 at 160x90; 0.82 here) ..."""
VEACH_FLOORS = {"qddgi": 0.72, "isddgi": 0.74, "ddgi-primary": 0.72, "ddgi-secondary": 0.58,
                "ddgi-resampling": 0.58}
"""... or these technique floors, recorded 2026-12-02 (64x36, frames 6-11), the same before and after issue
22: qddgi 0.759 (quantised caches, 32 rays, frustum culling), isddgi 0.782, ddgi-primary 0.766,
ddgi-secondary 0.630 / ddgi-resampling 0.626 (DDGI+ at the secondary vertex; veach-bidir's light is mostly
glossy). Losing the two-sided gain takes them to about half (ddgi 0.36)."""
PROBE_TECHNIQUES = [pytest.param(n, marks=() if n in FAST else pytest.mark.slow) for n in probe_technique_names()]


def _mean_image(name: str, scene, params: dict | None = None, camera=None) -> np.ndarray:
    scene.at(0.0)
    tech = create_technique(name, scene, {**SETTINGS.get(name, {}), **(params or {})})
    cam = camera if camera is not None else scene.camera(0.0)
    imgs = [tech.step(Frame(i, 0.0, cam, RES, seed=3, static=i > 0)).image for i in range(FRAMES)]
    img = np.mean(imgs[SETTLED:], 0)
    assert np.all(np.isfinite(img))
    return img


def _volume(tech):
    """The ProbeVolume a probe technique traces (ddgi-style, ddgi-primary's and DDGI+'s)."""
    for path in ("volume", "probes.volume", "vol.volume"):
        obj = tech
        try:
            for part in path.split("."):
                obj = getattr(obj, part)
        except AttributeError:
            continue
        return obj
    raise AssertionError(f"no probe volume on {type(tech).__name__}")


# -- registry and scenes ----------------------------------------------------------------------------

def test_every_probe_technique_is_flagged_and_takes_the_two_sided_rule():
    """The flag marks exactly the techniques with a probe volume (those that take ``two_sided``), and the
    parameter reaches the volume their probe rays are traced in."""
    names = set(probe_technique_names())
    assert names == {n for n in technique_names() if "two_sided" in get_technique(n).PARAMS}
    assert {"ddgi", "qddgi", "probes-reference", "adgi", "isddgi", "ddgi-primary", "ddgi-secondary",
            "ddgi-resampling"} <= names
    sc = load_scene("sealed-rooms")
    for n in sorted(names):
        assert get_technique(n).PARAMS["two_sided"].default == "enclosed"
        for rule in ("front", "enclosed"):
            assert _volume(create_technique(n, sc, {"two_sided": rule})).two_sided == rule, (n, rule)


def test_analog_scenes_are_registered_and_their_grids_start_inside_slabs():
    from dyngi.probes import ProbeGrid
    from dyngi.scene import builtin_probe_leaks as L

    for name in ("sealed-rooms", "sealed-rooms-open", "stair-hall"):
        assert name in builtin_names()
    for name, slabs in (("sealed-rooms", [(-L.SEALED_SLAB, 0.0), (L.SEALED_H, L.SEALED_H + L.SEALED_SLAB)]),
                        ("stair-hall", [(-L.HALL_T, 0.0), (L.HALL_GALLERY, L.HALL_GALLERY + L.HALL_T),
                                        (L.HALL_H, L.HALL_H + L.HALL_T)])):
        g = ProbeGrid.from_scene(load_scene(name))
        ys = sorted(set(np.round(g.base_positions()[:, 1], 6)))
        assert len(ys) == len(slabs)
        for y, (lo, hi) in zip(ys, slabs):
            assert lo < y < hi, (name, y, lo, hi)        # every layer starts inside a slab


def test_mitsuba_renders_the_sealed_room_black():
    sc = load_scene("sealed-rooms")
    img = np.asarray(mi.render(sc.mi_scene, sensor=sc.camera(0.0).to_sensor((32, 18), 16),
                               integrator=mi.load_dict({"type": "path", "max_depth": -1}), spp=16, seed=1))
    assert img.max() == 0.0
    sc = load_scene("sealed-rooms-open")
    img = np.asarray(mi.render(sc.mi_scene, sensor=sc.camera(0.0).to_sensor((32, 18), 16),
                               integrator=mi.load_dict({"type": "path", "max_depth": -1}), spp=16, seed=1))
    assert img.mean() > 0.02


# -- the leaks, for every probe technique --------------------------------------------------------

@pytest.mark.parametrize("name", PROBE_TECHNIQUES)
def test_sealed_room_stays_dark(backend, name):
    """The sealed room's mean is below 1% of the open room's (measured after the fix: 0.0000-0.0032;
    before: ddgi 0.73)."""
    sealed = _mean_image(name, load_scene("sealed-rooms")).mean()
    lit = _mean_image(name, load_scene("sealed-rooms-open")).mean()
    print(f"{name}: sealed {sealed:.5f} open {lit:.5f} ratio {sealed / lit:.4f}")
    assert lit > 0.03, lit
    assert sealed < 0.01 * lit, (sealed, lit)


@pytest.mark.parametrize("name", PROBE_TECHNIQUES)
def test_stair_hall_within_10_percent_of_mitsuba(backend, name):
    """The tall hall lit from its ceiling is not over-lit (measured after the fix: 0.93-1.06; before: ddgi
    1.53, qddgi 1.62, isddgi 1.59)."""
    from dyngi.experiments.references.path import reference_image

    sc = load_scene("stair-hall")
    img = _mean_image(name, sc, HALL_SETTINGS.get(name))
    ref = reference_image(sc, 0.0, RES, 1024, 12)
    ratio = img.mean() / ref.mean()
    print(f"{name}: stair-hall mean ratio {ratio:.3f}")
    assert abs(ratio - 1.0) < 0.10, ratio


@pytest.mark.parametrize("name", PROBE_TECHNIQUES)
def test_veach_bidir_keeps_the_two_sided_gain(backend, name):
    from conftest import shared_scene
    from dyngi.experiments.references.path import reference_image, scene_max_depth

    sc = load_scene(shared_scene("veach-bidir/scene_mi3.xml"))
    img = _mean_image(name, sc, VEACH_SETTINGS.get(name))
    ref = reference_image(sc, 0.0, RES, 1024, scene_max_depth(sc))
    ratio = img.mean() / ref.mean()
    print(f"{name}: veach-bidir mean ratio {ratio:.3f}")
    assert ratio >= VEACH_FLOORS.get(name, VEACH_FLOOR), ratio


# -- the sealed room on every frame from frame 0 ---------------------------------------------

SEQUENCE = 20          # frames 0-19, as the real two-room scene was measured
ALTERNATION = 0.002    # the most a sealed/open ratio may go back and forth between consecutive frames


SEALED_VARIANTS = ("dim", "midslab")
"""The variants of the sealed-rooms building (:mod:`dyngi.scene.builtin_probe_leaks`): ``sealed_rooms_dim``
(white, a dimmer sun: ``adgi``'s toggling code) and ``sealed_rooms_midslab`` (1.2 m slabs, probe layers on
their mid-planes, a sky: ``isddgi``'s relocation by chance)."""


@functools.lru_cache(maxsize=None)
def _sealed_ratios(name: str, variant: str) -> tuple:
    """Per frame 0..19: mean(sealed view) / mean(open view) on a variant of the building
    (:data:`SEALED_VARIANTS`), and the open room's means; shared by the two tests below."""
    from dyngi.scene import builtin_probe_leaks as L

    make = getattr(L, f"sealed_rooms_{variant}")
    means = []
    for view in ("sealed", "open"):
        sc = make(view)
        sc.at(0.0)
        tech = create_technique(name, sc, SETTINGS.get(name, {}))
        cam = sc.camera(0.0)
        imgs = [tech.step(Frame(i, 0.0, cam, RES, seed=3, static=i > 0)).image for i in range(SEQUENCE)]
        assert all(np.all(np.isfinite(im)) for im in imgs)
        means.append(np.array([im.mean() for im in imgs]))
    return means[0] / means[1], means[1]


def alternation(r: np.ndarray) -> float:
    """The largest back-and-forth of a per-frame series: over consecutive differences of opposite sign
    (up then down, or down then up), the smaller of the two; 0 for a monotone series."""
    d = np.diff(np.asarray(r, np.float64))
    flip = d[:-1] * d[1:] < 0
    return float(np.max(np.where(flip, np.minimum(np.abs(d[:-1]), np.abs(d[1:])), 0.0), initial=0.0))


def test_alternation_measure():
    assert alternation([0.1, 0.2, 0.3, 0.4]) == 0.0
    assert alternation([0.028, 0.036, 0.028, 0.036]) == pytest.approx(0.008)
    assert alternation([0.0, 0.01, 0.009]) == pytest.approx(0.001)


@pytest.mark.parametrize("variant", SEALED_VARIANTS)
@pytest.mark.parametrize("name", PROBE_TECHNIQUES)
def test_sealed_room_dark_on_every_frame_from_frame_0(backend, name, variant):
    """The sealed room below 1% of the open room on each of frames 0-19. Before the fixes: 'dim'
    ``adgi`` 0.043 / 0.018 on even / odd frames (the real scene: 0.028 / 0.036); 'midslab' ``isddgi``
    0.11-0.12 from frame 0 (fixed by the relocation rule of :mod:`dyngi.probes.states`)."""
    r, lit = _sealed_ratios(name, variant)
    print(f"{name} {variant}: sealed/open per frame " + " ".join(f"{x:.4f}" for x in r))
    assert np.all(lit > 0.001), lit          # the open room is lit
    assert np.all(r < 0.01), r


@pytest.mark.parametrize("variant", SEALED_VARIANTS)
@pytest.mark.parametrize("name", PROBE_TECHNIQUES)
def test_sealed_ratio_does_not_alternate(backend, name, variant):
    """No back-and-forth of the sealed/open ratio between consecutive frames above 0.002 (before the fix
    ``adgi`` 0.023: its convolved irradiance toggled one code every frame)."""
    r, _ = _sealed_ratios(name, variant)
    a = alternation(r)
    print(f"{name} {variant}: alternation {a:.5f}")
    assert a <= ALTERNATION, (a, r)


# -- the pieces ---------------------------------------------------------------------------------------

def _box_scene(shapes: dict):
    return mi.load_dict({"type": "scene", **shapes})


def _mesh(V, F, two_sided=True):
    from dyngi.scene.geometry import make_mesh

    bsdf = {"type": "diffuse"}
    return make_mesh("m", V, F, {"type": "twosided", "bsdf": bsdf} if two_sided else bsdf)


def _back_ratio(mscene, grid, pos, rule):
    from dyngi.probes import FixedSFDirections, ProbeVolume
    from dyngi.probes.trace import trace_probe_distances

    vol = ProbeVolume(grid, two_sided=rule)
    vol.state.offsets[:] = (np.asarray(pos) - grid.base_positions()).astype(np.float32)
    vol.sync(("positions",))
    ids = np.arange(vol.n_probes, dtype=np.uint32)
    plan = FixedSFDirections(64, stream=3).plan(0, 0, ids)
    d = np.asarray(trace_probe_distances(mscene, vol, plan)).reshape(len(ids), -1)
    return (d < 0).mean(1), vol


def test_two_sided_rule_slab_inside_room_outside(backend):
    """'enclosed': inside a two-sided slab thinner than a cell the probe sees back faces; in a room of
    outward-facing two-sided planes (wider than a cell) it sees front faces. 'front' sees no back face
    in either, 'back' sees back faces in both."""
    from dyngi.probes import ProbeGrid
    from dyngi.scene.geometry import box, merge, quad

    grid = ProbeGrid((-1.0, -1.0, -1.0), (1.0, 1.0, 1.0), (2, 2, 2))
    slab = _box_scene({"slab": _mesh(*box((-5, -0.2, -5), (5, 0.2, 5)))})
    probe = np.tile([[0.3, 0.05, 0.2]], (8, 1))
    # a 6 m room of single outward-facing planes (veach-bidir's walls)
    R = 3.0
    room = merge([quad((R, 0, 0), (0, R, 0), (0, 0, R)), quad((-R, 0, 0), (0, 0, R), (0, R, 0)),
                  quad((0, R, 0), (0, 0, R), (R, 0, 0)), quad((0, -R, 0), (R, 0, 0), (0, 0, R)),
                  quad((0, 0, R), (R, 0, 0), (0, R, 0)), quad((0, 0, -R), (0, R, 0), (R, 0, 0))])
    V, F = room
    c = V[F].mean(1)
    nrm = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    assert np.all(np.sum(nrm * c, 1) > 0)              # every plane faces outwards
    rooms = _box_scene({"room": _mesh(*room)})
    center = np.tile([[0.3, 0.05, 0.2]], (8, 1))
    # 'enclosed' inside the slab: every ray across it is a back face, rays along it (a chord longer than
    # a cell) are not; well above ProbeStates' 0.25 threshold either way
    slab_ratio = _back_ratio(slab, grid, probe, "enclosed")[0]
    assert np.all(slab_ratio > 0.5), slab_ratio
    assert np.allclose(_back_ratio(rooms, grid, center, "enclosed")[0], 0.0)
    for rule, both in (("front", 0.0), ("back", 1.0)):
        assert np.allclose(_back_ratio(slab, grid, probe, rule)[0], both), rule
        assert np.allclose(_back_ratio(rooms, grid, center, rule)[0], both), rule


def test_relocation_never_moves_a_probe_through_a_surface(backend):
    """A probe pushed away from a front face stops before the thin wall behind it; a probe inside a slab
    leaves it through its nearest face and stops before the next surface; with 'front' the slab probe
    stays in the slab (it is not inside anything, and may not cross the slab's faces)."""
    from dyngi.probes import FixedSFDirections, ProbeGrid, ProbeStates
    from dyngi.probes.states import safe_moves
    from dyngi.probes.trace import trace_probe_distances
    from dyngi.scene.geometry import box

    # thin wall at x = 0.1 (two-sided, 2 cm), a probe at x = -0.05 pushed towards +x by 0.5: stays at x < 0.09
    wall = _box_scene({"w": _mesh(*box((0.09, -5, -5), (0.11, 5, 5)))})
    p = safe_moves(wall, np.array([[-0.05, 0.0, 0.0]]), np.array([[0.45, 0.0, 0.0]]), np.array([False]), 0.1)
    assert p[0, 0] < 0.09 and p[0, 0] >= -0.05 + 0.5 * (0.14 - 0.1) - 1e-6, p
    # inside a slab y in [-0.2, 0.2] with a ceiling at y = 0.5: crossing the slab's top is allowed, the
    # ceiling is not
    slab2 = _box_scene({"s": _mesh(*box((-5, -0.2, -5), (5, 0.2, 5))),
        "c": _mesh(*box((-5, 0.5, -5), (5, 0.6, 5)))})
    p = safe_moves(slab2, np.array([[0.0, 0.1, 0.0]]), np.array([[0.0, 0.9, 0.0]]), np.array([True]), 0.2)
    assert 0.2 < p[0, 1] < 0.5, p
    # full relocation on a slab probe under each rule
    grid = ProbeGrid((-1.0, 0.05, -1.0), (1.0, 1.0, 1.0), (2, 2, 2))
    slab = _box_scene({"slab": _mesh(*box((-5, -0.2, -5), (5, 0.2, 5)))})
    for rule in ("enclosed", "front"):
        _, vol = _back_ratio(slab, grid, grid.base_positions(), rule)
        states = ProbeStates(min_frontface=0.4)
        ids = np.arange(vol.n_probes, dtype=np.uint32)
        for f in range(4):
            plan = FixedSFDirections(64, stream=3).plan(f, 0, ids)
            states.update(vol, ids, plan.shared_directions, trace_probe_distances(slab, vol, plan))
        y = vol.positions()[:, 1]
        low = grid.base_positions()[:, 1] < 0.5            # the layer that starts inside the slab
        if rule == "enclosed":
            assert np.all(y[low] > 0.2), y                  # left through the nearest face (the top)
        else:
            assert np.all(np.abs(y[low]) < 0.2), y          # never through a face: still inside
        assert np.all(y[~low] > 0.2), y                     # the other layer never crosses the slab


def test_fallback_never_reads_a_probe_behind_a_wall(backend):
    """A cell whose 8 corners are inactive falls back to the nearest active probes only where the
    corners' visibility test would accept them: a candidate whose moments put a surface 0.1 away in
    every direction (behind a wall for a point 1.5 cells away) gives 0; far surfaces give its value."""
    from dyngi.probes import ProbeGrid, ProbeQuery, ProbeVolume

    grid = ProbeGrid((0.0, 0.0, 0.0), (1.0, 1.0, 1.0), (4, 2, 2))
    vol = ProbeVolume(grid, 6, 6)
    st = vol.state
    st.states[:] = 0
    st.states[3] = 1                             # only probe (3, 0, 0) is active
    st.irradiance[:] = 1.0
    pt = mi.Point3f(0.5, 0.5, 0.5)               # in cell (0, 0, 0): all 8 corners inactive
    n = mi.Vector3f(1.0, 0.0, 0.0)
    for mean, want in ((0.1, 0.0), (5.0, np.pi)):
        st.distance[..., 0] = mean
        st.distance[..., 1] = mean * mean
        vol.sync()
        q = ProbeQuery(vol)
        E = q.irradiance(pt, n, n)
        dr.eval(E)
        assert np.allclose(np.asarray(E.x), want, rtol=1e-4), (mean, E)
        # the stochastic lookup agrees
        from dyngi.sampling.rng import make_sampler
        E2 = q.irradiance(pt, n, n, sampler=make_sampler(1, 0, 0, 5))
        assert np.allclose(np.asarray(E2.x), want, rtol=1e-4), (mean, E2)

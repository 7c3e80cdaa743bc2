"""Built-in procedural animated scenes (the default scenes and the test fixtures).

Each stands in for a scene of one of the papers; the docstring of each factory
says which and what it exercises. Units are metres; y is up; every shape is a
triangle mesh with a stable id, every light an emitter of its own.

==========================  =====================================================
scene                       stands in for
==========================  =====================================================
cornell-moving-light/-box   DDGI/ADGI Cornell box tests (moving light / object)
cornell-static, furnace     convergence and furnace tests
tunnel-gate                 ADGI Bistro tunnel with an opening gate (Fig. 1, 8)
atrium-sun                  ADGI Sponza under a moving sun (Fig. 9)
glossy-floor                ADGI glossy Buddha (Fig. 10)
corridor-rooms              SMC-IR Soda Hall (14 lights, heavy occlusion)
maze                        SMC-IR Maze (13 lights, walking camera)
warehouse-lights            VLC/CDQ scene (a): 128 lights in 8 halls
sky-pit                     VLC/CDQ scene (b): mine open to the sky, sun
covered-lights              VLC/CDQ scene (c): 10 lights behind a cover
rotating-hidden-light       VLC/CDQ Sec. 7.3 CDQ adaptation (floor, wall, hidden light)
room-sun-blinds             issue 11: interior lit by Mitsuba's sunsky through blinds
room-sky-only               issue 11: the same room lit by the sky part only
light-behind-glass          issue 11: area light inside a thindielectric lamp box
room-metal-furniture        issue 11: conductor/roughconductor furniture, one light
==========================  =====================================================

Radiances are set so that a path-traced frame has a mean pixel value of
roughly 0.05-0.4 (linear); the tunnel with its gate closed is darker (~0.01)
by design.
"""
from __future__ import annotations

import numpy as np

from ..backend import mi
from .animation import ParamTrack, RigidMotion, SunMotion, Track
from .builder import SceneBuilder
from .camera import Camera, CameraPath
from .geometry import box, cylinder, diffuse, merge, quad, uv_sphere
from .library import builtin

WHITE = (0.725, 0.71, 0.68)
RED = (0.63, 0.065, 0.05)
GREEN = (0.14, 0.45, 0.091)
CORNELL_LIGHT = (17.0, 12.0, 4.0)


def _cornell_shell(b: SceneBuilder, light_size=(0.25, 0.2)):
    """Room [-1,1] x [0,2] x [-1,1], open at z=+1; light quad under the ceiling."""
    b.mesh("floor", quad((0, 0, 0), (0, 0, 1), (1, 0, 0)), diffuse(WHITE))
    b.mesh("ceiling", quad((0, 2, 0), (1, 0, 0), (0, 0, 1)), diffuse(WHITE))
    b.mesh("back", quad((0, 1, -1), (1, 0, 0), (0, 1, 0)), diffuse(WHITE))
    b.mesh("left", quad((-1, 1, 0), (0, 1, 0), (0, 0, 1)), diffuse(RED))
    b.mesh("right", quad((1, 1, 0), (0, 0, 1), (0, 1, 0)), diffuse(GREEN))
    lx, lz = light_size
    b.mesh("light", quad((0, 1.98, 0), (lx, 0, 0), (0, 0, lz)), diffuse((0.0, 0.0, 0.0)), CORNELL_LIGHT)


def _cornell_boxes(b: SceneBuilder):
    b.mesh("short_box", box((0.05, 0.0, -0.05), (0.65, 0.6, 0.55)), diffuse(WHITE))
    b.mesh("tall_box", box((-0.65, 0.0, -0.7), (-0.05, 1.2, -0.1)), diffuse(WHITE))


CORNELL_CAMERA = Camera((0.0, 1.0, 3.9), (0.0, 1.0, 0.0), (0.0, 1.0, 0.0), 39.3)
CORNELL_PROBES = (((-0.9, 0.1, -0.9), (0.9, 1.9, 0.9)), (8, 8, 8))


@builtin("cornell-moving-light", "Cornell box whose ceiling light slides left-right",
         "DDGI/ADGI light-moves test; the classic diffuse interreflection box")
def cornell_moving_light():
    """The Cornell box (open front) whose ceiling light slides left and right and back in 2 s.

    The moving-light test of DDGI (Majercik et al.) and ADGI (Datta et al., Sec. 6):
    diffuse interreflection with strong colour bleeding, where every probe's
    irradiance changes every frame but no geometry moves.
    """
    b = SceneBuilder("cornell-moving-light")
    _cornell_shell(b)
    _cornell_boxes(b)
    b.animate(RigidMotion("light", translate=Track([0, 1, 2], [[-0.6, 0, 0], [0.6, 0, 0], [-0.6, 0, 0]],
                                                    interp="smooth", loop=True)))
    return b.build(CORNELL_CAMERA, "Cornell box whose ceiling light slides left-right",
                   duration=2.0, probe_box=CORNELL_PROBES[0], probe_counts=CORNELL_PROBES[1])


@builtin("cornell-moving-box", "Cornell box whose short box slides across the floor",
         "DDGI dynamic-geometry test: probes must re-classify and re-converge")
def cornell_moving_box():
    """The Cornell box whose short box slides across the floor and turns half a revolution.

    The dynamic-geometry test of DDGI-family techniques: probes inside or
    next to the moving box must be re-classified (probe states) and their
    irradiance and visibility (Chebyshev) moments re-converge.
    """
    b = SceneBuilder("cornell-moving-box")
    _cornell_shell(b)
    _cornell_boxes(b)
    b.animate(RigidMotion("short_box", translate=Track([0, 1, 2], [[0, 0, 0], [-0.6, 0, 0.3], [0, 0, 0]],
                                                        interp="smooth", loop=True),
                          angle=Track([0, 2], [[0.0], [np.pi]], loop=True), pivot=(0.35, 0, 0.25)))
    return b.build(CORNELL_CAMERA, "Cornell box whose short box slides across the floor",
                   duration=2.0, probe_box=CORNELL_PROBES[0], probe_counts=CORNELL_PROBES[1])


@builtin("cornell-static", "Static Cornell box (convergence and progressive-accumulation tests)",
         "the classic Cornell box")
def cornell_static():
    """The static Cornell box: convergence of probe blending, progressive accumulation, static adaptive sampling
    (ADGI, Sec. 4.8 and Fig. 7) and no-recompilation tests."""
    b = SceneBuilder("cornell-static")
    _cornell_shell(b)
    _cornell_boxes(b)
    return b.build(CORNELL_CAMERA, "Static Cornell box", duration=1.0,
                   probe_box=CORNELL_PROBES[0], probe_counts=CORNELL_PROBES[1])


@builtin("furnace", "Closed sphere, diffuse albedo 0.5 and emission 0.5: radiance 1 everywhere",
         "the furnace test of every integrator")
def furnace():
    """Closed inward-facing sphere with albedo 0.5 and emission 0.5: L = 0.5 + 0.5 L gives L = 1 everywhere.

    The furnace test (STYLE.md, tests 3) every integrator and probe technique
    must pass with unbounded depth; with ``max_depth = d`` the exact value is
    ``1 - 0.5**d``.
    """
    b = SceneBuilder("furnace")
    b.mesh("sphere", uv_sphere((0, 0, 0), 1.0, 24, 48, inward=True), diffuse((0.5, 0.5, 0.5)), (0.5, 0.5, 0.5))
    return b.build(Camera((0.0, 0.0, 0.5), (0.0, 0.0, -1.0), (0, 1, 0), 60.0), "furnace", duration=1.0,
                   probe_box=((-0.5, -0.5, -0.5), (0.5, 0.5, 0.5)), probe_counts=(4, 4, 4))


# ---------------------------------------------------------------------------
# shared helpers for the larger procedural scenes
# ---------------------------------------------------------------------------
STONE = (0.62, 0.57, 0.5)
CONCRETE = (0.5, 0.5, 0.48)
PLASTER = (0.7, 0.68, 0.64)
DARK = (0.0, 0.0, 0.0)


def _sun(direction, irradiance) -> dict:
    """Directional emitter; ``direction`` is the direction light travels (towards the ground)."""
    d = np.asarray(direction, np.float64)
    return {"type": "directional", "direction": (d / np.linalg.norm(d)).tolist(),
            "irradiance": {"type": "rgb", "value": list(map(float, irradiance))}}


def _sky(radiance) -> dict:
    return {"type": "constant", "radiance": {"type": "rgb", "value": list(map(float, radiance))}}


def _sun_dir(elevation_deg: float, azimuth_deg: float) -> np.ndarray:
    """Travel direction of sunlight coming from elevation/azimuth (azimuth from +x towards +z)."""
    el, az = np.radians(elevation_deg), np.radians(azimuth_deg)
    return -np.array([np.cos(el) * np.cos(az), np.sin(el), np.cos(el) * np.sin(az)])


def _floor(x0, x1, z0, z1, y=0.0):
    """Horizontal rectangle facing +y."""
    return quad(((x0 + x1) / 2, y, (z0 + z1) / 2), (0, 0, (z1 - z0) / 2), ((x1 - x0) / 2, 0, 0))


def _ceiling(x0, x1, z0, z1, y):
    """Horizontal rectangle facing -y."""
    return quad(((x0 + x1) / 2, y, (z0 + z1) / 2), ((x1 - x0) / 2, 0, 0), (0, 0, (z1 - z0) / 2))


def _ceiling_light(x, y, z, half=0.15):
    """Small square emitter facing down (-y) centred at (x, y, z)."""
    return quad((x, y, z), (half, 0, 0), (0, 0, half))


def _wall(axis: str, pos: float, a0: float, a1: float, height: float, doors=(), thick: float = 0.1,
          y0: float = 0.0):
    """Solid wall (boxes) on the plane ``axis = pos`` spanning [a0, a1] along the other horizontal axis.

    ``doors`` are (b0, b1, door_height) openings along that axis; a lintel closes
    the wall above each door.
    """
    h = thick / 2
    pieces, cur = [], a0
    spans = []
    for b0, b1, dh in sorted(doors):
        if b0 > cur:
            spans.append((cur, b0, y0, y0 + height))
        if dh < height:
            spans.append((b0, b1, y0 + dh, y0 + height))
        cur = b1
    if cur < a1:
        spans.append((cur, a1, y0, y0 + height))
    for s0, s1, ylo, yhi in spans:
        if axis == "x":
            pieces.append(box((pos - h, ylo, s0), (pos + h, yhi, s1)))
        else:
            pieces.append(box((s0, ylo, pos - h), (s1, yhi, pos + h)))
    return merge(pieces)


def _twosided(rgb) -> dict:
    return {"type": "twosided", "bsdf": diffuse(rgb)}


# ---------------------------------------------------------------------------
# ADGI (Datta et al.) stand-ins
# ---------------------------------------------------------------------------
@builtin("tunnel-gate", "Tunnel through a hill whose entry gate slides open; interior lit only indirectly",
         "ADGI's modified Bistro Exterior tunnel (Fig. 1, 8)")
def tunnel_gate():
    """A 4 m wide, 3.5 m high, 14 m long tunnel through a hill, entry at z = 0.

    Stands for the tunnel of ADGI's modified BISTRO EXTERIOR (Sec. 6, Fig. 1 and
    8): the sun (directional) and a constant sky light the outside; the tunnel
    interior walls are lit only indirectly, by sunlight bouncing off the floor
    patch behind the entry gate. The gate (a rigid box) slides up between
    t = 0.5 s and 3.5 s, so the directly lit patch grows from nothing: it
    exercises how fast probe techniques track a moving, indirect-only change
    close to a dynamic object, and the low-light colour encodings. The far exit
    stays open (dim sky light only), so no frame is black.
    """
    b = SceneBuilder("tunnel-gate")
    L, W, H = 14.0, 2.0, 3.5
    b.mesh("ground", _floor(-20, 20, -30, 20), diffuse((0.45, 0.42, 0.38)))
    hill = merge([box((-12, 0, -L), (-W, 8, 0)), box((W, 0, -L), (12, 8, 0)), box((-W, H, -L), (W, 8, 0))])
    b.mesh("hill", hill, diffuse(STONE))
    b.mesh("gate", box((-W - 0.2, 0.0, 0.0), (W + 0.2, H + 0.2, 0.2)), diffuse((0.55, 0.3, 0.15)))
    b.add("sun", _sun((0.25, -0.6, -0.75), (8.0, 7.5, 6.6)))
    b.add("sky", _sky((0.5, 0.62, 0.8)))
    b.animate(RigidMotion("gate", translate=Track([0.0, 0.5, 3.5, 4.0], [[0, 0, 0], [0, 0, 0], [0, 3.6, 0],
                                                                         [0, 3.6, 0]], interp="smooth")))
    cam = Camera((1.2, 1.7, -11.0), (0.0, 1.2, 0.0), (0, 1, 0), 60.0)
    return b.build(cam, "Tunnel whose entry gate slides open; interior lit indirectly", duration=4.0,
                   probe_box=((-1.9, 0.1, -13.9), (1.9, 3.4, 3.0)), probe_counts=(8, 6, 32))


@builtin("atrium-sun", "Sponza-like atrium with colonnades and galleries under a moving sun",
         "ADGI's Sponza under dynamic lighting (Fig. 9)")
def atrium_sun():
    """An open-roof courtyard (20 x 12 m, 8 m high) with two colonnades and covered galleries.

    Stands for ADGI's Sponza under dynamic lighting (Sec. 6, Fig. 9): the sun
    (directional, :class:`SunMotion`) sweeps in azimuth and elevation over 6 s,
    moving its lit patch across the floor, the columns and into one gallery; a
    dim constant sky fills the shadows. Coloured drapes between the columns add
    colour bleeding. Nothing moves but the light: it tests change *detection*
    without dynamic geometry.
    """
    b = SceneBuilder("atrium-sun")
    X, Z, H = 10.0, 6.0, 8.0
    b.mesh("floor", _floor(-X, X, -Z, Z), diffuse((0.55, 0.5, 0.42)))
    walls = merge([box((-X - 0.3, 0, -Z - 0.3), (X + 0.3, H, -Z)), box((-X - 0.3, 0, Z), (X + 0.3, H, Z + 0.3)),
                   box((-X - 0.3, 0, -Z), (-X, H, Z)), box((X, 0, -Z), (X + 0.3, H, Z))])
    b.mesh("walls", walls, diffuse(STONE))
    # galleries: slabs at 3.5 m and a roof at 7 m over |z| in [3, 6], with parapets
    slabs = []
    for s in (-1, 1):
        z0, z1 = sorted((s * 3.0, s * Z))
        slabs += [box((-X, 3.5, z0), (X, 3.8, z1)), box((-X, 7.0, z0), (X, 7.3, z1)),
                  box((-X, 3.8, s * 3.0 - 0.1), (X, 4.7, s * 3.0 + 0.1))]
    b.mesh("galleries", merge(slabs), diffuse(PLASTER))
    # colonnades: columns every 2 m with lintels ("arches") on both storeys
    cols = []
    for s in (-1, 1):
        for x in np.arange(-8.0, 8.01, 2.0):
            cols.append(cylinder((x, 0.0, s * 3.0), 0.25, 3.5, n=12, caps=False))
            cols.append(cylinder((x, 4.7, s * 3.0), 0.2, 2.3, n=12, caps=False))
        cols.append(box((-X, 3.0, s * 3.0 - 0.3), (X, 3.5, s * 3.0 + 0.3)))
        cols.append(box((-X, 6.6, s * 3.0 - 0.25), (X, 7.0, s * 3.0 + 0.25)))
    b.mesh("colonnades", merge(cols), diffuse(STONE))
    drapes_r = merge([quad((x, 5.6, -2.95), (0.8, 0, 0), (0, 1.0, 0)) for x in (-5.0, 1.0, 7.0)])
    drapes_g = merge([quad((x, 5.6, 2.95), (0.8, 0, 0), (0, -1.0, 0)) for x in (-7.0, -1.0, 5.0)])
    b.mesh("drapes_red", drapes_r, _twosided((0.6, 0.08, 0.06)))
    b.mesh("drapes_green", drapes_g, _twosided((0.1, 0.45, 0.12)))
    b.add("sun", _sun(_sun_dir(60.0, 100.0), (5.0, 4.7, 4.2)))
    b.add("sky", _sky((0.12, 0.15, 0.2)))
    times = [0.0, 2.0, 4.0, 6.0]
    dirs = [_sun_dir(55.0, 60.0), _sun_dir(68.0, 100.0), _sun_dir(62.0, 150.0), _sun_dir(50.0, 200.0)]
    b.animate(SunMotion("sun", Track(times, dirs, interp="smooth")))
    cam = Camera((-9.0, 1.7, 0.5), (4.0, 3.5, -0.5), (0, 1, 0), 70.0)
    return b.build(cam, "Sponza-like atrium under a moving sun", duration=6.0,
                   probe_box=((-9.6, 0.3, -5.6), (9.6, 7.6, 5.6)), probe_counts=(24, 8, 12))


@builtin("glossy-floor", "Statue stand-in moving over a glossy floor under ambient sky light and one area light",
         "ADGI's glossy Buddha (Fig. 10)")
def glossy_floor():
    """A statue stand-in (pedestal, body and head) sliding and turning over a glossy floor.

    Stands for ADGI's Stanford Buddha on a glossy floor (Sec. 6, Fig. 10): the
    floor is dark ``roughplastic`` (GGX, alpha 0.04), so probes must resolve
    view-dependent glossy indirect light, and the moving object changes it. The
    direct light is ambient (constant sky) plus one overhead area light; two
    coloured walls give something to reflect. Probe spacing is denser than
    elsewhere, as ADGI uses for its glossy scene.
    """
    b = SceneBuilder("glossy-floor")
    S = 6.0
    b.mesh("floor", _floor(-S, S, -S, S), {"type": "roughplastic", "distribution": "ggx", "alpha": 0.04, "int_ior": 1.8,
                                           "diffuse_reflectance": {"type": "rgb", "value": [0.08, 0.08, 0.09]}})
    b.mesh("back_wall", box((-S, 0, -S - 0.2), (S, 4.0, -S)), diffuse((0.7, 0.45, 0.2)))
    b.mesh("left_wall", box((-S - 0.2, 0, -S), (-S, 4.0, S)), diffuse((0.2, 0.35, 0.65)))
    Vb, Fb = uv_sphere((0.0, 0.0, 0.0), 1.0, 12, 24)
    body = (Vb * [0.5, 0.6, 0.4] + [0.0, 0.95, 0.0], Fb)
    statue = merge([box((-0.45, 0.0, -0.45), (0.45, 0.35, 0.45)), body, uv_sphere((0.0, 1.75, 0.0), 0.25, 10, 20)])
    b.mesh("statue", statue, diffuse((0.8, 0.7, 0.35)))
    b.mesh("light", _ceiling_light(1.5, 4.0, 1.0, half=0.5), diffuse(DARK), (12.0, 11.0, 9.5))
    b.add("sky", _sky((0.35, 0.38, 0.42)))
    b.animate(RigidMotion("statue", translate=Track([0, 2, 4], [[-2.0, 0, 0], [2.0, 0, 0.5], [-2.0, 0, 0]],
                                                    interp="smooth", loop=True),
                          angle=Track([0, 4], [[0.0], [2 * np.pi]], loop=True)))
    cam = Camera((0.5, 1.1, 6.5), (0.0, 0.7, 0.0), (0, 1, 0), 55.0)
    return b.build(cam, "Statue stand-in moving over a glossy floor", duration=4.0,
                   probe_box=((-5.8, 0.1, -5.8), (5.8, 3.0, 5.8)), probe_counts=(16, 5, 16))


# ---------------------------------------------------------------------------
# SMC instant radiosity (Hedman et al.) stand-ins
# ---------------------------------------------------------------------------
CORRIDOR_SWITCHED = {  # light id -> (times, on/off values): step tracks
    "light_room_1_n": ([0.0, 1.0, 3.0], [1.0, 0.0, 1.0]),
    "light_room_3_s": ([0.0, 2.0], [0.0, 1.0]),
    "light_hall_2": ([0.0, 1.5, 2.5], [1.0, 0.0, 1.0]),
    "light_room_4_n": ([0.0, 2.0], [1.0, 0.0]),
}


@builtin("corridor-rooms", "Corridor with ten side rooms and 14 small ceiling lights, some switching on/off",
         "SMC-IR's Soda Hall (heavy occlusion, rooms seen through doors)")
def corridor_rooms():
    """A 20 m corridor with five 4 x 4 m rooms on each side, reached through 1 m doors.

    Stands for Soda Hall in SMC instant radiosity (Hedman et al., Sec. 5,
    Table 1: 14 static lights): only a small part of the scene is visible, and
    rooms behind walls are brightly lit but contribute nothing to the image.
    Fourteen small (0.3 x 0.3 m) ceiling area lights, four in the corridor and
    one per room; four of them switch on or off (step tracks on their
    radiance), so rooms seen through the doors appear and disappear. Exercises
    visibility-aware VPL placement and many-light NEE under heavy occlusion.
    """
    b = SceneBuilder("corridor-rooms")
    X, Z, H, C = 20.0, 5.0, 3.0, 1.0  # length, half depth, height, corridor half width
    b.mesh("floor", _floor(0, X, -Z, Z), diffuse((0.45, 0.4, 0.35)))
    b.mesh("ceiling", _ceiling(0, X, -Z, Z, H), diffuse(PLASTER))
    doors = [(4.0 * k + 0.6, 4.0 * k + 1.6, 2.2) for k in range(5)]
    walls = [_wall("z", -Z, 0, X, H), _wall("z", Z, 0, X, H), _wall("x", 0.0, -Z, Z, H), _wall("x", X, -Z, Z, H),
             _wall("z", -C, 0, X, H, doors), _wall("z", C, 0, X, H, doors)]
    for k in range(1, 5):
        walls += [_wall("x", 4.0 * k, C, Z, H), _wall("x", 4.0 * k, -Z, -C, H)]
    b.mesh("walls", merge(walls), diffuse((0.65, 0.63, 0.58)))
    furniture = []
    for k in range(5):
        for s in (-1, 1):
            zc = s * 3.0
            furniture += [box((4 * k + 1.2, 0.0, zc - 0.5), (4 * k + 2.8, 0.75, zc + 0.5)),   # table
                          box((4 * k + 3.2, 0.0, zc - 1.5), (4 * k + 3.8, 1.9, zc + 1.5))]   # shelf
    b.mesh("furniture", merge(furniture), diffuse((0.5, 0.35, 0.22)))
    radiance = (40.0, 37.0, 32.0)
    for i, x in enumerate((2.0, 7.0, 12.0, 17.0)):
        b.mesh(f"light_hall_{i}", _ceiling_light(x, H - 0.01, 0.0), diffuse(DARK), radiance)
    for k in range(5):
        for s, tag in ((1, "n"), (-1, "s")):
            b.mesh(f"light_room_{k}_{tag}", _ceiling_light(4 * k + 2.0, H - 0.01, s * 3.0), diffuse(DARK), radiance)
    for sid, (times, vals) in CORRIDOR_SWITCHED.items():
        b.animate(ParamTrack(f"{sid}.emitter.radiance.value", Track(times, vals, interp="step")))
    cam = Camera((0.5, 1.6, 0.4), (20.0, 1.2, -0.6), (0, 1, 0), 65.0)
    return b.build(cam, "Corridor with side rooms and 14 lights, some switching", duration=4.0,
                   probe_box=((0.25, 0.25, -4.75), (19.75, 2.75, 4.75)), probe_counts=(32, 4, 16))


def _maze(n: int, seed: int):
    """Perfect maze on an n x n grid by a depth-first backtracker; returns the set of open cell pairs."""
    rng = np.random.default_rng(seed)
    seen = np.zeros((n, n), bool)
    stack, open_pairs = [(0, 0)], set()
    seen[0, 0] = True
    while stack:
        i, j = stack[-1]
        nbrs = [(i + di, j + dj) for di, dj in ((1, 0), (-1, 0), (0, 1), (0, -1))
                if 0 <= i + di < n and 0 <= j + dj < n and not seen[i + di, j + dj]]
        if not nbrs:
            stack.pop()
            continue
        c = nbrs[rng.integers(len(nbrs))]
        seen[c] = True
        open_pairs.add(frozenset(((i, j), c)))
        stack.append(c)
    return open_pairs


def _maze_path(n: int, open_pairs, start, goal):
    """Cells from ``start`` to ``goal`` (breadth-first search over open pairs)."""
    prev, frontier = {start: None}, [start]
    while frontier:
        nxt = []
        for c in frontier:
            for di, dj in ((1, 0), (-1, 0), (0, 1), (0, -1)):
                d = (c[0] + di, c[1] + dj)
                if d not in prev and frozenset((c, d)) in open_pairs:
                    prev[d] = c
                    nxt.append(d)
        frontier = nxt
    path, c = [], goal
    while c is not None:
        path.append(c)
        c = prev[c]
    return path[::-1]


@builtin("maze", "Roofed 8 x 8 maze with 13 small lights (11 area, 2 point); the camera walks through it",
         "SMC-IR's Maze (13 static lights, walkthrough)")
def maze():
    """A roofed maze of 8 x 8 cells (2 m each, walls 2.4 m high) generated with a fixed seed.

    Stands for the Maze of SMC instant radiosity (Hedman et al., Sec. 5,
    Table 1: 13 static lights): thirteen small lights (eleven 0.3 x 0.3 m
    ceiling area lights and two point lights) in scattered cells; the camera
    walks 7 cells along the maze's solution path in 6 s, so the set of
    indirectly visible surfaces changes every second. Probes sit at cell
    centres (spacing 1 m, never inside a wall).
    """
    n, cell, H = 8, 2.0, 2.4
    pairs = _maze(n, seed=2)  # seed chosen for a walk with straight runs and three turns
    b = SceneBuilder("maze")
    S = n * cell
    b.mesh("floor", _floor(0, S, 0, S), diffuse((0.5, 0.45, 0.4)))
    b.mesh("ceiling", _ceiling(0, S, 0, S, H), diffuse(PLASTER))
    walls = [_wall("x", 0.0, 0, S, H), _wall("x", S, 0, S, H), _wall("z", 0.0, 0, S, H), _wall("z", S, 0, S, H)]
    for i in range(n):
        for j in range(n):
            if i + 1 < n and frozenset(((i, j), (i + 1, j))) not in pairs:  # wall between cell i and i+1 along x
                walls.append(_wall("x", (i + 1) * cell, j * cell - 0.05, (j + 1) * cell + 0.05, H))
            if j + 1 < n and frozenset(((i, j), (i, j + 1))) not in pairs:
                walls.append(_wall("z", (j + 1) * cell, i * cell - 0.05, (i + 1) * cell + 0.05, H))
    b.mesh("walls", merge(walls), diffuse((0.62, 0.6, 0.56)))
    path = _maze_path(n, pairs, (0, 0), (n - 1, n - 1))
    centre = lambda c: np.array([(c[0] + 0.5) * cell, 0.0, (c[1] + 0.5) * cell])  # noqa: E731
    rng = np.random.default_rng(11)
    on_path = [path[k] for k in (1, 3, 5, 7) if k < len(path)]
    others = [c for c in ((i, j) for i in range(n) for j in range(n)) if c not in path[:9]]
    cells = on_path + [others[k] for k in rng.choice(len(others), 13 - len(on_path), replace=False)]
    radiance = (45.0, 40.0, 33.0)
    for k, c in enumerate(cells):
        p = centre(c)
        if k in (2, 7):  # two point lights, intensity ~ on-axis intensity of an area light (L * A)
            b.add(f"point_{k}", {"type": "point", "position": [float(p[0]), 1.9, float(p[2])],
                                 "intensity": {"type": "rgb", "value": [v * 0.09 for v in radiance]}})
        else:
            b.mesh(f"light_{k}", _ceiling_light(p[0], H - 0.01, p[2]), diffuse(DARK), radiance)
    walk = [centre(c) + [0, 1.5, 0] for c in path[:8]]
    look = walk[1:] + [2 * walk[-1] - walk[-2]]
    times = np.linspace(0.0, 6.0, len(walk))
    cam = CameraPath(Track(times, walk), Track(times, look), (0.0, 1.0, 0.0), 75.0)
    return b.build(cam, "Maze with 13 lights and a walking camera", duration=6.0,
                   probe_box=((0.5, 0.4, 0.5), (S - 0.5, 2.0, S - 0.5)), probe_counts=(16, 3, 16))


# ---------------------------------------------------------------------------
# VLC / CDQ (Dittebrandt et al.) stand-ins
# ---------------------------------------------------------------------------
@builtin("warehouse-lights", "Eight connected warehouse halls with 128 small ceiling lights; the camera walks "
         "through a door", "VLC/CDQ scene (a): Quake 2 RTX warehouse with many lights")
def warehouse_lights():
    """Eight 10 x 10 m halls (6 m high) in a 4 x 2 layout, joined by 2 x 3 m doors.

    Stands for scene (a) of Dittebrandt et al. (Sec. 7.1, Fig. 8): a warehouse
    with many lights and mostly uniform illumination, of which only a few are
    visible from any point. Each hall has a 4 x 4 grid of 0.4 x 0.4 m ceiling
    lights, each its own mesh and emitter (128 emitters, so NEE really has
    to choose), plus four shelf blocks. The camera walks along the central aisle of
    the first hall through a door into the next over 6 s, changing the visible light set:
    it exercises the visibility light cache and its adaptation.
    """
    b = SceneBuilder("warehouse-lights")
    R, H, nx, nz = 10.0, 6.0, 4, 2
    X, Z = nx * R, nz * R
    b.mesh("floor", _floor(0, X, 0, Z), diffuse((0.42, 0.42, 0.4)))
    b.mesh("ceiling", _ceiling(0, X, 0, Z, H), diffuse((0.6, 0.6, 0.6)))
    walls = [_wall("x", 0.0, 0, Z, H), _wall("x", X, 0, Z, H), _wall("z", 0.0, 0, X, H), _wall("z", Z, 0, X, H)]
    for i in range(1, nx):
        walls += [_wall("x", i * R, j * R, (j + 1) * R, H, [(j * R + 4.0, j * R + 6.0, 3.0)], thick=0.3)
                  for j in range(nz)]
    for j in range(1, nz):
        walls += [_wall("z", j * R, i * R, (i + 1) * R, H, [(i * R + 4.0, i * R + 6.0, 3.0)], thick=0.3)
                  for i in range(nx)]
    b.mesh("walls", merge(walls), diffuse((0.55, 0.52, 0.48)))
    shelves = []
    for i in range(nx):
        for j in range(nz):
            x0, z0 = i * R, j * R
            shelves += [box((x0 + xa, 0, z0 + za), (x0 + xa + 2.0, 2.5, z0 + za + 2.0))
                        for xa in (2.0, 6.0) for za in (1.5, 6.5)]
    b.mesh("shelves", merge(shelves), diffuse((0.35, 0.3, 0.5)))
    radiance = (20.0, 18.6, 16.4)
    for i in range(nx):
        for j in range(nz):
            for a in range(4):
                for c in range(4):
                    b.mesh(f"light_{i}{j}_{a}{c}", _ceiling_light(i * R + 1.25 + 2.5 * a, H - 0.01, j * R + 1.25 + 2.5 * c,
                                                                  half=0.2), diffuse(DARK), radiance)
    # the walk follows the central aisle (z = 5) of the first two halls, through the door at x = 10
    walk = [[1.0, 1.7, 5.0], [7.0, 1.7, 5.0], [11.0, 1.7, 5.0], [15.0, 1.7, 5.5]]
    look = [[10.0, 1.6, 4.5], [14.0, 1.6, 5.0], [20.0, 1.6, 3.5], [20.0, 1.5, 9.0]]
    times = [0.0, 2.0, 4.0, 6.0]
    cam = CameraPath(Track(times, walk, interp="smooth"), Track(times, look, interp="smooth"), (0, 1, 0), 70.0)
    return b.build(cam, "Eight halls with 128 ceiling lights", duration=6.0,
                   probe_box=((0.3, 0.3, 0.3), (X - 0.3, H - 0.3, Z - 0.3)), probe_counts=(32, 4, 16))


def sky_pit_geometry(b: SceneBuilder) -> tuple[float, float]:
    """The meshes of ``sky-pit`` (shared by its variants): returns (pit half width P, depth D)."""
    P, D, G = 3.0, 6.0, 25.0  # pit half width, depth, ground half size
    ground = merge([_floor(-G, G, -G, -P), _floor(-G, G, P, G), _floor(-G, -P, -P, P), _floor(P, G, -P, P)])
    b.mesh("ground", ground, diffuse((0.45, 0.4, 0.33)))
    rock = merge([box((-P - 0.5, -D, -P - 0.5), (-P, 0, P + 0.5)), box((P, -D, -P - 0.5), (P + 0.5, 0, P + 0.5)),
                  box((-P, -D, -P - 0.5), (P, 0, -P)), box((-P, -D, P), (P, 0, P + 0.5))])
    b.mesh("pit_walls", rock, diffuse((0.5, 0.42, 0.34)))
    b.mesh("pit_floor", _floor(-P, P, -P, P, -D), diffuse((0.4, 0.38, 0.33)))
    b.mesh("overhang", box((-P, -0.4, -P), (0.0, 0.0, P)), diffuse((0.5, 0.42, 0.34)))
    # rubble and a beam under the overhang for some local occlusion
    b.mesh("rubble", merge([box((-2.5, -D, -2.2), (-1.3, -D + 1.0, -0.8)), box((1.2, -D, 1.0), (2.4, -D + 0.6, 2.6)),
                            box((-P, -3.2, -0.2), (0.0, -2.9, 0.2))]), diffuse((0.55, 0.5, 0.45)))
    return P, D


@builtin("sky-pit", "Pit open to the sky, half roofed by an overhang, under a moving sun and a sky",
         "VLC/CDQ scene (b): Quake 2 RTX mine open to the sky (path guiding)")
def sky_pit():
    """A 6 x 6 m pit, 6 m deep, dug into open ground and half covered by an overhang.

    Stands for scene (b) of Dittebrandt et al. (Sec. 7.1, Fig. 8): a mine open
    towards the sky, lit mostly by the environment (a constant sky) and a sun
    (directional) whose small directly lit spot dominates the indirect light
    under the overhang. The sun moves over 4 s, so the lit spot slides along the
    pit floor and up a wall. With BSDF sampling alone the sun, the sky opening
    and the lit spot are all small-solid-angle features: it exercises path
    guiding (CDQ) and its readaptation. The probe volume is the pit only.
    """
    b = SceneBuilder("sky-pit")
    P, D = sky_pit_geometry(b)
    b.add("sun", _sun(_sun_dir(70.0, 200.0), (10.0, 9.4, 8.4)))
    b.add("sky", _sky((0.55, 0.65, 0.85)))
    times = [0.0, 2.0, 4.0]
    b.animate(SunMotion("sun", Track(times, [_sun_dir(78.0, 190.0), _sun_dir(70.0, 220.0), _sun_dir(62.0, 250.0)],
                                     interp="smooth")))
    cam = Camera((-2.6, -4.4, 2.6), (1.0, -4.6, -1.5), (0, 1, 0), 75.0)
    return b.build(cam, "Pit open to the sky under a moving sun", duration=4.0,
                   probe_box=((-P + 0.1, -D + 0.1, -P + 0.1), (P - 0.1, -0.1, P - 0.1)), probe_counts=(8, 8, 8))


@builtin("covered-lights", "Statue lit by ten area lights behind a rotating cover plate",
         "VLC/CDQ scene (c): Stanford dragon lit by ten area lights behind a cover")
def covered_lights():
    """A statue stand-in in an 8 x 8 x 3.6 m room under ten ceiling lights hidden by a cover plate.

    Stands for scene (c) of Dittebrandt et al. (Sec. 7.1, Fig. 8): ten small
    (0.3 x 0.3 m) ceiling area lights on a ring (radius 1.3 m) face down onto
    a dark 2 x 3.2 m cover plate hung 0.6 m below them; light reaches the room and the object only around the
    plate's edges (lights near its short sides are partly visible from below,
    the others hidden) and via the plate and ceiling. The plate turns by 90
    degrees over 4 s, so which lights are visible from which point changes
    continuously: complex, partly occluded direct light, for many-light NEE
    (VLC) and guiding.
    """
    b = SceneBuilder("covered-lights")
    S, H = 4.0, 3.6
    b.mesh("floor", _floor(-S, S, -S, S), diffuse((0.5, 0.48, 0.45)))
    b.mesh("ceiling", _ceiling(-S, S, -S, S, H), diffuse(PLASTER))
    b.mesh("walls", merge([_wall("x", -S, -S, S, H), _wall("x", S, -S, S, H), _wall("z", -S, -S, S, H),
                           _wall("z", S, -S, S, H)]), diffuse((0.62, 0.6, 0.55)))
    b.mesh("cover", box((-1.0, 2.96, -1.6), (1.0, 3.0, 1.6)), diffuse((0.25, 0.25, 0.25)))
    Vb, Fb = uv_sphere((0.0, 0.0, 0.0), 1.0, 12, 24)
    statue = merge([box((-0.6, 0.0, -0.4), (0.6, 0.3, 0.4)), (Vb * [0.55, 0.35, 0.3] + [0.0, 0.6, 0.0], Fb),
                    cylinder((0.35, 0.7, 0.0), 0.09, 0.55, n=10), uv_sphere((0.42, 1.3, 0.0), 0.17, 8, 16),
                    cylinder((-0.5, 0.35, 0.0), 0.07, 0.45, n=10)])
    b.mesh("statue", statue, diffuse((0.75, 0.6, 0.3)))
    for k in range(10):
        a = 2 * np.pi * (k + 0.5) / 10
        b.mesh(f"light_{k}", _ceiling_light(1.3 * np.cos(a), H - 0.01, 1.3 * np.sin(a), half=0.15), diffuse(DARK),
               (40.0, 36.6, 32.0))
    b.animate(RigidMotion("cover", angle=Track([0.0, 4.0], [[0.0], [np.pi / 2]], interp="smooth")))
    cam = Camera((0.3, 1.5, 3.8), (0.0, 1.3, 0.0), (0, 1, 0), 80.0)
    return b.build(cam, "Statue under ten covered area lights", duration=4.0,
                   probe_box=((-3.8, 0.2, -3.8), (3.8, 3.4, 3.8)), probe_counts=(12, 6, 12))


@builtin("rotating-hidden-light", "Floor lit only via a circular wall by a light below the floor that turns "
         "in 90-degree steps", "CDQ adaptation experiment (Dittebrandt et al., Sec. 7.3)")
def rotating_hidden_light(step_deg: float = 90.0, name: str = "rotating-hidden-light"):
    """A floor disc (radius 1.5 m) inside a cylindrical wall (radius 2 m), lit by a light below the floor.

    Stands for the CDQ adaptation scene of Dittebrandt et al. (Sec. 7.3): the
    light (a small area light under the floor, facing out and up through the
    gap between floor and wall) never sees the floor's top, which is lit only
    by the patch of wall it illuminates. The light turns about the axis by 90
    degrees at t = 1, 2, 3 s (a step track: a sudden, defined rotational
    change over one frame), so guiding distributions must readapt. The camera
    looks straight down at the floor through the open top.

    ``step_deg`` (default 90) is the rotation per step, so the 9 and 36 degree changes of Fig. 10
    can be run (registered as ``rotating-hidden-light-9`` / ``-36`` in ``builtin_cdq.py``).
    """
    step = np.radians(float(step_deg))
    b = SceneBuilder(name)
    R, r, H, B = 2.0, 1.5, 2.5, 0.8
    b.mesh("wall", cylinder((0.0, -B, 0.0), R, H + B, n=64, inward=True, caps=False), diffuse((0.7, 0.7, 0.7)))
    b.mesh("bottom", _floor(-R, R, -R, R, -B), diffuse((0.3, 0.3, 0.3)))
    b.mesh("floor", cylinder((0.0, -0.05, 0.0), r, 0.05, n=64), diffuse((0.7, 0.7, 0.7)))
    s2 = np.sqrt(0.5)
    b.mesh("light", quad((1.35, -0.3, 0.0), (0.0, 0.0, 0.12), (0.08 * s2, -0.08 * s2, 0.0)), diffuse(DARK),
           (400.0, 380.0, 340.0))
    b.animate(RigidMotion("light", angle=Track([0.0, 1.0, 2.0, 3.0], [[0.0], [step], [2.0 * step], [3.0 * step]],
                                                interp="step")))
    cam = Camera((0.0, 5.2, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, -1.0), 55.0)
    return b.build(cam, "Floor lit via a wall by a hidden, turning light", duration=4.0,
                   probe_box=((-1.4, 0.1, -1.4), (1.4, 2.3, 1.4)), probe_counts=(8, 6, 8))


# ---------------------------------------------------------------------------
# real-interior analogs (issue 11): sun through blinds, sky only, light behind glass, metal furniture
# ---------------------------------------------------------------------------
ROOM_X, ROOM_H, ROOM_Z = 2.0, 2.5, 2.0     # the analog rooms: [-2, 2] x [0, 2.5] x [-2, 2]
ROOM_PROBES = (((-1.85, 0.15, -1.85), (1.85, 2.35, 1.85)), (6, 4, 6))
SUN_TRAVEL = _sun_dir(32.0, 15.0)           # the sun stands beyond the +x wall; its light falls towards -x


def _sunsky(sun_scale: float, sky_scale: float, direction=SUN_TRAVEL) -> dict:
    """Mitsuba's ``sunsky`` emitter (Hosek-Wilkie sky + sun disk); ``direction`` is the way sunlight travels."""
    d = -np.asarray(direction, np.float64)
    # Mitsuba's sky is z-up in its local frame: to_world turns local +z into our +y; sun_direction is
    # in world space
    return {"type": "sunsky", "sun_direction": (d / np.linalg.norm(d)).tolist(), "turbidity": 3.0,
            "to_world": mi.ScalarTransform4f().rotate([1.0, 0.0, 0.0], -90.0),
            "albedo": {"type": "rgb", "value": [0.3, 0.3, 0.3]},
            "sun_scale": float(sun_scale), "sky_scale": float(sky_scale)}


def _room_shell(b: SceneBuilder, window: bool):
    """Closed diffuse room (walls 0.1 m thick boxes); with ``window`` an opening in the +x wall,
    z in [-0.8, 0.8], y in [0.8, 2.0]."""
    X, H, Z = ROOM_X, ROOM_H, ROOM_Z
    b.mesh("floor", box((-X - 0.1, -0.1, -Z - 0.1), (X + 0.1, 0.0, Z + 0.1)), diffuse((0.55, 0.5, 0.42)))
    b.mesh("ceiling", box((-X - 0.1, H, -Z - 0.1), (X + 0.1, H + 0.1, Z + 0.1)), diffuse(PLASTER))
    walls = [box((-X - 0.1, 0.0, -Z - 0.1), (-X, H, Z + 0.1)), box((-X, 0.0, -Z - 0.1), (X, H, -Z)),
             box((-X, 0.0, Z), (X, H, Z + 0.1))]
    if window:
        walls += [box((X, 0.0, -Z - 0.1), (X + 0.1, 0.8, Z + 0.1)), box((X, 2.0, -Z - 0.1), (X + 0.1, H, Z + 0.1)),
                  box((X, 0.8, -Z - 0.1), (X + 0.1, 2.0, -0.8)), box((X, 0.8, 0.8), (X + 0.1, 2.0, Z + 0.1))]
    else:
        walls.append(box((X, 0.0, -Z - 0.1), (X + 0.1, H, Z + 0.1)))
    b.mesh("walls", merge(walls), diffuse((0.68, 0.66, 0.62)))


SUNSKY_EXPOSURE = 8.0    # both scales of the rooms' sunsky: a frame mean of ~0.1-0.3 (Mitsuba's units are dim)
ROOM_CAMERA = Camera((-1.7, 1.4, 1.7), (0.6, 0.7, -0.9), (0, 1, 0), 70.0)
SUN_ROOM_CAMERA = Camera((1.75, 1.6, 1.75), (-0.9, 0.5, -0.9), (0, 1, 0), 65.0)   # back to the window


def _slide(dx: float, dz: float) -> Track:
    """There and back again in 4 s (the analog rooms' one simple animation; their tests hold t = 0)."""
    return Track([0.0, 2.0, 4.0], [[0.0, 0.0, 0.0], [dx, 0.0, dz], [0.0, 0.0, 0.0]], interp="smooth", loop=True)


def _room_sun(name: str, sun_scale: float, sky_scale: float, description: str):
    b = SceneBuilder(name)
    _room_shell(b, window=True)
    # horizontal blind slats across the window: 0.02 m thick, 0.08 m deep, every 0.12 m
    slats = [box((ROOM_X - 0.04, y, -0.8), (ROOM_X + 0.04, y + 0.02, 0.8)) for y in np.arange(0.86, 2.0, 0.12)]
    b.mesh("blinds", merge(slats), diffuse((0.7, 0.7, 0.68)))
    b.mesh("table", merge([box((-0.9, 0.7, -0.8), (0.5, 0.76, 0.4))] +
                          [box((x, 0.0, z), (x + 0.06, 0.7, z + 0.06)) for x in (-0.85, 0.39) for z in (-0.75, 0.29)]),
           diffuse((0.45, 0.3, 0.2)))
    b.add("sunsky", _sunsky(SUNSKY_EXPOSURE * sun_scale, SUNSKY_EXPOSURE * sky_scale))
    b.animate(RigidMotion("table", translate=_slide(0.0, 0.6)))
    return b.build(SUN_ROOM_CAMERA, description, duration=4.0, probe_box=ROOM_PROBES[0], probe_counts=ROOM_PROBES[1])


@builtin("room-sun-blinds", "Room lit only by a sunsky (sun + sky) through a window with horizontal blinds",
         "issue 11: a dining room lit only by Mitsuba's sunsky through window blinds")
def room_sun_blinds(sun_scale: float = 1.0, sky_scale: float = 1.0):
    """A 4 x 2.5 x 4 m room with a table, lit only by Mitsuba's ``sunsky`` through a 1.6 x 1.2 m window
    with horizontal blinds (slats 0.02 m thick, 0.08 m deep, every 0.12 m).

    Stands for the sunlit interiors of issue 11 (a dining room with window
    blinds, a classroom): the sun (elevation 32 degrees) draws a striped patch on
    the floor and the table; that patch's bounce and the sky through the window
    light the rest. The sun must be sampled by NEE (``direct='sun'``), the sky
    through the probes. ``sun_scale``/``sky_scale`` build the sun-only and
    sky-only variants of the tests (the sky-only one is ``room-sky-only``). The
    table slides 0.6 m and back over 4 s (the tests hold t = 0: static).
    """
    return _room_sun("room-sun-blinds", sun_scale, sky_scale, "Room lit by a sunsky through window blinds")


@builtin("room-sky-only", "The room-sun-blinds room lit only by the sky of a sunsky (sun_scale = 0)",
         "issue 11: the sky part of a sunsky reaching an interior through a window")
def room_sky_only():
    """:func:`room_sun_blinds` with ``sun_scale = 0``: only the Hosek-Wilkie sky lights the room, through the
    window. All its light reaches the image through the probes' miss rays under ``direct='sun'``. The table
    slides as in ``room-sun-blinds``."""
    return _room_sun("room-sky-only", 0.0, 1.0, "Room lit by the sky of a sunsky through window blinds")


@builtin("light-behind-glass", "Room lit by one ceiling area light inside a glass (thindielectric) lamp box",
         "issue 11: lamps with glass shades, window panes (veach-bidir's covered lamp)")
def light_behind_glass():
    """A closed 4 x 2.5 x 4 m room lit by one 0.6 x 0.6 m ceiling light enclosed in a box of
    ``thindielectric`` glass (a 1 x 1 m pane 0.3 m below the ceiling and four side panes).

    Every light path leaves the lamp through glass: NEE shadow rays and probe
    rays must pass it (attenuated by its transmittance, :mod:`dyngi.scene.passthrough`)
    or the room is dark (a small uncovered light adds ~10% of the power). Mitsuba's ``path`` blocks NEE
    at the glass but reaches
    the light through it by BSDF sampling (a thin slab does not refract), so its
    reference is exact, only noisier. The cabinet slides 0.8 m and back over 4 s.
    """
    b = SceneBuilder("light-behind-glass")
    _room_shell(b, window=False)
    H = ROOM_H
    b.mesh("cabinet", box((-1.9, 0.0, -1.9), (-1.2, 1.2, -0.9)), diffuse((0.3, 0.4, 0.6)))
    b.mesh("light", _ceiling_light(0.3, H - 0.01, 0.2, half=0.3), diffuse(DARK), (30.0, 27.0, 22.0))
    glass = {"type": "thindielectric", "int_ior": 1.5, "ext_ior": 1.0}
    panes = merge([quad((0.3, H - 0.3, 0.2), (0.5, 0, 0), (0, 0, 0.5)),            # bottom, then 4 sides
                   quad((0.8, H - 0.15, 0.2), (0, 0.15, 0), (0, 0, 0.5)),
                   quad((-0.2, H - 0.15, 0.2), (0, 0, 0.5), (0, 0.15, 0)),
                   quad((0.3, H - 0.15, 0.7), (0.5, 0, 0), (0, 0.15, 0)),
                   quad((0.3, H - 0.15, -0.3), (0, 0.15, 0), (0.5, 0, 0))])
    b.mesh("lamp_glass", panes, glass)
    # a small uncovered light (~10% of the lamp's power), so that path tracers with NEE see more than
    # BSDF-sampled speckles at a few samples per pixel
    b.mesh("night_light", _ceiling_light(-1.5, H - 0.01, 1.5, half=0.1), diffuse(DARK), (27.0, 24.0, 20.0))
    b.animate(RigidMotion("cabinet", translate=_slide(0.0, 0.8)))
    cam = Camera((-1.7, 1.5, 1.75), (0.9, 0.3, -1.0), (0, 1, 0), 60.0)     # the lamp just out of view
    return b.build(cam, "Room lit by an area light in a glass lamp box", duration=4.0,
                   probe_box=ROOM_PROBES[0], probe_counts=ROOM_PROBES[1])


@builtin("room-metal-furniture", "Diffuse room with metal (conductor, roughconductor) furniture, a roughplastic "
         "table and one ceiling area light", "issue 11: a classroom with metal chair frames")
def room_metal_furniture():
    """A closed 4 x 2.5 x 4 m diffuse room with one 0.5 x 0.5 m ceiling light, a ``roughconductor``
    (aluminium, alpha 0.1) cabinet and chair frames, a ``conductor`` (mirror chrome) ball and a
    ``roughplastic`` table top.

    Metals have no diffuse lobe: probe rays that hit them must return (almost) no
    light, not Mitsuba's ``eval_diffuse_reflectance`` of a rough conductor
    (``pi f``, 20x a diffuse surface head-on), which made rare probe rays inject
    fireflies into the cache and the image flicker (issue 11). The chrome ball rolls 0.8 m
    and back over 4 s.
    """
    b = SceneBuilder("room-metal-furniture")
    _room_shell(b, window=False)
    H = ROOM_H
    alu = {"type": "roughconductor", "material": "Al", "distribution": "ggx", "alpha": 0.1}
    b.mesh("cabinet", box((-1.95, 0.0, -1.95), (-1.45, 1.1, -1.55)), alu)
    frames = [box((x, 0.0, z), (x + 0.04, 0.9, z + 0.04)) for x in (0.6, 1.0) for z in (0.6, 1.0)]
    frames.append(box((0.6, 0.45, 0.6), (1.04, 0.49, 1.04)))
    b.mesh("chair_frames", merge(frames), alu)
    b.mesh("ball", uv_sphere((1.2, 0.2, -1.2), 0.2, 10, 20), {"type": "conductor", "material": "Cr"})
    b.mesh("table", merge([box((-0.8, 0.0, -0.3), (-0.72, 0.7, -0.22)), box((0.2, 0.0, -0.3), (0.28, 0.7, -0.22)),
                           box((-0.8, 0.0, 0.5), (-0.72, 0.7, 0.58)), box((0.2, 0.0, 0.5), (0.28, 0.7, 0.58))]),
           diffuse((0.4, 0.3, 0.2)))
    b.mesh("table_top", box((-0.85, 0.7, -0.35), (0.33, 0.75, 0.63)),
           {"type": "roughplastic", "distribution": "ggx", "alpha": 0.15, "int_ior": 1.5,
            "diffuse_reflectance": {"type": "rgb", "value": [0.5, 0.35, 0.2]}})
    b.mesh("light", _ceiling_light(0.0, H - 0.01, 0.0, half=0.25), diffuse(DARK), (25.0, 23.0, 20.0))
    b.animate(RigidMotion("ball", translate=_slide(-0.8, 0.0)))
    return b.build(ROOM_CAMERA, "Room with metal furniture and one area light", duration=4.0,
                   probe_box=ROOM_PROBES[0], probe_counts=ROOM_PROBES[1])

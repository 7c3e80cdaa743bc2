"""Built-in analogs of issue 22's probe leaks: ``sealed-rooms``, ``sealed-rooms-open``, ``stair-hall``.

Both analogs are built of **thick two-sided solids** (closed boxes with a
``twosided`` diffuse BSDF, as scenes exported from modelling tools are) and
carry a probe grid that an engine would lay over the whole building: its
layers *start inside the slabs*, where no probe can be of use until
relocation has moved it out. They stand for public scenes that are not in
``../shared`` (issue 22) and are the scenes of ``tests/probes/test_probe_leaks.py``.

* ``sealed-rooms`` / ``sealed-rooms-open`` -- two rooms side by side
  (interiors 5.8 x 3 x 6.8 m) of 0.6 m thick slabs: ground, roof, outer and
  middle walls. The open room (x < 0) has a 4 x 1.8 m window towards +z; the
  other one is **sealed**: no opening at all, so Mitsuba's ``path`` renders
  it exactly black. One directional sun (elevation 35 degrees) lights the
  roof, the ground outside and, through the window, the open room's floor.
  The probe grid has 5 x 2 x 3 probes, layer y = -0.2 inside the ground slab,
  layer y = 3.2 inside the roof slab, the outer columns inside the outer and
  middle walls. ``sealed-rooms`` looks into the sealed room,
  ``sealed-rooms-open`` (the same building) into the open room.
* ``stair-hall`` -- a tall two-storey stair hall (5 x 6 m, 6.1 m high) lit
  by **one ceiling area light** at the top (1.2 x 1.2 m, 2 cm under the roof
  slab): 0.15 m thick two-sided walls with raised panels (wainscot boxes 4 cm
  proud, both storeys), a gallery floor slab (y in [3.0, 3.15]) over the whole
  hall but the stairwell, a solid staircase of 18 small steps (0.175 m rise) up
  the +x wall, a balustrade at the stairwell's edge. The lower storey is lit
  through the stairwell only, mostly indirectly. The grid (5 x 3 x 6 probes,
  spacing 1.28 x 3.09 x 1.22 m) has its three layers inside the ground slab
  (y = -0.05), the gallery slab (y = 3.04) and the roof slab (y = 6.13, just
  above the light's plane: after relocation these are the probes near the
  light), its outer columns inside the walls. What differs from
  ``hall-top-light`` (within 1% before and after): there the walls are 10 cm
  boxes the grid stays clear of, and a layer of probes runs through every
  storey; here every layer starts inside a slab, so relocation decides where
  the lower storey's probes end up.

What ``ddgi`` did with them before issue 22 (``tests/probes/test_probe_leaks.py``;
docs/techniques/ddgi.md has the figures): the two-sided rule ``'front'`` (commit
7d79077) let no probe find itself inside a slab, and relocation pushed every
layer out on the far side of its slab -- the ground layer below the ground,
the roof layer above the sunlit roof, the gallery layer up into the lit upper
storey -- so neither room nor the lower storey kept a probe, and their
points interpolated the probes on the lit side through the Chebyshev floor
and the fallback: the sealed room as bright as the open one, the hall over-lit.

Two unregistered variants of the sealed rooms (their sealed view is black; fixtures of the every-frame
tests of ``tests/probes/test_probe_leaks.py``, issue 36): :func:`sealed_rooms_dim` (white slabs, a sun 10x
dimmer) and :func:`sealed_rooms_midslab` (1.2 m slabs, probe layers on their mid-planes, a sky).

All three are static for the first second (the tests hold t = 0); then the sun of the sealed rooms
rises (elevation 35 -> 50 degrees) and the hall's light dims to half, between t = 1 and 2 s; 4 s clips.
The sealed room stays sealed throughout.
"""
from __future__ import annotations

import numpy as np

from .animation import ParamTrack, SunMotion, Track
from .builder import SceneBuilder
from .builtin_default import _sky, _sun, _sun_dir, _twosided
from .camera import Camera
from .geometry import box, merge
from .library import builtin

# -- sealed rooms ------------------------------------------------------------------------------------
SEALED_SLAB = 0.6                         # thickness of the ground, roof and walls
SEALED_X, SEALED_Z, SEALED_H = 7.0, 4.0, 3.0   # building x in [-7, 7], z in [-4, 4]; rooms 3 m high
SEALED_WINDOW = (-5.5, -1.5, 0.6, 2.4)    # x0, x1, y0, y1 of the open room's window (in the +z wall)
SEALED_SUN = _sun_dir(35.0, 60.0)         # from +z, slightly towards +x: falls through the window
SEALED_SUN_LATER = _sun_dir(50.0, 75.0)   # where it has moved to at t = 2 s
SEALED_SUN_IRRADIANCE = (6.0, 5.6, 5.0)
SEALED_PROBE_BOX = ((-6.55, -0.2, -3.55), (6.55, 3.2, 3.55))
SEALED_PROBE_COUNTS = (5, 2, 3)
SEALED_CAMERA = Camera((1.2, 1.6, -2.6), (4.8, 0.6, 2.0), (0, 1, 0), 75.0)
OPEN_CAMERA = Camera((-1.2, 1.6, -2.6), (-4.8, 0.6, 2.0), (0, 1, 0), 75.0)
SLAB = (0.72, 0.70, 0.66)


def sealed_rooms_geometry(b: SceneBuilder, sun_irradiance=SEALED_SUN_IRRADIANCE, slab=SLAB,
                          thickness: float = SEALED_SLAB) -> None:
    """The building of ``sealed-rooms`` (shapes ``ground``, ``roof``, ``walls``; ``slab`` the albedo of the
    roof and walls, ``thickness`` that of every slab) and its sun."""
    T, X, Z, H = thickness, SEALED_X, SEALED_Z, SEALED_H
    b.mesh("ground", box((-16.0, -T, -12.0), (16.0, 0.0, 12.0)), _twosided((0.5, 0.45, 0.4)))
    b.mesh("roof", box((-X, H, -Z), (X, H + T, Z)), _twosided(slab))
    x0, x1, y0, y1 = SEALED_WINDOW
    walls = [box((-X, 0.0, -Z), (-X + T, H, Z)), box((X - T, 0.0, -Z), (X, H, Z)),      # outer x walls
             box((-X, 0.0, -Z), (X, H, -Z + T)),                                          # -z wall
             box((-T / 2, 0.0, -Z), (T / 2, H, Z)),                                       # middle wall
             box((-T / 2, 0.0, Z - T), (X, H, Z)),                                        # +z wall, sealed room
             # +z wall of the open room, around its window
             box((-X, 0.0, Z - T), (x0, H, Z)), box((x1, 0.0, Z - T), (-T / 2, H, Z)),
             box((x0, 0.0, Z - T), (x1, y0, Z)), box((x0, y1, Z - T), (x1, H, Z))]
    b.mesh("walls", merge(walls), _twosided(slab))
    b.add("sun", _sun(SEALED_SUN, sun_irradiance))
    b.animate(SunMotion("sun", Track([0.0, 1.0, 2.0, 4.0], [SEALED_SUN, SEALED_SUN, SEALED_SUN_LATER,
                                                           SEALED_SUN_LATER], interp="smooth")))


def _sealed(name: str, camera: Camera, what: str, sun_scale: float = 1.0, slab=SLAB, thickness=SEALED_SLAB,
            probe_box=SEALED_PROBE_BOX, probe_counts=SEALED_PROBE_COUNTS, sky=None):
    b = SceneBuilder(name)
    sealed_rooms_geometry(b, tuple(sun_scale * c for c in SEALED_SUN_IRRADIANCE), slab, thickness)
    if sky is not None:
        b.add("sky", _sky(sky))
    return b.build(camera, f"Two rooms of thick two-sided slabs, one sealed, a sun outside: {what}",
                   duration=4.0, probe_box=probe_box, probe_counts=probe_counts)


@builtin("sealed-rooms", "Two rooms of thick (0.6 m) two-sided slabs side by side, one fully sealed, a sun "
         "outside; probe layers start inside the ground and roof slabs; the camera in the sealed room "
         "(Mitsuba: black)",
         "issue 22: the public two-room scene where DDGI lit a sealed room (sealed/open 1.03)")
def sealed_rooms():
    """Camera inside the sealed room: every pixel is 0 in Mitsuba's ``path`` (see the module docstring)."""
    return _sealed("sealed-rooms", SEALED_CAMERA, "view into the sealed room")


@builtin("sealed-rooms-open", "The sealed-rooms building seen from inside its open room (lit by the sun through "
         "a window)", "issue 22: the open room of the two-room scene")
def sealed_rooms_open():
    """The ``sealed-rooms`` building, camera in the open room (the sun patch on its floor in view)."""
    return _sealed("sealed-rooms-open", OPEN_CAMERA, "view into the open room")


SEALED_DIM_SCALE = 0.1
"""Sun of :func:`sealed_rooms_dim`: 1/10 of ``sealed-rooms``' (irradiance 0.6, 0.56, 0.5)."""
SEALED_DIM_SLAB = (0.85, 0.82, 0.78)
"""Roof and walls of :func:`sealed_rooms_dim`: white paint (``sealed-rooms``: 0.72, 0.70, 0.66)."""


def sealed_rooms_dim(view: str = "sealed"):
    """The ``sealed-rooms`` building painted white (:data:`SEALED_DIM_SLAB`) under a sun 10x dimmer
    (:data:`SEALED_DIM_SCALE`); ``view`` 'sealed' or 'open' (the cameras of ``sealed-rooms`` /
    ``sealed-rooms-open``). Mitsuba: the sealed view black.

    Issue 36's variant. An encoded probe texel holds nothing between 0 and one code (ADGI's 9-9-8 log
    words: one code is ~6.5e-4 in R and G), an amount fixed in absolute units, so a leak of a code weighs
    more against a dimmer open room; and the brighter the walls, the more of a code's light the sealed
    room's inter-reflection hands back to its probes (what kept ``adgi``'s toggling codes alive). Here
    ``adgi`` before the fix showed the real two-room scene's defect: the sealed room at 0.043 / 0.018 of
    the open one on even / odd frames (the real scene: 0.028 / 0.036); ``sealed-rooms`` itself (full sun,
    grey slabs) showed it at 0.0025 / 0.0037 only. Figures: docs/probes.md. Not a registered scene (a
    fixture of ``tests/probes/test_probe_leaks.py``)."""
    if view not in ("sealed", "open"):
        raise ValueError(f"sealed_rooms_dim: view must be 'sealed' or 'open', not {view!r}")
    cam = SEALED_CAMERA if view == "sealed" else OPEN_CAMERA
    return _sealed(f"sealed-rooms-dim-{view}", cam, f"white, under a dim sun, view into the {view} room",
                   SEALED_DIM_SCALE, SEALED_DIM_SLAB)


SEALED_MIDSLAB = 1.2
"""Slab thickness of :func:`sealed_rooms_midslab`."""
SEALED_MIDSLAB_PROBE_BOX = ((-6.4, -0.6, -3.4), (6.4, 3.6, 3.4))
SEALED_MIDSLAB_PROBE_COUNTS = (10, 2, 8)
SEALED_MIDSLAB_SKY = (0.3, 0.35, 0.45)


def sealed_rooms_midslab(view: str = "sealed"):
    """The ``sealed-rooms`` building of 1.2 m slabs under its sun and a constant sky, with a 10 x 2 x 8 grid
    whose boundary layers lie on the slabs' *mid-planes* (y = -0.6 in the ground, 3.6 in the roof, x = +-6.4
    and z = +-3.4 in the outer walls); ``view`` 'sealed' or 'open'. Mitsuba: the sealed view black.

    Issue 36's second variant: a probe on a mid-plane sees both faces of its slab at one distance, so which
    one relocation takes it through is decided by its own rays. ``isddgi`` rotates its rays per probe, and
    before the rule that a probe leaves on the grid's side (:mod:`dyngi.probes.states`) its roof-layer probes
    went up above the sunlit roof or down into the rooms at random: the sealed room at 0.10-0.12 of the open
    one from frame 0, where ``ddgi`` (one direction set for all probes: every probe of a layer chose alike)
    gave 0.005. Figures: docs/probes.md. Not a registered scene (a fixture of
    ``tests/probes/test_probe_leaks.py``)."""
    if view not in ("sealed", "open"):
        raise ValueError(f"sealed_rooms_midslab: view must be 'sealed' or 'open', not {view!r}")
    cam = SEALED_CAMERA if view == "sealed" else OPEN_CAMERA
    return _sealed(f"sealed-rooms-midslab-{view}", cam, f"1.2 m slabs, probe layers on their mid-planes, view "
                   f"into the {view} room", thickness=SEALED_MIDSLAB, probe_box=SEALED_MIDSLAB_PROBE_BOX,
                   probe_counts=SEALED_MIDSLAB_PROBE_COUNTS, sky=SEALED_MIDSLAB_SKY)


# -- stair hall --------------------------------------------------------------------------------------
HALL_X, HALL_Z = 2.5, 3.0                 # inner hall x in [-2.5, 2.5], z in [-3, 3]
HALL_T = 0.15                             # walls and slabs
HALL_GALLERY = 3.0                        # gallery slab y in [3.0, 3.15]
HALL_H = 6.1                              # underside of the roof slab
HALL_STAIRWELL = (1.0, -1.0)              # opening of the gallery slab: x > 1.0, z > -1.0
HALL_STEPS = 18
HALL_LIGHT = (-0.5, 0.5, 0.6)             # x, z, half size of the ceiling light
HALL_LIGHT_RADIANCE = (30.0, 27.0, 22.0)
HALL_PROBE_BOX = ((-2.56, -0.05, -3.06), (2.56, 6.13, 3.06))
HALL_PROBE_COUNTS = (5, 3, 6)
HALL_CAMERA = Camera((-2.1, 1.5, 2.7), (1.2, 2.4, -2.2), (0, 1, 0), 80.0)
WOOD = (0.45, 0.30, 0.18)
PLASTER = (0.75, 0.72, 0.66)


def _panels(y0: float, y1: float):
    """Raised wainscot panels (0.5 x 0.7 m, 4 cm proud) on the -x and -z walls' inner faces, rows from y0."""
    X, Z, d = HALL_X, HALL_Z, 0.04
    out = []
    for y in np.arange(y0 + 0.2, y1 - 0.8, 0.9):
        out += [box((-X, y, a), (-X + d, y + 0.7, a + 0.5)) for a in np.arange(-Z + 0.15, Z - 0.6, 0.65)]
        out += [box((a, y, -Z), (a + 0.5, y + 0.7, -Z + d)) for a in np.arange(-X + 0.15, X - 0.6, 0.65)]
    return out


def stair_hall_geometry(b: SceneBuilder) -> None:
    """The hall of ``stair-hall`` (see the module docstring)."""
    X, Z, T, G, H = HALL_X, HALL_Z, HALL_T, HALL_GALLERY, HALL_H
    sx, sz = HALL_STAIRWELL
    b.mesh("ground", box((-X - T, -T, -Z - T), (X + T, 0.0, Z + T)), _twosided(WOOD))
    b.mesh("roof", box((-X - T, H, -Z - T), (X + T, H + T, Z + T)), _twosided(PLASTER))
    b.mesh("walls", merge([box((-X - T, 0.0, -Z - T), (-X, H, Z + T)), box((X, 0.0, -Z - T), (X + T, H, Z + T)),
                           box((-X, 0.0, -Z - T), (X, H, -Z)), box((-X, 0.0, Z), (X, H, Z + T))]),
           _twosided(PLASTER))
    b.mesh("panels", merge(_panels(0.0, G) + _panels(G + T, H)), _twosided(WOOD))
    b.mesh("gallery", merge([box((-X, G, -Z), (sx, G + T, Z)), box((sx, G, -Z), (X, G + T, sz))]), _twosided(WOOD))
    # solid stairs up the +x wall, from the floor at z = 2.6 to the gallery at z = -1
    n, z0 = HALL_STEPS, 2.6
    run, rise = (z0 - sz) / n, (G + T) / n
    b.mesh("stairs", merge([box((sx + 0.1, 0.0, z0 - (i + 1) * run), (X, (i + 1) * rise, z0 - i * run))
                            for i in range(n)]), _twosided(WOOD))
    b.mesh("balustrade", merge([box((sx - 0.05, G + T, sz), (sx, G + T + 0.9, Z)),
                                box((sx, G + T + 0.85, sz - 0.05), (X, G + T + 0.9, sz))]), _twosided(WOOD))
    lx, lz, h = HALL_LIGHT
    y = H - 0.02
    quad = (np.array([[lx - h, y, lz - h], [lx + h, y, lz - h], [lx + h, y, lz + h], [lx - h, y, lz + h]]),
            np.array([[0, 1, 2], [0, 2, 3]]))               # faces down
    b.mesh("light", quad, {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.0, 0.0, 0.0]}},
           {"type": "area", "radiance": {"type": "rgb", "value": list(HALL_LIGHT_RADIANCE)}})
    b.animate(ParamTrack("light.emitter.radiance.value",
                         Track([0.0, 1.0, 2.0, 4.0], [1.0, 1.0, 0.5, 0.5], interp="smooth")))


@builtin("stair-hall", "Tall two-storey stair hall of thick two-sided walls and slabs (panelled, 18 small steps, "
         "a gallery) lit by one ceiling area light at the top; probe layers start inside the slabs",
         "issue 22: the public staircase hall where ddgi was +71% over Mitsuba")
def stair_hall():
    """See the module docstring; the camera in the lower storey, the stairs and the gallery's underside in view."""
    b = SceneBuilder("stair-hall")
    stair_hall_geometry(b)
    return b.build(HALL_CAMERA, "Two-storey stair hall lit by one ceiling light", duration=4.0,
                   probe_box=HALL_PROBE_BOX, probe_counts=HALL_PROBE_COUNTS)

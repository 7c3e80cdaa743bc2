"""A sunlit classroom with metal furniture (issue 36): thick two-sided walls whose outer probe layers start
inside the slabs.

``sunlit-classroom`` stands for a real classroom scene (Mitsuba ``sunsky`` through windows, conductors,
many small objects, every material ``twosided`` as converted scenes have them). Its probe grid is what a
loaded scene's bounding-box grid gives such a room: the outer layers lie in the walls, floor and roof,
0.1 m from their *outer* faces. A probe inside a slab is relocated through a face (the two-sided rule
``'enclosed'``, :mod:`dyngi.probes.trace`); through the nearest one, it left the room and the room lost
its outer layer (ddgi +12% over Mitsuba, docs/probes.md). The probes leave through a face on the grid's
side instead (:mod:`dyngi.probes.states`).
"""
from __future__ import annotations

import numpy as np

from ..backend import mi
from .animation import RigidMotion, Track
from .builder import SceneBuilder
from .camera import Camera
from .geometry import box, diffuse, merge
from .library import builtin

CLASS_X, CLASS_H, CLASS_Z = 4.0, 3.0, 3.0   # the room: [-4, 4] x [0, 3] x [-3, 3]
CLASS_WALL = 0.3                            # walls, floor and roof: 0.3 m thick (a probe cell: 0.68-0.93 m)
CLASS_PROBE_INSET = 0.1                     # the grid's outer layers: 0.1 m inside the slabs' outer faces
CLASS_PROBE_COUNTS = (10, 6, 8)
CLASS_SUN = (45.0, 20.0)                    # sun elevation and azimuth (from +z towards +x), degrees
CLASS_EXPOSURE = 8.0                        # both scales of the sunsky (Mitsuba's units are dim)


def _sun_travel(elevation_deg: float, azimuth_deg: float) -> np.ndarray:
    """The way sunlight travels from a sun beyond the +z wall (azimuth from +z towards +x)."""
    e, a = np.radians(elevation_deg), np.radians(azimuth_deg)
    return -np.array([np.cos(e) * np.sin(a), np.sin(e), np.cos(e) * np.cos(a)])


def _two_sided(bsdf: dict) -> dict:
    return {"type": "twosided", "bsdf": bsdf}


@builtin("sunlit-classroom", "Classroom lit by a sunsky through three windows; thick two-sided walls, chrome "
         "desk and chair legs, metal shelves, desks, chairs and books",
         "issue 36: a real sunlit classroom with metal furniture (sunsky, conductors, many small objects)")
def sunlit_classroom(elevation: float = CLASS_SUN[0], azimuth: float = CLASS_SUN[1]):
    """An 8 x 3 x 6 m classroom with 0.3 m walls, floor and roof (closed boxes, every material two-sided),
    three 1.2 x 1.3 m windows in the +z wall, lit only by Mitsuba's ``sunsky`` (sun at 45 degrees).

    Nine desks (wooden tops on chrome ``conductor`` legs) with chairs, ``conductor`` shelves of books along
    the +x wall and a blackboard. The probe grid (10 x 6 x 8) spans the room *with* its slabs: its outer
    layers start inside the walls, floor and roof, 0.1 m from their outer faces (as the bounding-box grid of
    a loaded scene does). The chair seats and backs slide 0.3 m and back over 4 s (the tests hold t = 0: static).
    """
    X, H, Z, T = CLASS_X, CLASS_H, CLASS_Z, CLASS_WALL
    b = SceneBuilder("sunlit-classroom")
    metal = _two_sided({"type": "conductor", "material": "Cr"})
    b.mesh("floor", box((-X - T, -T, -Z - T), (X + T, 0.0, Z + T)), _two_sided(diffuse((0.5, 0.45, 0.38))))
    b.mesh("ceiling", box((-X - T, H, -Z - T), (X + T, H + T, Z + T)), _two_sided(diffuse((0.8, 0.8, 0.78))))
    walls = [box((-X - T, 0.0, -Z - T), (-X, H, Z + T)), box((-X, 0.0, -Z - T), (X, H, -Z)),
             box((X, 0.0, -Z - T), (X + T, H, Z + T))]
    # the window wall (+z): three openings 1.2 m wide, y in [0.9, 2.2]
    lo, hi, w = 0.9, 2.2, 1.2
    xs = np.linspace(-X, X, 5)[1:-1]
    edges = [-X] + [e for cx in xs for e in (cx - w / 2, cx + w / 2)] + [X]
    walls += [box((-X, 0.0, Z), (X, lo, Z + T)), box((-X, hi, Z), (X, H, Z + T))]
    walls += [box((edges[i], lo, Z), (edges[i + 1], hi, Z + T)) for i in range(0, len(edges), 2)]
    b.mesh("walls", merge(walls), _two_sided(diffuse((0.7, 0.68, 0.62))))
    tops, legs, seats = [], [], []
    for i in range(3):
        for j in range(3):
            x0, z0 = -2.2 + 1.6 * i, -2.0 + 1.5 * j
            tops.append(box((x0, 0.72, z0), (x0 + 0.6, 0.76, z0 + 1.0)))
            legs += [box((x0 + dx, 0.0, z0 + dz), (x0 + dx + 0.04, 0.72, z0 + dz + 0.04))
                     for dx in (0.02, 0.54) for dz in (0.02, 0.94)]
            cx = x0 + 0.75
            seats += [box((cx, 0.44, z0 + 0.3), (cx + 0.4, 0.48, z0 + 0.7)),
                      box((cx + 0.36, 0.48, z0 + 0.3), (cx + 0.4, 0.9, z0 + 0.7))]
            legs += [box((cx + dx, 0.0, z0 + dz), (cx + dx + 0.04, 0.44, z0 + dz + 0.04))
                     for dx in (0.0, 0.36) for dz in (0.3, 0.66)]
    b.mesh("desk_tops", merge(tops), _two_sided(diffuse((0.55, 0.4, 0.25))))
    b.mesh("seats", merge(seats), _two_sided(diffuse((0.25, 0.35, 0.5))))
    b.mesh("legs", merge(legs), metal)
    shelves = [box((X - 0.4, y, -2.5), (X - 0.05, y + 0.03, 1.5)) for y in (0.3, 0.8, 1.3, 1.8)]
    shelves += [box((X - 0.4, 0.0, z), (X - 0.05, 1.85, z + 0.03)) for z in (-2.5, -0.5, 1.47)]
    b.mesh("shelves", merge(shelves), metal)
    books = [box((X - 0.35, y + 0.03, z), (X - 0.1, y + 0.3, z + 0.08))
             for y in (0.3, 0.8, 1.3) for z in np.arange(-2.4, 1.4, 0.25)]
    b.mesh("books", merge(books), _two_sided(diffuse((0.5, 0.2, 0.15))))
    b.mesh("board", box((-X, 0.9, -1.5), (-X + 0.03, 2.1, 1.5)), _two_sided(diffuse((0.1, 0.2, 0.12))))
    d = -_sun_travel(elevation, azimuth)
    b.add("sunsky", {"type": "sunsky", "sun_direction": (d / np.linalg.norm(d)).tolist(), "turbidity": 3.0,
                     "to_world": mi.ScalarTransform4f().rotate([1.0, 0.0, 0.0], -90.0),
                     "albedo": {"type": "rgb", "value": [0.3, 0.3, 0.3]},
                     "sun_scale": CLASS_EXPOSURE, "sky_scale": CLASS_EXPOSURE})
    b.animate(RigidMotion("seats", translate=Track([0.0, 2.0, 4.0], [[0.0, 0.0, 0.0], [0.0, 0.0, 0.3],
                                                                    [0.0, 0.0, 0.0]], interp="smooth", loop=True)))
    cam = Camera((3.6, 1.7, -2.6), (-2.0, 0.6, 1.0), (0, 1, 0), 70.0)
    e = CLASS_PROBE_INSET
    return b.build(cam, "Sunlit classroom with metal furniture", duration=4.0,
                   probe_box=((-X - T + e, -T + e, -Z - T + e), (X + T - e, H + T - e, Z + T - e)),
                   probe_counts=CLASS_PROBE_COUNTS)

"""Built-in ``hall-top-light``: a tall two-storey hall lit from the top (issue 11, item 1).

Stands for the real two-storey staircase hall of issue 11 (Mitsuba XML, 13
area lights, glass pieces, metal trims; ``ddgi`` rendered whole regions black
there). The analog keeps the features that the diagnosis found responsible
and the lighting that makes the case hard:

* a 5 x 6 x 8 m hall of thin (10 cm) walls with a gallery slab halfway up
  (y = 3 m) over its back half, so the walls below the gallery and most of
  the upper walls see the light only indirectly;
* one ceiling area light at the top, written as Mitsuba's ``rectangle`` with a
  *mirroring* ``to_world`` (negative determinant, as exporters write them and
  as in the real scene): its winding normal points up, into the ceiling,
  while its shading normal -- the side Mitsuba emits from -- points down. A
  consumer that decides "front" by the geometric normal drops its emission;
* a glass panel (``dielectric``, 2 cm slab, 1.6 x 0.9 m) in the middle of the
  gallery's edge, seen by the camera with the gallery and the back wall
  behind it; a consumer that shades glass as an opaque surface draws it
  black, where Mitsuba's ``path`` sees through. Small on purpose, like the
  real scene's pieces: probe rays that it stops (until they pass through
  glass) cost the image ~6% (measured: 2% without the panel, 15% with a
  full-width glass balustrade).

Static for the first second (the tests check the mean against Mitsuba's ``path``
and the frame-to-frame stability of the image mean at t = 0); then the top
light dims to half between t = 1 s and 2 s, so re-convergence of light that
reaches the walls only indirectly can be measured too.
"""
from __future__ import annotations

from ..backend import mi
from .animation import ParamTrack, Track
from .builder import SceneBuilder
from .builtin_default import _ceiling, _floor, _twosided, _wall
from .camera import Camera
from .geometry import box, merge
from .library import builtin

HALL_WALL = (0.72, 0.70, 0.66)
HALL_FLOOR = (0.55, 0.50, 0.44)
GALLERY = (0.60, 0.56, 0.50)
HALL_LIGHT = (30.0, 28.0, 24.0)   # radiance of the 1.2 x 1.2 m top light


def _mirrored_top_light(x: float, y: float, z: float, half: float) -> dict:
    """A ``rectangle`` emitter at height ``y`` that emits downwards through a mirroring to_world."""
    T = (mi.ScalarTransform4f().translate([x, y, z]) @ mi.ScalarTransform4f().rotate([1, 0, 0], 90)
         @ mi.ScalarTransform4f().scale([half, -half, 1.0]))
    return {"type": "rectangle", "to_world": T,
            "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.0, 0.0, 0.0]}},
            "emitter": {"type": "area", "radiance": {"type": "rgb", "value": list(HALL_LIGHT)}}}


@builtin("hall-top-light", "Two-storey hall of thin walls with a gallery, lit by one ceiling light at the top "
         "(mirrored emitter transform; dims at t = 1-2 s), a glass panel at the gallery's edge",
         "issue 11's real two-storey staircase hall (area light at the top, glass, walls lit indirectly)")
def hall_top_light():
    """Hall x in [-2.5, 2.5], y in [0, 6], z in [-4, 4]; gallery slab y in [2.9, 3.0] over z in [-4, 0]."""
    b = SceneBuilder("hall-top-light")
    X, H, Z = 2.5, 6.0, 4.0
    t = 0.1
    b.mesh("floor", _floor(-X, X, -Z, Z, 0.0), _twosided(HALL_FLOOR))
    b.mesh("ceiling", _ceiling(-X, X, -Z, Z, H), _twosided(HALL_WALL))
    walls = merge([_wall("x", -X - t / 2, -Z - t, Z + t, H, thick=t),
                   _wall("x", X + t / 2, -Z - t, Z + t, H, thick=t),
                   _wall("z", -Z - t / 2, -X, X, H, thick=t),
                   _wall("z", Z + t / 2, -X, X, H, thick=t)])
    b.mesh("walls", walls, _twosided(HALL_WALL))
    b.mesh("gallery", box((-X, 2.9, -Z), (X, 3.0, 0.0)), _twosided(GALLERY))
    # a column under the gallery's edge and a thin partition on the upper floor: thin occluders
    b.mesh("column", box((-1.6, 0.0, -0.25), (-1.4, 2.9, -0.05)), _twosided(HALL_WALL))
    b.mesh("partition", box((1.0, 3.0, -3.0), (1.05, 5.0, -1.0)), _twosided(HALL_WALL))
    b.mesh("balustrade", box((-0.8, 3.0, -0.02), (0.8, 3.9, 0.0)),
           {"type": "dielectric", "int_ior": 1.5, "ext_ior": 1.0})
    b.add("top_light", _mirrored_top_light(0.0, H - 0.02, -0.5, 0.6))
    b.animate(ParamTrack("top_light.emitter.radiance.value",
                         Track([0.0, 1.0, 2.0, 4.0], [1.0, 1.0, 0.5, 0.5], interp="smooth")))
    cam = Camera((0.3, 1.5, 3.7), (0.0, 4.0, -4.0), (0, 1, 0), 90.0)
    return b.build(cam, "Two-storey hall lit from the top, gallery with a glass panel", duration=4.0,
                   probe_box=((-X + 0.1, 0.1, -Z + 0.1), (X - 0.1, H - 0.1, Z - 0.1)), probe_counts=(6, 8, 9))


"""Built-in analogs of real interiors whose probe GI missed Mitsuba's, one feature each (issue 36).

``coated-hall`` stands for ``../shared/scenes/wooden-staircase`` ('The Wooden Staircase': a two-storey
hall lit by one rectangle area light at the top; every probe technique +39% to +74% over Mitsuba's
``path``). The ablation (docs/probes.md, "Issue 36: the wooden staircase") found the cause in the
materials, not the geometry: the real hall's walls, ceiling, stairs and floor are ``twosided``
``roughplastic`` (``nonlinear``, ``intIOR`` 1.5, alpha 0.1-0.2: painted plaster and varnished wood).
Mitsuba's ``eval_diffuse_reflectance`` returns such a BSDF's diffuse *texture* (0.578 for the paint),
while the diffuse lobe it renders is that texture under the coating (0.34); the probes' multi-bounce
feedback took the texture as the albedo at every bounce. The built-in ``stair-hall`` (plain ``diffuse``)
and ``hall-top-light`` could not show it. The analog keeps that and the lighting that makes bounces
count:

* a 5 x 6.2 x 6 m hall of thick (15 cm) walls and slabs, a gallery slab halfway up over its back half,
  a solid stair block up one side; walls and ceiling painted (``roughplastic`` alpha 0.2, 0.578, as
  the real ``WhitePaint``/``MagnoliaPaint``), floor, gallery and stairs varnished wood
  (``roughplastic`` alpha 0.1);
* one 1.8 m square area light at the top facing down (radiance 30, as the real scene's ~2 m one), so
  the lower storey under the gallery is lit by bounced light only;
* static for the first second (the tests compare the mean of settled frames at t = 0 with Mitsuba's at
  equal depth); then the light dims to half between t = 1 s and 2 s (every built-in scene is animated).
"""
from __future__ import annotations

import numpy as np

from ..backend import mi
from .animation import ParamTrack, Track
from .builder import SceneBuilder
from .camera import Camera
from .geometry import box, merge
from .library import builtin

COATED_X, COATED_Z = 2.5, 3.0            # inner hall x in [-2.5, 2.5], z in [-3, 3]
COATED_T = 0.15                          # walls and slabs
COATED_GALLERY = 3.0                     # gallery slab y in [3.0, 3.15], over z < 0
COATED_H = 6.2                           # underside of the roof slab
COATED_LIGHT = (0.0, 0.0, 0.9)           # x, z, half size of the top light
COATED_LIGHT_RADIANCE = 30.0
COATED_PAINT = 0.578596                  # the real scene's WhitePaint / MagnoliaPaint
COATED_WOOD = (0.50, 0.34, 0.20)
COATED_PROBE_BOX = ((-2.45, 0.1, -2.95), (2.45, 6.1, 2.95))
COATED_PROBE_COUNTS = (5, 5, 6)
COATED_CAMERA = Camera((-2.0, 1.5, 2.7), (0.8, 3.6, -2.5), (0, 1, 0), 75.0)


def coated(rgb, alpha: float) -> dict:
    """A ``twosided`` ``roughplastic`` (GGX, ``intIOR`` 1.5, ``nonlinear``) of diffuse reflectance ``rgb``:
    the real scene's paint and varnish."""
    rgb = [float(rgb)] * 3 if np.isscalar(rgb) else [float(c) for c in rgb]
    return {"type": "twosided", "bsdf": {"type": "roughplastic", "distribution": "ggx", "alpha": float(alpha),
                                         "int_ior": 1.5, "ext_ior": 1.0, "nonlinear": True,
                                         "diffuse_reflectance": {"type": "rgb", "value": rgb}}}


@builtin("coated-hall", "Two-storey hall of painted and varnished (roughplastic) thick walls and slabs, a gallery "
         "and a stair block, lit by one rectangle light at the top (dims at t = 1-2 s)",
         "issue 36: ../shared/scenes/wooden-staircase (every probe technique +39-74% over Mitsuba)")
def coated_hall():
    """See the module docstring; the camera in the lower storey, the gallery's underside and the upper walls
    in view."""
    b = SceneBuilder("coated-hall")
    X, Z, T, G, H = COATED_X, COATED_Z, COATED_T, COATED_GALLERY, COATED_H
    paint, wood = coated(COATED_PAINT, 0.2), coated(COATED_WOOD, 0.1)
    b.mesh("ground", box((-X - T, -T, -Z - T), (X + T, 0.0, Z + T)), wood)
    b.mesh("roof", box((-X - T, H, -Z - T), (X + T, H + T, Z + T)), paint)
    b.mesh("walls", merge([box((-X - T, 0.0, -Z - T), (-X, H, Z + T)), box((X, 0.0, -Z - T), (X + T, H, Z + T)),
                           box((-X, 0.0, -Z - T), (X, H, -Z)), box((-X, 0.0, Z), (X, H, Z + T))]), paint)
    b.mesh("gallery", box((-X, G, -Z), (X, G + T, 0.0)), wood)
    # a solid stair block up the +x wall, from the floor at z = 2.6 to the gallery's edge at z = 0
    n = 12
    rise, run = (G + T) / n, 2.6 / n
    b.mesh("stairs", merge([box((X - 1.0, 0.0, i * run), (X, G + T - i * rise, (i + 1) * run))
                            for i in range(n)]), wood)
    lx, lz, h = COATED_LIGHT
    y = H - 0.02
    quad = (np.array([[lx - h, y, lz - h], [lx + h, y, lz - h], [lx + h, y, lz + h], [lx - h, y, lz + h]]),
            np.array([[0, 1, 2], [0, 2, 3]]))               # faces down
    b.mesh("light", quad, {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.0, 0.0, 0.0]}},
           {"type": "area", "radiance": {"type": "rgb", "value": [COATED_LIGHT_RADIANCE] * 3}})
    b.animate(ParamTrack("light.emitter.radiance.value",
                         Track([0.0, 1.0, 2.0, 4.0], [1.0, 1.0, 0.5, 0.5], interp="smooth")))
    return b.build(COATED_CAMERA, "Two-storey hall of painted and varnished walls lit by one top light",
                   duration=4.0, probe_box=COATED_PROBE_BOX, probe_counts=COATED_PROBE_COUNTS)

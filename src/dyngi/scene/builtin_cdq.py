"""Built-in scenes for the CDQ issue (Dittebrandt et al., Secs. 7.1 and 7.3; issue 18 item 4).

* ``sky-pit-sun-disc`` -- ``sky-pit``'s geometry (same pit, overhang, rubble and beam) lit by
  Mitsuba's ``sunsky`` instead of a delta ``directional`` sun and a constant sky: the sun is a
  finite disc of Mitsuba's default aperture (0.5358 degrees, the real sun's) inside the
  environment, so BSDF and CDQ samples can hit it. **Sun and sky are out of NEE, as in Quake 2
  RTX**: ``nee-pt`` never does NEE of the environment (issue 17 item 1), so with every ``lights=``
  choice both reach a surface only through indirect (BSDF or CDQ) rays -- the situation of
  Fig. 8 (b), where the CDQ gains "two to three orders of magnitude". With ``path``/``ddgi`` (whose
  NEE samples the environment) it is simply an environment-lit pit. The sun stands still at 70
  degrees elevation, azimuth 200 (like ``sky-pit``'s directional sun) for the first 1.5 s (45
  frames: the stationary window of the MSE measurements, Fig. 8 b), then moves to 64 / 215 degrees
  by t = 2 s and stays there (a readaptation event for the guiding). Exposure: sun x 7, sky x 4 of Mitsuba's units (frame
  mean of the same order as ``sky-pit``).
* ``sky-pit-sun-disc-2deg`` -- the same with a 2-degree sun (16x the solid angle, same irradiance),
  for our sample counts (see its docstring).
* ``rotating-hidden-light-9`` / ``rotating-hidden-light-36`` -- ``rotating-hidden-light`` with a
  rotation step of 9 and 36 degrees at t = 1, 2, 3 s (Fig. 10's two changes; the base scene steps
  by 90 degrees). Any other step: ``rotating_hidden_light(step_deg=...)`` in Python.
"""
from __future__ import annotations

import numpy as np

from .animation import ParamTrack, Track
from .builder import SceneBuilder
from .builtin_default import _sun_dir, _sunsky, rotating_hidden_light, sky_pit_geometry
from .camera import Camera
from .library import builtin

SUN_DISC_SCALE, SKY_SCALE = 7.0, 4.0
SUN_ELEVATION, SUN_AZIMUTH = 70.0, 200.0
SUN_LATER = (64.0, 215.0)       # where the sun moves between t = 1.5 s and 2 s
STILL_UNTIL = 1.5               # seconds of a static sun (45 frames at 30 fps)


def _sun_track() -> Track:
    """Towards-the-sun unit vectors: still until STILL_UNTIL, then along a great circle to SUN_LATER at
    t = 2 s (9 linear keyframes of unit vectors, so the interpolated direction stays unit to ~1e-4)."""
    s = np.linspace(0.0, 1.0, 9)
    w = 0.5 - 0.5 * np.cos(np.pi * s)                 # ease in/out
    el = SUN_ELEVATION + w * (SUN_LATER[0] - SUN_ELEVATION)
    az = SUN_AZIMUTH + w * (SUN_LATER[1] - SUN_AZIMUTH)
    dirs = [-_sun_dir(e, a) for e, a in zip(el, az)]
    times = [0.0] + list(STILL_UNTIL + s * (2.0 - STILL_UNTIL))
    return Track(times, [dirs[0]] + dirs, interp="linear")


@builtin("sky-pit-sun-disc", "sky-pit with a 0.5-degree sun disc in a sunsky environment; sun and sky out of "
         "NEE in nee-pt, as Quake 2 RTX", "VLC/CDQ Fig. 8 (b): Quake 2 RTX mine open to the sky, sun in the envmap")
def sky_pit_sun_disc(sun_aperture_deg: float | None = None, name: str = "sky-pit-sun-disc"):
    """``sky-pit``'s pit under a ``sunsky`` environment (finite 0.5358-degree sun disc, static).

    See the module docstring: nee-pt leaves sun and sky out of NEE, so only indirect rays find
    them (paper Sec. 7.1, scene (b)); path guiding (CDQ) must learn the sun's direction and the
    directly lit spot. ``sun_aperture_deg``: the sun's angular diameter (Mitsuba's ``sun_aperture``;
    default its 0.5358 degrees); the sun's irradiance stays the same.
    """
    b = SceneBuilder(name)
    P, D = sky_pit_geometry(b)   # the meshes of builtin.sky_pit
    # -- the environment: sun disc + sky, both out of nee-pt's NEE --
    env = _sunsky(SUN_DISC_SCALE, SKY_SCALE, _sun_dir(SUN_ELEVATION, SUN_AZIMUTH))
    if sun_aperture_deg is not None:
        env["sun_aperture"] = float(sun_aperture_deg)
    b.add("sunsky", env)
    b.animate(ParamTrack("sunsky.sun_direction", _sun_track(), mode="set"))
    cam = Camera((-2.6, -4.4, 2.6), (1.0, -4.6, -1.5), (0, 1, 0), 75.0)
    return b.build(cam, "Pit open to a sunsky (0.5-degree sun disc), sun and sky out of NEE", duration=4.0,
                   probe_box=((-P + 0.1, -D + 0.1, -P + 0.1), (P - 0.1, -0.1, P - 0.1)), probe_counts=(8, 8, 8))


@builtin("sky-pit-sun-disc-2deg", "sky-pit-sun-disc with a 2-degree sun (16x the solid angle, same irradiance)",
         "VLC/CDQ Fig. 8 (b) at our sample counts: the sun found as often per octree leaf as at 1080p")
def sky_pit_sun_disc_2deg():
    """``sky-pit-sun-disc`` with a sun of 2 degrees angular diameter (16x the 0.5-degree sun's solid
    angle, the same irradiance): our 160x90 frames place ~500 samples per octree leaf against the
    paper's ~4096 at 1080p, so a BSDF or CDQ sample finds this sun about as often per leaf as the
    paper's samples find a real-size one; sun and sky are out of nee-pt's NEE as in Quake 2 RTX.
    """
    return sky_pit_sun_disc(2.0, "sky-pit-sun-disc-2deg")


@builtin("rotating-hidden-light-9", "rotating-hidden-light turning in 9-degree steps (Fig. 10, small change)",
         "CDQ adaptation after a 9-degree change (Dittebrandt et al., Sec. 7.3, Fig. 10)")
def rotating_hidden_light_9():
    """``rotating-hidden-light`` whose light turns by 9 degrees at t = 1, 2, 3 s: the small sudden
    change of the CDQ adaptation experiment (Dittebrandt et al., Sec. 7.3, Fig. 10)."""
    return rotating_hidden_light(step_deg=9.0, name="rotating-hidden-light-9")


@builtin("rotating-hidden-light-36", "rotating-hidden-light turning in 36-degree steps (Fig. 10, large change)",
         "CDQ adaptation after a 36-degree change (Dittebrandt et al., Sec. 7.3, Fig. 10)")
def rotating_hidden_light_36():
    """``rotating-hidden-light`` whose light turns by 36 degrees at t = 1, 2, 3 s: the large sudden
    change of the CDQ adaptation experiment (Dittebrandt et al., Sec. 7.3, Fig. 10)."""
    return rotating_hidden_light(step_deg=36.0, name="rotating-hidden-light-36")

"""Built-in scenes for SMC instant radiosity's Table 1 (Hedman et al. 2017, Sec. 5.2), issue 16 item 6.

* ``corridor-walk`` -- the Soda Hall walk: the corridor and ten side rooms of
  ``corridor-rooms`` (same geometry and materials) with all 14 ceiling lights kept on
  (Table 1: 14 static lights) and a camera walking down the corridor, glancing into the
  doors; rooms appear at the corridor's far end and through the doors as it walks.
* ``street-canyon`` / ``street-canyon-moving-sun`` -- the Epic Citadel analog: a town of
  3 x 4 building blocks (8-22 m tall) on a street grid under a sun and a dim sky. Most of
  the scene (roofs, sunny facades, the open squares) is sunlit, while the camera walks at
  street level (1.7 m) along one street and sees a small part of it: the set of lit
  surfaces is much larger than the set of indirectly visible ones (Sec. 5.2). The static
  version keeps the sun fixed (Table 1 row 2); the moving one sweeps it 60 degrees in
  azimuth and drops it from 55 to 35 degrees elevation over the walk (row 5).
"""
from __future__ import annotations

import numpy as np

from .animation import Track
from .builder import SceneBuilder
from .animation import SunMotion
from .builtin_default import PLASTER, _floor, _sky, _sun, _sun_dir
from .camera import CameraPath
from .core import Scene
from .geometry import box, diffuse, merge
from .library import BUILTINS, builtin

WALK_SECONDS = 6.0


@builtin("corridor-walk", "Corridor with ten side rooms, all 14 ceiling lights on, camera walking down the corridor",
         "SMC-IR's Soda Hall walk (Table 1 row 1: 14 static lights, heavy occlusion)")
def corridor_walk():
    """The Soda Hall walk of SMC-IR (Table 1 row 1): ``corridor-rooms``' corridor, ten side rooms and
    furniture with all 14 ceiling lights on (no switching), and a camera walking 15 m down the corridor
    in 6 s, looking ahead and swaying towards the doors, so rooms come into view through the doors and
    at the corridor's far end."""
    base = BUILTINS["corridor-rooms"].factory()
    # the camera walks down the corridor (|z| < 1), looking ahead and swaying towards the doors
    times = np.linspace(0.0, WALK_SECONDS, 7)
    xs = np.linspace(0.6, 16.0, len(times))
    walk = [(float(x), 1.6, 0.25 * float(np.sin(1.3 * i))) for i, x in enumerate(xs)]
    look = [(float(x) + 5.0, 1.3, 1.6 * float(np.sin(0.9 * i + 0.5))) for i, x in enumerate(xs)]
    cam = CameraPath(Track(times, walk, interp="smooth"), Track(times, look, interp="smooth"), (0, 1, 0), 65.0)
    # no animators: the switched lights stay at their built (on) radiance
    return Scene("corridor-walk", base.mi_scene, cam, [], "Corridor with side rooms, 14 lights on, walking camera",
                 duration=WALK_SECONDS, fps=base.fps, probe_box=base.probe_box, probe_counts=base.probe_counts)


def _street_canyon(name: str, moving_sun: bool):
    b = SceneBuilder(name)
    # street grid: blocks 16 m (x) by 12 m (z), streets 8 m (x-streets) and 6 m wide
    bx, bz, sx, sz = 16.0, 12.0, 6.0, 8.0
    nx, nz = 4, 3
    x0 = -(nx * bx + (nx - 1) * sx) / 2
    z0 = -(nz * bz + (nz - 1) * sz) / 2
    rng = np.random.default_rng(16)
    blocks, roofs = [], []
    for i in range(nx):
        for j in range(nz):
            xa, za = x0 + i * (bx + sx), z0 + j * (bz + sz)
            # each block: 2 x 2 buildings of different heights (8-22 m)
            for a in range(2):
                for c in range(2):
                    h = float(rng.uniform(8.0, 22.0))
                    lo = (xa + a * bx / 2 + 0.2, 0.0, za + c * bz / 2 + 0.2)
                    hi = (xa + (a + 1) * bx / 2 - 0.2, h, za + (c + 1) * bz / 2 - 0.2)
                    blocks.append(box(lo, hi))
                    roofs.append(box((lo[0], h, lo[2]), (hi[0], h + 0.8, lo[2] + 0.5)))    # a parapet
    ext = (x0 - 20, -x0 + 20, z0 - 20, -z0 + 20)
    b.mesh("ground", _floor(*ext), diffuse((0.42, 0.4, 0.37)))
    b.mesh("buildings", merge(blocks), diffuse((0.62, 0.55, 0.45)))
    b.mesh("parapets", merge(roofs), diffuse(PLASTER))
    # awnings over the walked street (sunlit on top, shade the street: light bounces in)
    street_z = z0 + bz + sz / 2          # the street between block rows 0 and 1
    awn = [box((x0 + i * (bx + sx) + 2.0, 3.0, street_z - sz / 2 + 0.2),
               (x0 + i * (bx + sx) + 6.0, 3.1, street_z - sz / 2 + 1.8)) for i in range(nx)]
    b.mesh("awnings", merge(awn), diffuse((0.6, 0.15, 0.1)))
    sun0 = _sun_dir(55.0, 40.0)
    b.add("sun", _sun(sun0, (6.0, 5.6, 5.0)))
    b.add("sky", _sky((0.1, 0.13, 0.18)))
    if moving_sun:
        times = [0.0, WALK_SECONDS / 2, WALK_SECONDS]
        dirs = [sun0, _sun_dir(47.0, 70.0), _sun_dir(35.0, 100.0)]
        b.animate(SunMotion("sun", Track(times, dirs, interp="smooth")))
    times = np.linspace(0.0, WALK_SECONDS, 5)
    xs = np.linspace(x0 + 4.0, x0 + 40.0, len(times))
    walk = [(float(x), 1.7, street_z + 0.8 * float(np.sin(i))) for i, x in enumerate(xs)]
    look = [(float(x) + 10.0, 3.0, street_z + 2.5 * float(np.sin(0.8 * i + 1.0))) for i, x in enumerate(xs)]
    cam = CameraPath(Track(times, walk, interp="smooth"), Track(times, look, interp="smooth"), (0, 1, 0), 70.0)
    what = "moving" if moving_sun else "static"
    return b.build(cam, f"Sunlit street canyon (town of 12 blocks), {what} sun, camera walking at street level",
                   duration=WALK_SECONDS, probe_box=((x0, 0.3, z0), (-x0, 22.0, -z0)), probe_counts=(32, 6, 16))


@builtin("street-canyon", "Sunlit town of 12 blocks, static sun, camera walking at street level",
         "SMC-IR's Epic Citadel with a static light (Table 1 row 2)")
def street_canyon():
    """The Epic Citadel analog with a static sun (SMC-IR Table 1 row 2): a sunlit town of 12 blocks,
    the camera walking at street level and seeing a small part of the lit scene (module docstring)."""
    return _street_canyon("street-canyon", False)


@builtin("street-canyon-moving-sun", "Sunlit town of 12 blocks, moving sun, camera walking at street level",
         "SMC-IR's Epic Citadel with a moving light (Table 1 row 5)")
def street_canyon_moving_sun():
    """The Epic Citadel analog with a moving sun (SMC-IR Table 1 row 5): ``street-canyon`` with the sun
    sweeping 60 degrees in azimuth and sinking from 55 to 35 degrees elevation over the 6 s walk."""
    return _street_canyon("street-canyon-moving-sun", True)

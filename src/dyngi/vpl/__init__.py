"""Virtual point lights (VPLs), shared by ``ir``, ``smcir`` (Hedman et al. 2017) and their baselines.

* :mod:`.store`     -- the VPL store (a dataclass of host arrays; small: I <= 8K VPLs);
* :mod:`.smc`       -- SMC-IR's selection steps on the host (NumPy) and MIR's device resampling;
* :mod:`.smc_device` -- SMC-IR's iteration steps on the device (a Dr.Jit VPL store, visibility, sorts);
* :mod:`.density`   -- kNN surface-density estimate (Eq. 7, k from Eq. 8);
* :mod:`.radiosity` -- per-VPL-seeded radiosity estimate by a path tracer with NEE (Sec. 3.2.3);
* :mod:`.points`    -- directly visible points, candidate hits, photon paths, mailbox visibility (Sec. 3.2.2);
* :mod:`.shading`   -- shading of the camera's G-buffer by the VPLs: ray-traced visibility, clamped
  geometry term, interleaved 4x4 + cross-bilateral filter, or exhaustive (Sec. 4, Sec. 5.4).
"""
from .density import knn_density, knn_k  # noqa: F401
from .store import VPLStore  # noqa: F401

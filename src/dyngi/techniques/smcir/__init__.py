"""SMC-IR (Hedman, Karras, Lehtinen, TVCG 2017), technique ``smcir``: the technique and its parameters
(:mod:`.technique`, whose docstring describes the method), Algorithm 1 on the device (:mod:`.device`, the
default) and on the host (:mod:`.host`), and what both share (:mod:`.common`). The VPL store, densities,
radiosity estimate and selection steps they compose live in :mod:`dyngi.vpl`."""
from .common import CANDIDATE_K, IMPLS, REESTIMATE_MODES, WARMUP_FRAME_BASE, lighting_signature  # noqa: F401
from .technique import SMCIR  # noqa: F401

"""Backend selection: libLLVM discovery, Mitsuba variant, device info.

Dr.Jit's LLVM backend loads a shared ``libLLVM`` at run time. Debian's default
libLLVM 14 crashes drjit 1.5 kernels ("Cannot select ... fmaximum"), so this
module looks for a libLLVM >= 16 *before* drjit is imported and points
``DRJIT_LIBLLVM_PATH`` at it. Search order:

1. ``DRJIT_LIBLLVM_PATH`` if already set and the file exists;
2. the ``karellen-llvm-core`` wheel (installed as a dependency of dyngi),
   which ships ``libLLVM.so.23.1`` under ``<prefix>/lib``;
3. Debian/Ubuntu ``/usr/lib/llvm-NN/lib/libLLVM*.so*`` for NN >= 16.

Import ``mi`` and ``dr`` from here (``from dyngi.backend import mi, dr``) so
that the discovery always runs first. The default variant is
``llvm_ad_rgb``; :func:`set_device` switches to ``cuda_ad_rgb``.
"""
from __future__ import annotations

import glob
import os
import re
import sys

from .errors import DyngiError

MIN_LLVM = 16
VARIANTS = {"cpu": "llvm_ad_rgb", "cuda": "cuda_ad_rgb"}


def _llvm_version(path: str) -> int:
    m = re.search(r"(?:libLLVM-|libLLVM\.so\.|llvm-)(\d+)", path)
    return int(m.group(1)) if m else 0


def find_libllvm() -> str | None:
    """Return the path of a usable libLLVM (>= 16), or None."""
    env = os.environ.get("DRJIT_LIBLLVM_PATH")
    if env and os.path.exists(env):
        return env
    candidates: list[str] = []
    prefixes = {sys.prefix, sys.base_prefix, os.path.dirname(os.path.dirname(sys.executable))}
    for pre in prefixes:
        for libdir in ("lib", "lib64"):
            candidates += glob.glob(os.path.join(pre, libdir, "libLLVM.so.*"))
            candidates += glob.glob(os.path.join(pre, libdir, "libLLVM-*.so"))
    candidates += glob.glob("/usr/lib/llvm-*/lib/libLLVM*.so*")
    candidates += glob.glob("/usr/lib/*-linux-gnu/libLLVM*.so.*")
    good = [c for c in candidates if _llvm_version(c) >= MIN_LLVM and os.path.exists(c)]
    if not good:
        return None
    good.sort(key=_llvm_version, reverse=True)
    return os.path.realpath(good[0])


def _setup_llvm() -> None:
    if "drjit" in sys.modules:
        return  # too late to influence; the user imported drjit first
    path = find_libllvm()
    if path is None:
        raise DyngiError(
            "no libLLVM >= 16 found for Dr.Jit (Debian's libLLVM 14 crashes drjit 1.5); "
            "install the pip wheel 'karellen-llvm-core' or Debian's 'libllvm19', "
            "or set DRJIT_LIBLLVM_PATH"
        )
    os.environ["DRJIT_LIBLLVM_PATH"] = path


_setup_llvm()

import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402

mi.set_variant(VARIANTS["cpu"])

BLAS_THREADS_ENV = "DYNGI_BLAS_THREADS"


def limit_blas_threads() -> int | None:
    """Run NumPy's BLAS on one thread (``$DYNGI_BLAS_THREADS`` overrides); returns the limit set.

    Dr.Jit's LLVM backend runs its kernels on its own pool of one thread per
    core. An OpenBLAS pool beside it busy-waits after every matrix product
    (the probe blend, :mod:`dyngi.probes.blend`) and steals those cores: on the
    2-core machine a DDGI frame's Dr.Jit kernels ran up to 2x slower with two
    BLAS threads than with one (docs/techniques/ddgi.md, "BLAS threads"). Without
    ``threadpoolctl`` installed only libraries loaded after this call are limited.
    """
    try:
        n = int(os.environ.get(BLAS_THREADS_ENV, "1"))
    except ValueError:
        raise DyngiError(f"{BLAS_THREADS_ENV} must be an integer, got '{os.environ[BLAS_THREADS_ENV]}'")
    if n <= 0:
        return None
    # BLAS libraries loaded later (SciPy's own OpenBLAS) read these at load time ...
    for var in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "BLIS_NUM_THREADS"):
        os.environ.setdefault(var, str(n))
    # ... those loaded already (NumPy's, if the user imported it first) are limited by threadpoolctl
    import numpy  # noqa: F401
    try:
        import threadpoolctl
    except ImportError:  # pragma: no cover - a dependency of dyngi
        return None
    threadpoolctl.threadpool_limits(n, user_api="blas")
    return n


BLAS_THREADS = limit_blas_threads()


def upload(T, *arrays):
    """NumPy arrays as Dr.Jit arrays of type ``T`` in Dr.Jit's own memory, evaluated (one array, or a tuple).

    ``T(numpy_array)`` on the LLVM backend maps NumPy's buffer without a copy, and a kernel that then loads
    it directly is compiled with ``align 64`` loads when the buffer happens to be 64-byte aligned and
    ``align 1`` loads when it is not: two kernel hashes for one computation, chosen by the heap's state
    (garbage collection, what an earlier test left allocated). A per-frame upload from the host therefore
    "compiled new kernels" in a steady frame at random (issue 36: ``test_steady_device_builds_compile_nothing``
    failed in CI only). Here each array is copied by a gather with an opaque index into a buffer Dr.Jit
    allocates (always aligned): the copy kernel reads the mapped buffer by gather, which has no alignment in
    its IR, so it has one hash too. Arrays of one length are copied in one kernel."""
    import numpy as np

    dtype = {mi.Float: np.float32, mi.UInt32: np.uint32, mi.Int32: np.int32}.get(T)
    U = mi.UInt32
    out = []
    for a in arrays:
        src = T(np.ascontiguousarray(a, dtype) if dtype is not None else a)
        n = dr.width(src)
        out.append(dr.gather(T, src, dr.arange(U, n) + dr.opaque(U, 0)) if n else src)
    dr.eval(*out)
    return out[0] if len(out) == 1 else tuple(out)


def cuda_available() -> bool:
    """True when the CUDA backend of Dr.Jit can run (a GPU and driver present)."""
    try:
        return bool(dr.has_backend(dr.JitBackend.CUDA))
    except Exception:  # pragma: no cover - depends on the machine
        return False


def set_device(device: str = "cpu") -> str:
    """Select the Mitsuba variant for ``device`` ('cpu' or 'cuda'); return it.

    Must be called before any scene is built: Mitsuba objects belong to the
    variant that was active when they were created.
    """
    if device not in VARIANTS:
        raise DyngiError(f"unknown device '{device}'; valid devices: {', '.join(VARIANTS)}")
    variant = VARIANTS[device]
    if device == "cuda" and not cuda_available():
        raise DyngiError("device 'cuda' requested but no CUDA GPU/driver is available; use --device cpu")
    if variant not in mi.variants():
        raise DyngiError(f"Mitsuba variant '{variant}' is not available in this build")
    mi.set_variant(variant)
    return variant


def device_info() -> dict:
    """Facts for reports: variant, versions, libLLVM path, thread count."""
    return {
        "variant": mi.variant(),
        "mitsuba": mi.__version__,
        "drjit": dr.__version__,
        "libllvm": os.environ.get("DRJIT_LIBLLVM_PATH", ""),
        "threads": os.cpu_count(),
        "blas_threads": BLAS_THREADS,
    }

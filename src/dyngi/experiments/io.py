"""Image, video and table output, written atomically.

All outputs of one command are written into a temporary folder beside the
destination and moved into place only when everything succeeded, so a failure
midway leaves nothing half-written and loses nothing that was there before.
"""
from __future__ import annotations

import contextlib
import json
import os
import shutil
import tempfile

import numpy as np

from ..backend import dr, mi
from ..errors import DyngiError


def tonemap_srgb(img: np.ndarray, exposure: float = 1.0) -> np.ndarray:
    """Linear HDR -> 8-bit sRGB (clamped), for PNG and video."""
    x = np.clip(np.nan_to_num(img * exposure, nan=0.0, posinf=1.0), 0.0, 1.0)
    s = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return (s * 255.0 + 0.5).astype(np.uint8)


@contextlib.contextmanager
def exr_threads():
    """Mitsuba's OpenEXR reader and writer wait on Dr.Jit's thread pool and deadlock when it has a single
    thread (a cluster worker pinned to one, :mod:`~dyngi.experiments.cluster`): inside this block the pool
    has at least two threads; the count is restored afterwards."""
    n = dr.thread_count()
    if n >= 2:
        yield
        return
    dr.set_thread_count(2)
    try:
        yield
    finally:
        dr.set_thread_count(n)


def write_exr(path: str, img: np.ndarray) -> None:
    with exr_threads():
        mi.Bitmap(np.ascontiguousarray(img, dtype=np.float32)).write(path)


def read_exr(path: str) -> np.ndarray:
    with exr_threads():
        return np.asarray(mi.Bitmap(path), dtype=np.float32)


def write_png(path: str, img: np.ndarray, exposure: float = 1.0) -> None:
    import imageio.v3 as iio

    iio.imwrite(path, tonemap_srgb(img, exposure) if img.dtype != np.uint8 else img)


def write_mp4(path: str, frames, fps: float = 30.0) -> None:
    """8-bit frames (H x W x 3) -> H.264 MP4 via the ffmpeg that imageio-ffmpeg ships."""
    import imageio.v2 as iio2

    frames = list(frames)
    if not frames:
        return
    h, w = frames[0].shape[:2]
    # H.264 with yuv420p needs even sizes
    ph, pw = h + (h % 2), w + (w % 2)
    with iio2.get_writer(path, fps=fps, codec="libx264", quality=8, macro_block_size=1,
                         ffmpeg_log_level="error", pixelformat="yuv420p") as wr:
        for f in frames:
            if (ph, pw) != (h, w):
                f = np.pad(f, ((0, ph - h), (0, pw - w), (0, 0)), mode="edge")
            wr.append_data(f)


def write_json(path: str, obj) -> None:
    """Write ``obj`` as JSON to ``path`` atomically (a temporary file beside it, renamed): a reader never sees a
    half-written file, and an error while writing leaves the former file as it was."""
    tmp = f"{path}.tmp{os.getpid()}"
    try:
        with open(tmp, "w") as f:
            json.dump(obj, f, indent=1, default=_json_default)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)


def _json_default(o):
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, (np.floating,)):
        return float(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    return str(o)


def check_writable(out_dir: str) -> None:
    """Fail early, with one line, if ``out_dir`` cannot be created or written."""
    out_dir = os.path.abspath(out_dir)
    if os.path.exists(out_dir) and not os.path.isdir(out_dir):
        raise DyngiError(f"output '{out_dir}' exists and is not a folder")
    parent = out_dir
    while not os.path.exists(parent):
        parent = os.path.dirname(parent)
    if not os.path.isdir(parent):
        raise DyngiError(f"output '{out_dir}' cannot be created: '{parent}' is a file, not a folder")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise DyngiError(f"output folder '{out_dir}' is not writable (no write permission on '{parent}')")
    # permissions do not tell everything (root passes os.access on /proc, a read-only mount, a full disk):
    # make and remove a folder where the output will be made
    try:
        os.rmdir(tempfile.mkdtemp(prefix=".dyngi-probe-", dir=parent))
    except OSError as e:
        raise DyngiError(f"output folder '{out_dir}' cannot be created in '{parent}': "
                         f"{e.strerror or e}") from None


@contextlib.contextmanager
def atomic_output_dir(out_dir: str):
    """Yield a temporary folder; on success move its files into ``out_dir``."""
    check_writable(out_dir)
    out_dir = os.path.abspath(out_dir)
    parent = os.path.dirname(out_dir)
    try:
        os.makedirs(parent, exist_ok=True)
        tmp = tempfile.mkdtemp(prefix=".dyngi-tmp-", dir=parent)
        umask = os.umask(0o022)   # mkdtemp makes 0700; the result should look like any new folder
        os.umask(umask)
        os.chmod(tmp, 0o777 & ~umask)
    except OSError as e:
        raise DyngiError(f"cannot create output folder '{out_dir}': {e.strerror}") from None
    try:
        yield tmp
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    try:
        if not os.path.exists(out_dir):
            os.rename(tmp, out_dir)
            return
        for root, _, files in os.walk(tmp):
            rel = os.path.relpath(root, tmp)
            dst_root = os.path.join(out_dir, rel) if rel != "." else out_dir
            os.makedirs(dst_root, exist_ok=True)
            for fn in files:
                os.replace(os.path.join(root, fn), os.path.join(dst_root, fn))
        shutil.rmtree(tmp, ignore_errors=True)
    except OSError as e:
        shutil.rmtree(tmp, ignore_errors=True)
        raise DyngiError(f"cannot write into output folder '{out_dir}': {e.strerror}") from None

"""The summary files shared by the reproductions (no experiment of its own)."""
from __future__ import annotations

import json
import os

from ..io import atomic_output_dir


def write_summary(out_dir: str, md: str, json_files: dict) -> str:
    """Write ``summary.md`` (text ``md``) and one JSON file per ``{name: object}`` into ``out_dir``.

    The files are written into ``out_dir/_summary`` (atomically, :func:`atomic_output_dir`) and then
    moved up one by one, so a reader never sees a half-written summary. Returns ``out_dir``.
    """
    with atomic_output_dir(os.path.join(out_dir, "_summary")) as tmp:
        with open(os.path.join(tmp, "summary.md"), "w") as f:
            f.write(md)
        for name, obj in json_files.items():
            with open(os.path.join(tmp, name), "w") as f:
                json.dump(obj, f, indent=1, default=float)
    for name in ("summary.md", *json_files):
        os.replace(os.path.join(out_dir, "_summary", name), os.path.join(out_dir, name))
    os.rmdir(os.path.join(out_dir, "_summary"))
    return out_dir

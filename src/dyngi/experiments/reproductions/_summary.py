"""The summary files and the top-level report shared by the reproductions (no experiment of its own).

Every ``dyngi reproduce NAME`` ends in :func:`write_summary`, which writes ``summary.md``, the JSON
files, and ``report.html``: the paper-vs-ours table, the plots at the top level of the output folder
and a link to the report of each scene run in a sub-folder. ``summary.json`` at the top level always
has a ``techniques`` table (technique -> failed / non-finite counts), merged from the sub-folders'
``summary.json`` files when the experiment gives none, so the command line's failure check reads one
file.
"""
from __future__ import annotations

import html
import json
import os

from ..io import atomic_output_dir
from ..report import data_uri, md_to_html


def _sub_reports(out_dir: str) -> list[str]:
    """Relative paths of the ``report.html`` files below ``out_dir`` (not its own), sorted."""
    found = []
    for root, _, files in os.walk(out_dir):
        if root != out_dir and "report.html" in files:
            found.append(os.path.relpath(os.path.join(root, "report.html"), out_dir))
    return sorted(found)


def merged_techniques(out_dir: str) -> dict:
    """Failure status per technique merged over every ``summary.json`` below ``out_dir``: a technique
    failed if it failed in any run; non-finite pixel and frame counts add up."""
    merged: dict = {}
    for root, _, files in os.walk(out_dir):
        if root == out_dir or "summary.json" not in files:
            continue
        try:
            with open(os.path.join(root, "summary.json")) as f:
                techs = json.load(f).get("techniques", {})
        except (OSError, ValueError):
            continue
        for name, s in techs.items():
            if not isinstance(s, dict):
                continue
            m = merged.setdefault(name, {"failed": False, "nonfinite_pixels": 0, "nonfinite_frames": 0})
            m["failed"] = bool(m["failed"] or s.get("failed"))
            m["nonfinite_pixels"] += int(s.get("nonfinite_pixels", 0) or 0)
            m["nonfinite_frames"] += int(s.get("nonfinite_frames", 0) or 0)
    return merged


def report_html(out_dir: str, md: str) -> str:
    """The top-level ``report.html`` of a reproduction: ``md`` (the claim table), every PNG plot at the
    top level of ``out_dir`` embedded, and links to each scene's own report."""
    title = next((line[2:] for line in md.splitlines() if line.startswith("# ")), "dyngi reproduce")
    parts = ["<!doctype html><html><head><meta charset='utf-8'>"
             f"<title>{html.escape(title)}</title><style>body{{font-family:sans-serif;max-width:1200px;"
             "margin:auto}table{border-collapse:collapse}td,th{border:1px solid #ccc;padding:4px 8px;"
             "text-align:right}img{max-width:100%}</style></head><body>", md_to_html(md)]
    plots = sorted(n for n in os.listdir(out_dir) if n.endswith(".png"))
    if plots:
        parts.append("<h2>Plots</h2>")
        parts += [f"<figure><img src='{data_uri(os.path.join(out_dir, n), 'image/png')}' alt='{html.escape(n)}'>"
                  f"<figcaption>{html.escape(n)}</figcaption></figure>" for n in plots]
    subs = _sub_reports(out_dir)
    if subs:
        parts.append("<h2>Each run's report</h2><ul>")
        parts += [f"<li><a href='{html.escape(p)}'>{html.escape(os.path.dirname(p))}</a></li>" for p in subs]
        parts.append("</ul>")
    parts.append("</body></html>")
    return "\n".join(parts)


def write_summary(out_dir: str, md: str, json_files: dict) -> str:
    """Write ``summary.md`` (text ``md``), one JSON file per ``{name: object}`` and ``report.html``
    (:func:`report_html`) into ``out_dir``; ``summary.json`` gets the merged ``techniques`` table of the
    sub-folders (:func:`merged_techniques`) when ``json_files`` has none.

    The files are written into ``out_dir/_summary`` (atomically, :func:`atomic_output_dir`) and then
    moved up one by one, so a reader never sees a half-written summary. Returns ``out_dir``.
    """
    json_files = dict(json_files)
    summary = dict(json_files.get("summary.json", {}))
    if "techniques" not in summary:
        summary["techniques"] = merged_techniques(out_dir)
    json_files["summary.json"] = summary
    page = report_html(out_dir, md)
    with atomic_output_dir(os.path.join(out_dir, "_summary")) as tmp:
        with open(os.path.join(tmp, "summary.md"), "w") as f:
            f.write(md)
        with open(os.path.join(tmp, "report.html"), "w") as f:
            f.write(page)
        for name, obj in json_files.items():
            with open(os.path.join(tmp, name), "w") as f:
                json.dump(obj, f, indent=1, default=float)
    for name in ("summary.md", "report.html", *json_files):
        os.replace(os.path.join(out_dir, "_summary", name), os.path.join(out_dir, name))
    os.rmdir(os.path.join(out_dir, "_summary"))
    return out_dir

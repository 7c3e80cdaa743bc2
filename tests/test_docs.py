"""The docs stay organised by concept (DESIGN.md's layout; STYLE.md: name doc headings for the concept they
hold, never for when or how they were made): no heading under ``docs/`` names an issue or a session, the
index ``docs/README.md`` links every page, every registered technique has its page under
``docs/techniques/``, the top-level README links the index, and the pages' relative links resolve."""
from __future__ import annotations

import os
import re

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DOCS = os.path.join(ROOT, "docs")

# Registered technique -> the page under docs/techniques/ that describes it. A new technique needs a row
# here and a page (or a section of a family's page).
TECHNIQUE_PAGES = {
    "path": "path.md",
    "ddgi": "ddgi.md",
    "qddgi": "qddgi.md",
    "probes-reference": "probes-reference.md",
    "adgi": "adgi.md",
    "isddgi": "isddgi.md",
    "restir-pt": "restir-pt.md",
    "ddgi-primary": "ddgi-resampling.md",
    "ddgi-secondary": "ddgi-resampling.md",
    "ddgi-resampling": "ddgi-resampling.md",
    "ir": "smcir.md",
    "mir": "smcir.md",
    "tcas": "smcir.md",
    "smcir": "smcir.md",
    "nee-pt": "nee-pt.md",
}

NAMED_FOR_WHEN = re.compile(r"\b(issue|session)s?\s*#?\d+", re.IGNORECASE)
LINK = re.compile(r"\[[^\]]*\]\(([^)\s]+)\)")


def _pages() -> list[str]:
    out = []
    for d, _, files in os.walk(DOCS):
        out += [os.path.relpath(os.path.join(d, f), DOCS) for f in files if f.endswith(".md")]
    return sorted(out)


def _headings(path: str) -> list[tuple[int, str]]:
    """(line number, text) of the Markdown headings of a file, code fences skipped."""
    out, fence = [], False
    with open(path, encoding="utf-8") as f:
        for i, line in enumerate(f, 1):
            if line.lstrip().startswith("```"):
                fence = not fence
            elif not fence and re.match(r"^#{1,6}\s", line):
                out.append((i, line.rstrip()))
    return out


def _links(path: str) -> set[str]:
    """Relative link targets of a Markdown file, resolved against its folder (anchors dropped)."""
    text = open(path, encoding="utf-8").read()
    out = set()
    for target in LINK.findall(text):
        if re.match(r"^[a-z]+:", target) or target.startswith("#"):
            continue
        target = target.split("#")[0]
        out.add(os.path.normpath(os.path.join(os.path.dirname(path), target)))
    return out


def test_no_doc_heading_names_an_issue_or_a_session():
    bad = [f"docs/{p}:{i}: {h}" for p in _pages() for i, h in _headings(os.path.join(DOCS, p))
           if NAMED_FOR_WHEN.search(h)]
    assert not bad, "headings named for when they were written, not for their concept:\n" + "\n".join(bad)


def test_the_heading_check_can_fail(tmp_path):
    p = tmp_path / "x.md"
    p.write_text("# Probes\n```\n# issue 3 inside a code block is code\n```\n## Leaks (issue 22)\n### Session 7: VLC\n")
    assert [h for _, h in _headings(str(p)) if NAMED_FOR_WHEN.search(h)] == ["## Leaks (issue 22)",
                                                                             "### Session 7: VLC"]


def test_the_index_links_every_page():
    index = os.path.join(DOCS, "README.md")
    linked = _links(index)
    missing = [p for p in _pages() if p != "README.md" and os.path.join(DOCS, p) not in linked]
    assert not missing, f"docs/README.md does not link: {missing}"


def test_the_readme_links_the_docs_index():
    assert os.path.join(DOCS, "README.md") in _links(os.path.join(ROOT, "README.md"))


def test_every_registered_technique_has_a_page():
    from dyngi.techniques.base import technique_names

    names = technique_names()
    unmapped = sorted(set(names) - set(TECHNIQUE_PAGES))
    assert not unmapped, f"techniques without a docs page (add them to TECHNIQUE_PAGES and docs/techniques/): {unmapped}"
    for name in names:
        page = os.path.join(DOCS, "techniques", TECHNIQUE_PAGES[name])
        assert os.path.exists(page), f"{name}: {page} does not exist"
        assert f"`{name}`" in open(page, encoding="utf-8").read(), f"{name}: not named on {page}"
    stale = sorted(set(TECHNIQUE_PAGES) - set(names))
    assert not stale, f"TECHNIQUE_PAGES names techniques that are not registered: {stale}"


def test_relative_links_in_the_docs_resolve():
    broken = []
    for p in _pages() + ["../README.md", "../benchmarks/README.md"]:
        path = os.path.normpath(os.path.join(DOCS, p))
        broken += [f"{os.path.relpath(path, ROOT)} -> {os.path.relpath(t, ROOT)}" for t in _links(path)
                   if not os.path.exists(t)]
    assert not broken, "broken links:\n" + "\n".join(broken)


# -- every marked parameter listed on its technique's page (issue 40) -----------------------------------------
ROW = re.compile(r"^\| `([A-Za-z0-9_]+)` \| ([^|]*) \| ([^|]*) \|(.*)$")
SHARED_PAGE = "ddgi.md"
"""Where the probe techniques' shared parameters are listed ("Besides the shared probe parameters")."""


def ours_cell(p) -> str:
    """The ``ours?`` cell of a parameter row: empty, ``**ours**``, or ``**ours** (paper: VALUE)``."""
    if not p.ours:
        return ""
    return f"**ours** (paper: `{p.paper!r}`)" if p.has_paper_value else "**ours**"


def _page_rows(page: str, cell: int = 3) -> dict:
    rows = {}
    for line in open(os.path.join(DOCS, "techniques", page), encoding="utf-8"):
        m = ROW.match(line.rstrip("\n"))
        if m:
            rows.setdefault(m.group(1), []).append(m.group(cell).strip())
    return rows


def _expected_defaults() -> dict:
    """``{(page, parameter): {default cell}}`` (a page's parameter may belong to several techniques)."""
    from dyngi.techniques.base import REGISTRY, technique_names
    out: dict = {}
    for name in technique_names():
        for k, p in REGISTRY[name].PARAMS.items():
            out.setdefault((TECHNIQUE_PAGES[name], k), set()).add(f"`{p.default!r}`")
    return out


def _expected_cells() -> dict:
    """``{(page, parameter): {ours cell}}`` over every registered technique (a page's own technique first,
    the shared probe page for the probe techniques' common parameters)."""
    from dyngi.techniques.base import REGISTRY, technique_names
    out: dict = {}
    for name in technique_names():
        for k, p in REGISTRY[name].PARAMS.items():
            out.setdefault((TECHNIQUE_PAGES[name], k), set()).add(ours_cell(p))
    return out


def test_every_parameter_row_says_whether_it_is_ours():
    """The ``ours?`` column of every technique page's parameter tables agrees with the ``Param`` marks (issue
    40: the docs list every marked parameter per technique, with the paper's value where it gives one),
    every marked parameter has a row on its page (or the shared probe page), and a row's default is the
    code's where one technique owns it. ``python tests/test_docs.py
    --write`` rewrites the cells from the marks."""
    from dyngi.techniques.base import REGISTRY, technique_names
    want = _expected_cells()
    bad, missing = [], []
    for page in sorted(set(TECHNIQUE_PAGES.values())):
        for k, cells in _page_rows(page).items():
            ok = want.get((page, k)) or want.get((SHARED_PAGE, k))
            if ok is not None and any(c not in ok for c in cells):
                bad.append(f"{page}: `{k}` says {cells}, the marks say {sorted(ok)}")
    for name in technique_names():
        page = TECHNIQUE_PAGES[name]
        for k, p in REGISTRY[name].PARAMS.items():
            if p.ours and k not in _page_rows(page) and k not in _page_rows(SHARED_PAGE):
                missing.append(f"{name}: `{k}` (ours) has no row on {page}")
    defaults = _expected_defaults()
    for page in sorted(set(TECHNIQUE_PAGES.values())):
        for k, cells in _page_rows(page, 2).items():
            ok = defaults.get((page, k))
            if ok is not None and len(ok) == 1 and any(c not in ok for c in cells):
                bad.append(f"{page}: `{k}`'s default says {cells}, the code {sorted(ok)}")
    assert not bad and not missing, "\n".join(bad + missing)


def write_ours_cells() -> None:
    """Rewrite the ``ours?`` cells of every technique page from the marks (a cell shared by techniques whose
    marks differ is left as it is and reported by the test), and add a row for every marked parameter
    without one after the page's last parameter row."""
    from dyngi.techniques.base import REGISTRY, technique_names
    want, defaults = _expected_cells(), _expected_defaults()
    for page in sorted(set(TECHNIQUE_PAGES.values())):
        path = os.path.join(DOCS, "techniques", page)
        lines = open(path, encoding="utf-8").read().split("\n")
        last = None
        for i, line in enumerate(lines):
            m = ROW.match(line)
            if not m:
                continue
            last = i
            cells = want.get((page, m.group(1))) or want.get((SHARED_PAGE, m.group(1)))
            dflt = defaults.get((page, m.group(1)))
            d = next(iter(dflt)) if dflt is not None and len(dflt) == 1 else m.group(2)
            if cells is not None and len(cells) == 1:
                lines[i] = f"| `{m.group(1)}` | {d} | {next(iter(cells))} |{m.group(4)}"
        have = _page_rows(page) | (_page_rows(SHARED_PAGE) if page != SHARED_PAGE else {})
        new = []
        for name in technique_names():
            if TECHNIQUE_PAGES[name] != page:
                continue
            for k, p in REGISTRY[name].PARAMS.items():
                if p.ours and k not in have and not any(f"| `{k}` |" in x for x in new):
                    extra = f" (one of {', '.join(map(str, p.choices))})" if p.choices else ""
                    new.append(f"| `{k}` | `{p.default!r}` | {ours_cell(p)} | {p.doc}{extra} |")
        if new and last is not None:
            lines[last + 1:last + 1] = new
        with open(path, "w", encoding="utf-8") as f:
            f.write("\n".join(lines))


if __name__ == "__main__":
    import sys
    if sys.argv[1:] == ["--write"]:
        write_ours_cells()

"""``dyngi reproduce``: the registry, its errors, and the quick ``ddgi`` run."""
import json
import os
import time

import pytest


def test_list_and_unknown_experiment(backend, capsys):
    from dyngi.cli import main

    assert main(["reproduce", "--list"]) == 0
    lines = capsys.readouterr().out.splitlines()
    names = [ln.split(":", 1)[0] for ln in lines if ln and not ln.startswith(" ")]
    assert names == sorted(names) and {"ddgi", "adgi", "isddgi", "smcir"} <= set(names), names
    assert any(ln.startswith("ddgi: ") and "Majercik" in ln for ln in lines)
    assert main(["reproduce", "nope", "--quick"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    valid = ", ".join(sorted(names))
    assert len(err) == 1 and f"unknown experiment 'nope'; valid experiments: {valid}" in err[0], err
    assert main(["reproduce"]) == 2
    assert f"registered experiments: {valid}" in capsys.readouterr().err


@pytest.mark.slow
def test_ddgi_quick_writes_report_with_paper_table(backend, tmp_path, monkeypatch):
    """Under 3 minutes on 2 cores (references included); reuses the evaluation and the report writer,
    not ``run_compare``."""
    from dyngi.experiments import compare
    from dyngi.experiments.reproduce import run_experiment

    def no(*a, **k):
        raise AssertionError("reproduce must not call run_compare")

    monkeypatch.setattr(compare, "run_compare", no)
    monkeypatch.setenv("DYNGI_CACHE", str(tmp_path / "cache"))
    t0 = time.perf_counter()
    out = run_experiment("ddgi", str(tmp_path / "r"), quick=True)
    assert time.perf_counter() - t0 < 180
    for f in ("report.html", "summary.md", "summary.json", "metrics.csv", "reconvergence.csv", "paper.json",
              "plots/reconvergence.png"):
        assert os.path.isfile(os.path.join(out, f)), f
    md = open(os.path.join(out, "summary.md")).read()
    assert "## Beside the paper" in md and "| quantity | published (paper) | ours |" in md
    assert "6 ms/frame" in md and "no figure published" in md
    html = open(os.path.join(out, "report.html")).read()
    assert "Beside the paper" in html and html.count("data:image/png;base64,") >= 3
    js = json.load(open(os.path.join(out, "paper.json")))
    rc = js["reconvergence"]
    before = rc["before"]
    # the light jump raises the error, and ddgi comes back down
    assert rc["relmse"][before] > rc["converged_before"]
    assert rc["frames_to_reconverge"] is not None and rc["frames_to_reconverge"] < len(rc["relmse"]) - before
    s = json.load(open(os.path.join(out, "summary.json")))
    assert s["budget"] == "equal-time" and sorted(s["techniques"]) == ["ddgi", "path"]


def test_reconvergence_frames_criterion():
    from dyngi.experiments.reproduce import reconvergence_frames

    assert reconvergence_frames([1.0, 0.5, 0.2, 0.11, 0.1], 0.1) == 4     # 0.2 > 0.19, 0.11 <= 0.19
    assert reconvergence_frames([0.05, 0.1], 0.1) == 1
    assert reconvergence_frames([1.0, 0.9], 0.1) is None

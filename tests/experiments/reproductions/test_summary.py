"""The reproductions' shared summary writer: every reproduction gets a top-level
``report.html`` (claim table, plots, links to each scene's report) and a ``summary.json`` whose
``techniques`` table the command line's failure check reads, merged from the sub-folders."""
import json
import os

import numpy as np


def _png(path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(2, 2))
    ax.plot(np.arange(3))
    fig.savefig(path)
    plt.close(fig)


def _scene_run(out, name, techniques):
    d = out / name
    d.mkdir(parents=True)
    (d / "report.html").write_text("<html></html>")
    (d / "summary.json").write_text(json.dumps({"techniques": techniques}))


def test_top_level_report_and_merged_failures(tmp_path):
    from dyngi.cli import _report_failures
    from dyngi.experiments.reproductions._summary import write_summary

    out = tmp_path / "r"
    _scene_run(out, "tunnel-gate", {"ddgi": {"failed": False, "nonfinite_pixels": 0, "nonfinite_frames": 0}})
    _scene_run(out, "corridor-rooms", {"ddgi": {"failed": True, "nonfinite_pixels": 7, "nonfinite_frames": 2},
                                        "isddgi": {"failed": False}})
    _png(out / "errors.png")
    md = "# reproduce x (quick run)\n\n| quantity | published (paper) | ours |\n|---|---|---|\n| speed-up | 2x | 1.5x |\n"
    write_summary(str(out), md, {"paper.json": {"rows": []}})

    page = (out / "report.html").read_text()
    assert "<h1>reproduce x (quick run)</h1>" in page and "<td>1.5x</td>" in page
    assert page.count("data:image/png;base64,") == 1
    assert "href='corridor-rooms/report.html'" in page and "href='tunnel-gate/report.html'" in page
    techs = json.load(open(out / "summary.json"))["techniques"]
    assert techs["ddgi"] == {"failed": True, "nonfinite_pixels": 7, "nonfinite_frames": 2}
    assert techs["isddgi"]["failed"] is False
    assert _report_failures(str(out)) == 1
    assert not os.path.exists(out / "_summary")


def test_clean_run_reports_success_and_keeps_given_summary(tmp_path):
    from dyngi.cli import _report_failures
    from dyngi.experiments.reproductions._summary import write_summary

    out = tmp_path / "r"
    _scene_run(out, "a", {"ddgi": {"failed": False}})
    given = {"experiment": "y", "techniques": {"path": {"failed": False}}}
    write_summary(str(out), "# y\n", {"summary.json": given})
    assert json.load(open(out / "summary.json")) == given
    assert _report_failures(str(out)) == 0
    # no top-level summary.json at all (an experiment that wrote none): merged from the sub-folders
    os.remove(out / "summary.json")
    assert _report_failures(str(out)) == 0

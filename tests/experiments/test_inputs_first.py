"""Every command that writes files checks its output folder (and its other inputs) before it renders
anything: a bad folder is one line on stderr, exit 2, no ray traced, no reference rendered, nothing
written. "Bad" covers what permission bits do not show (root passes ``os.access`` on ``/proc``): the check
makes and removes a folder where the output goes."""
from __future__ import annotations

import os
import time

import pytest

from dyngi.backend import mi
from dyngi.cli import main


class Rendered(AssertionError):
    pass


@pytest.fixture()
def no_rendering(monkeypatch):
    """Any ray query or Mitsuba render raises :class:`Rendered` (caught by the CLI as a traceback, so the
    test sees it)."""
    def trap(*a, **k):
        raise Rendered("something was rendered before the inputs were checked")
    for name in ("ray_intersect", "ray_intersect_preliminary", "ray_test"):
        monkeypatch.setattr(mi.Scene, name, trap)
    monkeypatch.setattr(mi, "render", trap)


SMALL = ["--frames", "2", "--res", "16x9"]
COMMANDS = {
    "render": ["render", "cornell-static", "--technique", "ddgi", *SMALL],
    "compare": ["compare", "cornell-static", "--techniques", "ddgi,path", *SMALL],
    "sweep": ["sweep", "ddgi", "cornell-static", "--grid", "hysteresis=0.9,0.97", *SMALL],
    "reproduce": ["reproduce", "ddgi", "--quick"],
    "demo": ["demo", "--quick"],
    "probe-view": ["probe-view", "cornell-static", "--res", "16x9"],
}


def _bad_outputs(tmp_path):
    f = tmp_path / "a-file"
    f.write_text("x")
    return {"under /proc": "/proc/dyngi-out", "under a file": str(f / "out"), "is a file": str(f)}


@pytest.mark.parametrize("cmd", sorted(COMMANDS))
def test_bad_output_folder_fails_first(backend, no_rendering, tmp_path, capsys, cmd):
    for what, out in _bad_outputs(tmp_path).items():
        before = sorted(os.listdir(tmp_path))
        t0 = time.perf_counter()
        rc = main(COMMANDS[cmd] + ["--out", out])
        dt = time.perf_counter() - t0
        err = capsys.readouterr().err
        print(f"{cmd} --out {what}: exit {rc} in {dt:.2f} s")
        assert rc == 2, (cmd, what, err)
        assert err.startswith("dyngi: error: ") and err.count("\n") == 1 and "Traceback" not in err, err
        assert out in err or os.path.dirname(out) in err, err
        assert sorted(os.listdir(tmp_path)) == before, (cmd, what)


def test_unknown_cluster_is_refused_before_work(backend, no_rendering, tmp_path, capsys):
    for argv in (["reference", "cornell-static", *SMALL, "--cluster", "bogus"],
                 ["compare", "cornell-static", "--techniques", "ddgi", *SMALL, "--cluster", "bogus",
                  "--out", str(tmp_path / "o")]):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert "--cluster 'bogus' is invalid" in err and err.count("\n") == 1
    assert not (tmp_path / "o").exists()


def test_a_spec_is_parsed_once_at_the_edge(backend, tmp_path, monkeypatch, capsys):
    """``dyngi render`` / ``dyngi compare`` parse each technique spec once (the CLI) and pass the
    :class:`TechniqueSpec` down; ``--set`` keys are checked there, by the technique's own parameter table."""
    import dyngi.cli as cli
    import dyngi.techniques.base as base

    calls = []
    real = base.parse_spec
    monkeypatch.setattr(base, "parse_spec", lambda text: calls.append(text) or real(text))
    monkeypatch.setattr(cli, "parse_spec", base.parse_spec)
    out = tmp_path / "r"
    assert main(["render", "cornell-static", "--technique", "path:max_depth=3", "--set", "spp=2", "--frames", "1",
                 "--res", "8x6", "--out", str(out), "--quiet"]) == 0, capsys.readouterr().err
    assert calls == ["path:max_depth=3"], calls
    import json
    stats = json.loads((out / "stats.json").read_text())
    assert stats["params"]["spp"] == 2 and stats["params"]["max_depth"] == 3
    calls.clear()
    assert main(["render", "cornell-static", "--technique", "path", "--set", "bogus=1", "--res", "8x6",
                 "--out", str(tmp_path / "b")]) == 2
    err = capsys.readouterr().err
    assert "unknown parameter 'bogus' for technique 'path'" in err and err.count("\n") == 1
    assert not (tmp_path / "b").exists()


@pytest.mark.parametrize("cmd", ["render", "reference", "compare", "sweep", "probe-view"])
def test_scene_options_are_checked_before_work(backend, no_rendering, tmp_path, capsys, cmd):
    """``--camera``, ``--animation`` and ``--fps`` on a glTF scene: one line, exit 2, nothing rendered or
    written (the scene options reach every command that loads a scene)."""
    import runpy

    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    box = runpy.run_path(os.path.join(root, "examples", "animated_box.py"))["write"](str(tmp_path / "box.gltf"))
    argv = {"render": ["render", box], "reference": ["reference", box],
            "compare": ["compare", box, "--techniques", "ddgi"],
            "sweep": ["sweep", "ddgi", box, "--grid", "hysteresis=0.9,0.97"],
            "probe-view": ["probe-view", box]}[cmd] + SMALL
    if cmd != "reference":
        argv += ["--out", str(tmp_path / "o")]
    for extra, needle in ((["--camera", "nope"], "no camera named 'nope'"),
                          (["--animation", box], "--animation applies to Mitsuba XML"),
                          (["--fps", "-2"], "--fps must be a positive number")):
        before = sorted(os.listdir(tmp_path))
        try:
            rc = main(argv + extra)
        except SystemExit as e:       # argparse's own check (--fps's type)
            rc = e.code
        assert rc == 2
        err = capsys.readouterr().err
        assert err.startswith("dyngi: error: ") and err.count("\n") == 1 and needle in err, (cmd, err)
        assert sorted(os.listdir(tmp_path)) == before

"""The command line: clear one-line errors, render outputs, determinism, nothing half-written."""
import json
import os
import subprocess
import sys

import numpy as np
import pytest

DYNGI = [sys.executable, "-m", "dyngi.cli"]


def run(*args, cwd=None):
    return subprocess.run(DYNGI + list(args), capture_output=True, text=True, cwd=cwd, timeout=300)


def test_scenes_and_techniques_listed():
    r = run("scenes")
    assert r.returncode == 0 and "cornell-moving-light" in r.stdout
    r = run("techniques")
    assert r.returncode == 0 and "path:" in r.stdout and "max_depth" in r.stdout


@pytest.mark.parametrize("args,needle", [
    (["render", "no-such-scene", "--out", "{tmp}/o"], "unknown scene 'no-such-scene'"),
    (["render", "{tmp}/missing.xml", "--out", "{tmp}/o"], "does not exist"),
    (["render", "cornell-static", "--technique", "nope", "--out", "{tmp}/o"], "valid techniques: "),
    (["render", "cornell-static", "--set", "bogus=1", "--out", "{tmp}/o"], "valid parameters: "),
    (["render", "cornell-static", "--set", "spp=-3", "--out", "{tmp}/o"], "below its minimum"),
    (["render", "cornell-static", "--set", "mis=nope", "--out", "{tmp}/o"], "valid values: power, balance"),
    (["render", "cornell-static", "--res", "12by3", "--out", "{tmp}/o"], "use WxH"),
    (["render", "cornell-static", "--out", "{tmp}/afile/o"], "not a folder"),
    (["render", "cornell-static", "--res", "8x6", "--out", "/proc/dyngi-test/o"], "output folder"),
])
def test_bad_input_one_line_error(tmp_path, args, needle):
    (tmp_path / "afile").write_text("x")
    r = run(*[a.format(tmp=tmp_path) for a in args])
    assert r.returncode == 2, r.stderr
    lines = [l for l in r.stderr.strip().splitlines() if l.strip()]
    assert len(lines) == 1 and "Traceback" not in r.stderr, r.stderr
    assert needle in lines[0], lines[0]
    assert not (tmp_path / "o").exists()


def test_unwritable_output(tmp_path, monkeypatch):
    """A folder without write permission: one clear error, nothing rendered or written.

    Root ignores permission bits, so the permission check itself is made to answer 'no'
    for that folder (what os.access reports to an ordinary user).
    """
    from dyngi.errors import DyngiError
    from dyngi.experiments import render as rmod

    ro = tmp_path / "ro"
    ro.mkdir()
    real_access = os.access
    monkeypatch.setattr(os, "access", lambda p, mode, **kw: False if os.fspath(p) == str(ro)
                        else real_access(p, mode, **kw))
    with pytest.raises(DyngiError, match="not writable"):
        rmod.render_to_dir("cornell-static", "path", str(ro / "o"), frames=1, res=(8, 6), quiet=True)
    assert os.listdir(ro) == []


def test_render_outputs_and_determinism(tmp_path):
    from dyngi.experiments.io import read_exr

    outs = []
    for name, seed in (("a", 3), ("b", 3), ("c", 4)):
        out = tmp_path / name
        r = run("render", "cornell-moving-light", "--frames", "3", "--res", "32x24", "--spp", "2",
                "--seed", str(seed), "--out", str(out), "--quiet")
        assert r.returncode == 0, r.stderr
        outs.append(out)
    files = sorted(os.listdir(outs[0]))
    for i in range(3):
        assert f"frame_{i:04d}.exr" in files and f"frame_{i:04d}.png" in files
    assert "video.mp4" in files and os.path.getsize(outs[0] / "video.mp4") > 1000
    stats = json.loads((outs[0] / "stats.json").read_text())
    assert len(stats["frames"]) == 3
    assert stats["frames"][1]["rays"]["trace"] >= 32 * 24 * 2
    assert "trace" in stats["frames"][1]["ms"]
    a, b, c = (read_exr(str(o / "frame_0002.exr")) for o in outs)
    assert a.shape == (24, 32, 3) and np.all(np.isfinite(a)) and a.mean() > 0
    assert np.array_equal(a, b), "same seed must give bit-identical EXRs"
    assert not np.array_equal(a, c)


def test_failure_midway_leaves_nothing(tmp_path, monkeypatch):
    """A technique failing on frame 2 leaves no partial output and keeps what was there."""
    from dyngi.errors import DyngiError
    from dyngi.experiments import render as rmod
    from dyngi.techniques.path import PathTechnique

    out = tmp_path / "keep"
    out.mkdir()
    (out / "old.txt").write_text("precious")
    calls = {"n": 0}
    orig = PathTechnique.step

    def failing(self, frame):
        calls["n"] += 1
        if calls["n"] == 2:
            raise DyngiError("boom")
        return orig(self, frame)

    monkeypatch.setattr(PathTechnique, "step", failing)
    with pytest.raises(DyngiError):
        rmod.render_to_dir("cornell-static", "path", str(out), frames=3, res=(8, 6), quiet=True)
    assert sorted(os.listdir(out)) == ["old.txt"]
    assert not [p for p in os.listdir(tmp_path) if p.startswith(".dyngi-tmp")]


def test_probe_view_writes_images(tmp_path):
    import imageio.v3 as iio

    out = tmp_path / "pv"
    r = run("probe-view", "cornell-static", "--res", "48x36", "--set", "probe_counts=4",
            "--set", "rays_per_probe=32", "--out", str(out))
    assert r.returncode == 0, r.stderr
    img = iio.imread(out / "probes.png")
    assert img.shape == (36, 48, 3) and img.std() > 0
    assert "probes active" in r.stdout
    r = run("probe-view", "cornell-static", "--technique", "path", "--out", str(tmp_path / "x"))
    assert r.returncode == 2 and "no probe volume" in r.stderr


def test_scenes_listing_has_timing():
    r = run("scenes")
    assert "2 s at 30 fps (60 frames, loops)" in r.stdout      # cornell-moving-light
    assert "static" in r.stdout                                  # cornell-static


def test_demo_options_and_bad_section(tmp_path):
    """`dyngi demo`: the tour's options are there; a bad section is a one-line error, nothing written."""
    r = run("demo", "--help")
    assert r.returncode == 0
    for opt in ("--out", "--quick", "--sections", "--classic", "--frames", "--res", "--ref-spp", "--quiet"):
        assert opt in r.stdout, opt
    r = run("demo", "--quick", "--sections", "adgi,nope", "--out", str(tmp_path / "o"))
    assert r.returncode == 2, r.stderr
    lines = [l for l in r.stderr.strip().splitlines() if l.strip()]
    assert len(lines) == 1 and "unknown demo section 'nope'; sections: adgi, isddgi" in lines[0], r.stderr
    assert not (tmp_path / "o").exists()


def test_reproduce_has_smoke_size():
    r = run("reproduce", "--help")
    assert r.returncode == 0 and "--smoke" in r.stdout


# -- a user's own animated glTF scene (examples/animated_box.py writes it) --------------------------------
def _box(tmp_path):
    import runpy

    ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    mod = runpy.run_path(os.path.join(ROOT, "examples", "animated_box.py"))
    return mod["write"](str(tmp_path / "box.gltf"))


def test_scene_flags_on_every_scene_command():
    from dyngi.cli import build_parser

    p = build_parser()
    for argv in (["render", "s", "--out", "o"], ["reference", "s"], ["compare", "s", "--techniques", "path",
                 "--out", "o"], ["sweep", "path", "s"], ["probe-view", "s", "--out", "o"], ["view", "s"]):
        a = p.parse_args(argv + ["--fps", "24", "--camera", "cam", "--animation", "a.toml", "--loop"])
        assert (a.fps, a.camera, a.animation, a.loop) == (24.0, "cam", "a.toml", True), argv[0]


def test_gltf_render_moves_with_fps(tmp_path):
    box = _box(tmp_path)
    out = tmp_path / "out"
    r = run("render", box, "--technique", "ddgi", "--frames", "3", "--fps", "4", "--res", "24x18", "--quiet",
            "--out", str(out))
    assert r.returncode == 0, r.stderr
    assert "wrote 3 frame(s) of 'box'" in r.stdout
    from dyngi.experiments.io import read_exr

    f0, f2 = (read_exr(str(out / f"frame_{i:04d}.exr")) for i in (0, 2))
    assert np.abs(f0 - f2).mean() > 1e-3        # at 4 fps, frame 2 is t = 0.5 s: the box has moved


@pytest.mark.parametrize("args,needle", [
    (["--animation", "{box}"], "--animation applies to Mitsuba XML"),
    (["--camera", "nope"], "no camera named 'nope'; cameras: watch"),
    (["--fps", "0"], "--fps must be a positive number"),
])
def test_gltf_bad_scene_flags_one_line(tmp_path, args, needle):
    box = _box(tmp_path)
    r = run("render", box, "--res", "8x6", "--out", str(tmp_path / "o"), *[a.format(box=box) for a in args])
    assert r.returncode == 2, r.stderr
    lines = [l for l in r.stderr.strip().splitlines() if l.strip()]
    assert len(lines) == 1 and needle in lines[0], r.stderr
    assert not (tmp_path / "o").exists()


@pytest.mark.slow
def test_gltf_compare_writes_the_report(tmp_path):
    box = _box(tmp_path)
    out = tmp_path / "cmp"
    r = run("compare", box, "--techniques", "ddgi,path", "--frames", "3", "--fps", "24", "--res", "24x18",
            "--ref-spp", "4", "--metrics", "mse", "--quiet", "--out", str(out))
    assert r.returncode == 0, r.stderr
    assert (out / "report.html").exists() and (out / "metrics.csv").exists()

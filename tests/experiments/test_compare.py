"""``dyngi compare`` end to end on a tiny built-in scene.

Two comparisons are run once per module at 32 x 24, 4 frames, 32-spp
references (cached under a temporary ``$DYNGI_CACHE``):

* equal frames: ``path`` (1 spp) against ``path-b`` (the same tracer
  registered under a second name, 16 spp): every output file, and that more
  samples give a lower error (16 spp: relMSE ~ (1/16 + 1/32) / (1 + 1/32),
  about 0.1 of the 1-spp error; the test asks for < 0.4);
* equal rays: ``path`` (1 spp) against ``path-b`` (4 spp by parameter):
  the budget must bring the second technique down to the first's rays on
  every frame (within 30 %), the first frame included; and on a static
  scene a budgeted progressive technique must still accumulate.

Then input errors (one line, valid choices named, nothing written or
rendered), failures midway (nothing half-written), and the ``dyngi
reference`` / ``dyngi compare`` commands once through a subprocess.
"""
import base64
import csv
import math
import os
import re
import subprocess
import sys

import numpy as np
import pytest

SCENE = "cornell-moving-light"
RES = (32, 24)
FRAMES = 4
REF_SPP = 32
METRICS = ("mse", "relmse", "mape", "flip", "ssim")
DYNGI = [sys.executable, "-m", "dyngi.cli"]


# -- fixtures ---------------------------------------------------------------------

@pytest.fixture(scope="module")
def cache_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("dyngi-cache")


@pytest.fixture(scope="module")
def env(cache_dir, backend):
    """DYNGI_CACHE -> the module's cache; a second name ``path-b`` for the path tracer."""
    from dyngi.techniques.base import REGISTRY, technique_names
    from dyngi.techniques.path import PathTechnique

    class PathB(PathTechnique):
        name = "path-b"
        description = "the path tracer under a second name (tests)"

    technique_names()  # import every technique first
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("DYNGI_CACHE", str(cache_dir))
        mp.setitem(REGISTRY, "path-b", PathB)
        yield cache_dir


def _compare(out, techniques, **kw):
    from dyngi.experiments.compare import run_compare

    args = dict(frames=FRAMES, res=RES, ref_spp=REF_SPP, quiet=True)
    args.update(kw)
    return run_compare(SCENE, techniques, str(out), **args)


@pytest.fixture(scope="module")
def equal_frames(env, tmp_path_factory):
    out = tmp_path_factory.mktemp("cmp") / "equal-frames"
    ret = _compare(out, ["path", "path-b"], params={"path-b.spp": 16})
    assert os.path.abspath(ret) == os.path.abspath(out)
    return out


@pytest.fixture(scope="module")
def equal_rays(env, tmp_path_factory):
    out = tmp_path_factory.mktemp("cmp") / "equal-rays"
    _compare(out, ["path", "path-b"], budget="equal-rays", params={"path-b.spp": 4})
    return out


def _rows(out):
    with open(out / "metrics.csv", newline="") as f:
        return list(csv.DictReader(f))


def _by_tech(rows, tech, key):
    r = sorted((x for x in rows if x["technique"] == tech), key=lambda x: int(x["frame"]))
    return np.array([float(x[key]) for x in r])


def _cache_files(cache_dir):
    d = cache_dir / "reference"
    return sorted(os.listdir(d)) if d.exists() else []


# -- outputs ----------------------------------------------------------------------

def test_metrics_csv_has_every_technique_frame_and_metric(equal_frames):
    rows = _rows(equal_frames)
    assert len(rows) == 2 * FRAMES
    pairs = sorted((r["technique"], int(r["frame"])) for r in rows)
    assert pairs == sorted((t, i) for t in ("path", "path-b") for i in range(FRAMES))
    for col in METRICS + ("time", "wall_ms", "rays", "ms_trace"):
        assert col in rows[0], f"metrics.csv lacks column {col}: {list(rows[0])}"
    for r in rows:
        for col in METRICS + ("time", "wall_ms", "rays"):
            assert math.isfinite(float(r[col])), (col, r)
        assert float(r["mse"]) > 0 and float(r["relmse"]) > 0 and float(r["mape"]) > 0
        assert 0 < float(r["flip"]) <= 1 and -1 <= float(r["ssim"]) < 1
        assert float(r["wall_ms"]) > 0 and int(r["rays"]) >= RES[0] * RES[1]
    # frame times follow the scene's frame rate
    from dyngi.scene import load_scene

    fps = load_scene(SCENE).fps
    np.testing.assert_allclose(_by_tech(rows, "path", "time"), np.arange(FRAMES) / fps)


def test_more_samples_give_lower_error_and_more_rays(equal_frames):
    rows = _rows(equal_frames)
    e1, e16 = _by_tech(rows, "path", "relmse"), _by_tech(rows, "path-b", "relmse")
    assert e16.mean() < 0.4 * e1.mean(), (e1, e16)
    assert _by_tech(rows, "path-b", "mape").mean() < _by_tech(rows, "path", "mape").mean()
    ratio = _by_tech(rows, "path-b", "rays") / _by_tech(rows, "path", "rays")
    np.testing.assert_allclose(ratio, 16.0, rtol=0.1)


def test_summary_md_matches_csv(equal_frames):
    md = (equal_frames / "summary.md").read_text()
    rows = _rows(equal_frames)
    header = next(l for l in md.splitlines() if l.startswith("| technique"))
    cols = [c.strip() for c in header.strip("|").split("|")]
    for tech in ("path", "path-b"):
        line = next((l for l in md.splitlines() if l.startswith(f"| {tech} |")), None)
        assert line is not None, f"no row for {tech} in summary.md:\n{md}"
        cells = dict(zip(cols, (c.strip().strip("*") for c in line.strip("|").split("|"))))
        for key, col in (("relmse", "relMSE"), ("mape", "MAPE"), ("flip", "FLIP")):
            assert float(cells[col]) == pytest.approx(_by_tech(rows, tech, key).mean(), rel=1e-3)
        for col in ("abs(E)", "abs(E')", "ms/frame", "Mrays/frame"):
            assert math.isfinite(float(cells[col]))
        assert f"**{tech}**" in md  # stage times


def test_report_html_is_self_contained_and_embeds_plots(equal_frames):
    page = (equal_frames / "report.html").read_text()
    refs = re.findall(r"""(?:src|href)\s*=\s*["']([^"']*)["']""", page, flags=re.I)
    external = [r for r in refs if not r.startswith("data:") and r != "side_by_side.mp4"]
    assert not external, f"report.html links outside itself: {[e[:80] for e in external]}"
    assert "url(" not in page and "@import" not in page
    pngs = sorted((equal_frames / "plots").glob("*.png")) + sorted(equal_frames.glob("grid_*.png"))
    assert len(pngs) >= 4
    for p in pngs:
        assert base64.b64encode(p.read_bytes()).decode() in page, f"{p.name} is not embedded"
    assert "data:video/mp4;base64," in page
    for tech in ("path", "path-b"):
        assert f"<td>{tech}</td>" in page


def test_video_grids_and_frames_written(equal_frames):
    import imageio.v2 as iio2
    import imageio.v3 as iio

    mp4 = equal_frames / "side_by_side.mp4"
    assert mp4.is_file()
    with iio2.get_reader(str(mp4)) as r:
        frames = [f for f in r]
    assert len(frames) == FRAMES
    assert frames[0].shape[:2] == (RES[1], 3 * RES[0])  # reference + 2 techniques
    for i in (FRAMES // 2, FRAMES - 1):  # default grid frames
        g = iio.imread(equal_frames / f"grid_{i:04d}.png")
        assert g.ndim == 3 and g.shape[0] > 100 and g.std() > 0
    for sub in ("path", "path-b", "reference"):
        for i in range(FRAMES):
            im = iio.imread(equal_frames / sub / f"frame_{i:04d}.png")
            assert im.shape == (RES[1], RES[0], 3) and im.max() > 0
    assert not [p for p in os.listdir(equal_frames.parent) if p.startswith(".dyngi-tmp")]


def test_equal_rays_budget(equal_rays):
    rows = _rows(equal_rays)
    r_first, r_second = _by_tech(rows, "path", "rays"), _by_tech(rows, "path-b", "rays")
    assert np.all(r_first > 0)
    ratio = r_second / r_first
    # without the budget path-b would trace ~4x the rays
    assert np.all(np.abs(ratio - 1.0) < 0.3), f"rays per frame, second / first: {ratio}"


def test_budgeted_technique_accumulates_on_static_frames(env, tmp_path):
    """Equal rays on a static scene: the budgeted copy of ``path`` must accumulate like the first.

    Both trace 1 spp per frame; progressive accumulation brings the 4th
    frame's relMSE to ~(1/4 + 1/32) / (1 + 1/32) of the first's. A budgeted
    technique that is told every frame is new stays at the 1-spp error.
    """
    out = tmp_path / "static"
    from dyngi.experiments.compare import run_compare

    run_compare("cornell-static", ["path", "path-b"], str(out), frames=FRAMES, res=RES, ref_spp=REF_SPP,
                quiet=True, budget="equal-rays", grid_frames=[])
    rows = _rows(out)
    first, second = _by_tech(rows, "path", "relmse"), _by_tech(rows, "path-b", "relmse")
    assert first[-1] < 0.6 * first[0], first
    assert second[-1] < 0.6 * second[0], f"budgeted technique did not accumulate: relMSE {second}"
    assert second.mean() < 1.5 * first.mean(), (first, second)


def test_output_folder_permissions_follow_umask(equal_frames):
    umask = os.umask(0o022)
    os.umask(umask)
    mode = os.stat(equal_frames).st_mode & 0o777
    assert mode == 0o777 & ~umask, f"output folder mode {oct(mode)}, expected {oct(0o777 & ~umask)}"


def test_references_rendered_once(equal_frames, equal_rays, env):
    """Both comparisons share one set of cached references: two independent halves (exr + json) per frame."""
    files = [f for f in _cache_files(env) if f.startswith(SCENE + "-")]
    assert len([f for f in files if f.endswith(".exr")]) == 2 * FRAMES
    assert len([f for f in files if f.endswith(".json")]) == 2 * FRAMES


# -- input errors -----------------------------------------------------------------

@pytest.mark.parametrize("techniques,kw,needles", [
    (["path", "nope"], {}, ["unknown technique 'nope'", "valid techniques:", "path"]),
    (["path", "path"], {}, ["listed twice"]),
    ([], {}, ["no techniques"]),
    (["path"], {"budget": "equal-money"}, ["unknown budget 'equal-money'", "equal-frames", "equal-rays",
                                           "equal-time"]),
    (["path"], {"frames": 0}, [">= 1"]),
    (["path"], {"scene": "no-such-scene"}, ["unknown scene 'no-such-scene'", "cornell-moving-light"]),
    (["path"], {"params": {"bogus": 1}}, ["'bogus'", "spp", "max_depth"]),
    (["path"], {"params": {"path.bogus": 1}}, ["unknown parameter 'bogus'", "valid parameters:", "spp"]),
    (["path"], {"params": {"ddgi.spp": 1}}, ["'ddgi'", "compared techniques: path"]),
    (["path"], {"params": {"path.spp": 0}}, ["'spp'", "minimum"]),
    (["path"], {"params": {"path.mis": "nope"}}, ["valid values: power, balance"]),
])
def test_bad_input_raises_before_any_work(env, tmp_path, techniques, kw, needles):
    from dyngi.errors import DyngiError
    from dyngi.experiments.compare import run_compare

    before = _cache_files(env)
    out = tmp_path / "o"
    kw = dict(kw)
    scene = kw.pop("scene", SCENE)
    args = dict(frames=2, res=(8, 6), ref_spp=4, quiet=True)
    args.update(kw)
    with pytest.raises(DyngiError) as e:
        run_compare(scene, techniques, str(out), **args)
    msg = str(e.value)
    assert "\n" not in msg
    for n in needles:
        assert n in msg, f"{n!r} not in {msg!r}"
    assert not out.exists() and os.listdir(tmp_path) == []
    assert _cache_files(env) == before, "a reference was rendered before the input was checked"


# -- failures midway ----------------------------------------------------------------

def test_technique_failing_on_frame_2_leaves_nothing(env, tmp_path, monkeypatch):
    from dyngi.errors import DyngiError
    from dyngi.techniques.path import PathTechnique

    orig = PathTechnique.step
    seen = []

    def failing(self, frame):
        seen.append(frame.index)
        if frame.index == 2:
            raise DyngiError("boom on frame 2")
        return orig(self, frame)

    monkeypatch.setattr(PathTechnique, "step", failing)
    out = tmp_path / "o"
    with pytest.raises(DyngiError, match="boom on frame 2"):
        _compare(out, ["path"], frames=3)
    assert seen == [0, 1, 2]
    assert not out.exists()
    assert os.listdir(tmp_path) == [], os.listdir(tmp_path)


def test_failure_while_writing_keeps_old_output_and_no_temp(env, tmp_path, monkeypatch):
    """The last output step fails: nothing of the new outputs appears, old files stay."""
    from dyngi.experiments import report as cmod

    def broken(*a, **k):
        raise OSError("disk full (simulated)")

    monkeypatch.setattr(cmod, "_report_html", broken)
    out = tmp_path / "keep"
    out.mkdir()
    (out / "old.txt").write_text("precious")
    with pytest.raises(OSError, match="simulated"):
        _compare(out, ["path"], frames=2, grid_frames=[])
    assert sorted(os.listdir(out)) == ["old.txt"]
    assert (out / "old.txt").read_text() == "precious"
    assert sorted(os.listdir(tmp_path)) == ["keep"]


def test_single_frame_has_no_video(env, tmp_path):
    out = tmp_path / "one"
    _compare(out, ["path"], frames=1)
    names = set(os.listdir(out))
    assert {"metrics.csv", "summary.md", "report.html", "grid_0000.png"} <= names
    assert "side_by_side.mp4" not in names
    assert len(_rows(out)) == 1


# -- command line -------------------------------------------------------------------

def _cli(*args, cache):
    e = dict(os.environ, DYNGI_CACHE=str(cache))
    return subprocess.run(DYNGI + list(args), capture_output=True, text=True, env=e, timeout=300)


def test_cli_reference_then_compare(tmp_path):
    """``dyngi reference`` fills exactly the cache that ``dyngi compare`` then reads."""
    cache = tmp_path / "cache"
    r = _cli("reference", SCENE, "--frames", "2", "--res", "32x24", "--spp", "8", "--quiet", cache=cache)
    assert r.returncode == 0, r.stderr
    assert "2 frame(s)" in r.stdout and "0 already cached" in r.stdout, r.stdout
    filled = _cache_files(cache)
    assert len([f for f in filled if f.endswith(".exr")]) == 4   # two independent halves per frame

    out = tmp_path / "cmp"
    r = _cli("compare", SCENE, "--techniques", "path", "--frames", "2", "--res", "32x24", "--ref-spp", "8",
             "--set", "path.spp=2", "--out", str(out), "--quiet", cache=cache)
    assert r.returncode == 0, r.stderr
    assert "report.html" in r.stdout
    assert _cache_files(cache) == filled, "compare rendered references that 'dyngi reference' had cached"
    rows = _rows(out)
    assert len(rows) == 2 and all(int(x["rays"]) >= 2 * 32 * 24 for x in rows)
    assert (out / "report.html").is_file() and (out / "side_by_side.mp4").is_file()

    r = _cli("compare", SCENE, "--techniques", "path,nope", "--out", str(tmp_path / "bad"), cache=cache)
    lines = [l for l in r.stderr.strip().splitlines() if l.strip()]
    assert r.returncode == 2 and len(lines) == 1 and "Traceback" not in r.stderr, r.stderr
    assert "unknown technique 'nope'" in lines[0] and "valid techniques:" in lines[0]
    assert not (tmp_path / "bad").exists()


def test_cost_figures_exclude_the_first_frame(env, tmp_path):
    """ddgi's first frame runs 8 warm-up probe updates: Mrays/frame and ms/frame are steady-state means."""
    import json
    out = tmp_path / "ddgi"
    _compare(out, ["ddgi"], frames=3, params={"ddgi.probe_counts": "4"}, grid_frames=[])
    rays = _by_tech(_rows(out), "ddgi", "rays")
    assert rays[0] > 2 * rays[1:].max()         # the warm-up frame really differs
    summary = json.loads((out / "summary.json").read_text())
    s = summary["techniques"]["ddgi"]
    assert s["rays_per_frame"] == pytest.approx(rays[1:].mean(), rel=1e-6)
    md = (out / "summary.md").read_text()
    header = next(l for l in md.splitlines() if l.startswith("| technique"))
    cols = [c.strip() for c in header.strip("|").split("|")]
    line = next(l for l in md.splitlines() if l.startswith("| ddgi |"))
    cells = dict(zip(cols, (c.strip().strip("*") for c in line.strip("|").split("|"))))
    assert float(cells["Mrays/frame"]) == pytest.approx(rays[1:].mean() / 1e6, rel=1e-2)
    assert cells["NaN/Inf px"] == "0"

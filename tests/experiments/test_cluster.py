"""Executors, chunked references, the shared-cache lock and sweeps, without Ray (the fast suite).

The Ray back-end itself is tested in test_cluster_ray.py (slow, skipped without the extra). Here: the
local executor's retry/failure semantics, chunks merged by sample count equal to the serial render, the
lock of the reference cache with threads and processes, grid parsing, a tiny sweep, and the cluster code
path of compare/sweep run in-process (an executor that pretends to be remote) giving the same numbers.
"""
import json
import multiprocessing
import os
import sys
import threading
import time

import numpy as np
import pytest

from dyngi.errors import DyngiError

RES = (16, 12)


@pytest.fixture
def ref(backend):
    from dyngi.experiments.references import path

    return path


def _reference_job(*args, **kwargs):
    from dyngi.experiments.reference_job import reference_job

    return reference_job(*args, **kwargs)


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("DYNGI_CACHE", str(tmp_path / "cache"))
    return tmp_path / "cache" / "reference"


def _scene(name="cornell-moving-light"):
    from dyngi.scene import make_builtin

    return make_builtin(name)


class Pretend(object):
    """An executor that runs in this process but takes the cluster code path (SceneRefs, no live objects)."""

    @staticmethod
    def make(workers=2, retries=1):
        from dyngi.experiments.cluster import LocalExecutor

        class _P(LocalExecutor):
            kind = "pretend"
            in_process = False

        ex = _P(retries=retries, fail_fast=False)
        ex.workers = workers
        return ex


# -- executor semantics -------------------------------------------------------------------------------

_CALLS = {}


def _flaky(name, fail_times, value):
    n = _CALLS.get(name, 0) + 1
    _CALLS[name] = n
    if n <= fail_times:
        raise RuntimeError(f"{name} broke on attempt {n}")
    return value


def _bad_input():
    raise DyngiError("bad input")


def test_local_executor_retries_reports_by_name_and_finishes_the_rest(backend):
    from dyngi.experiments.cluster import LocalExecutor, Progress, Task, TaskFailure, failed

    _CALLS.clear()
    ex = LocalExecutor(retries=2, fail_fast=False)
    prog = Progress(4, quiet=True)
    done = []
    out = ex.map([Task("ok", _flaky, ("ok", 0, 1)), Task("flaky", _flaky, ("flaky", 2, 2)),
                  Task("broken", _flaky, ("broken", 99, 3)), Task("user", _bad_input)],
                 on_done=lambda i, v: done.append(i), progress=prog)
    assert out[0] == 1 and out[1] == 2                           # retried twice, then fine
    assert failed(out[2]) and isinstance(out[2], TaskFailure)
    assert out[2].name == "broken" and out[2].attempts == 3 and "RuntimeError: broken broke" in out[2].error
    assert failed(out[3]) and out[3].attempts == 1 and "DyngiError: bad input" in out[3].error  # not retried
    assert done == [0, 1] and [f.name for f in ex.failures] == ["broken", "user"]
    assert ex.retried == {"flaky": 3, "broken": 3}
    assert (prog.done, prog.failures, prog.retries) == (4, 2, 4)
    # the default (--cluster local): the first error propagates unchanged, as before executors
    with pytest.raises(RuntimeError, match="broke"):
        LocalExecutor().map([Task("again", _flaky, ("again", 1, 0))])


def test_cluster_choice_env_var_and_missing_ray(monkeypatch):
    from dyngi.experiments import cluster

    monkeypatch.delenv(cluster.CLUSTER_ENV, raising=False)
    assert cluster.resolve_cluster(None) == "local"
    assert cluster.resolve_cluster("ray://head:10001") == "ray://head:10001"
    monkeypatch.setenv(cluster.CLUSTER_ENV, "auto")
    assert cluster.resolve_cluster(None) == "auto" and cluster.resolve_cluster("local") == "local"
    monkeypatch.setenv(cluster.CLUSTER_ENV, "bogus")
    with pytest.raises(DyngiError, match=r"\$DYNGI_CLUSTER 'bogus' is invalid.*ray://HOST:PORT"):
        cluster.resolve_cluster(None)
    for bad in ("ray://head", "http://x:1", "remote"):
        with pytest.raises(DyngiError, match="--cluster"):
            cluster.resolve_cluster(bad)
    assert isinstance(cluster.make_executor("local"), cluster.LocalExecutor)
    monkeypatch.setitem(sys.modules, "ray", None)           # as if the extra were not installed
    with pytest.raises(DyngiError, match=r"needs Ray, an optional extra of dyngi: pip install 'dyngi\[ray\]'"):
        cluster.make_executor("auto")


# -- chunks ---------------------------------------------------------------------------------------------

def test_chunk_ranges_cover_every_pass_once(ref):
    assert ref._passes((16, 12), 1024) == [64] * 16       # MAX_SPP_PER_PASS: a frame splits into 16 chunks
    for spp, k in ((1024, 4), (1000, 3), (64, 8), (130, 16), (5, 1)):
        r = ref.chunk_ranges((16, 12), spp, k)
        n = len(ref._passes((16, 12), spp))
        assert len(r) == min(k, n) and r[0][0] == 0 and r[-1][1] == n
        assert all(a < b for a, b in r) and all(r[i][1] == r[i + 1][0] for i in range(len(r) - 1))


def test_chunks_merged_on_the_local_executor_equal_the_serial_render(ref, tmp_path):
    from dyngi.experiments.cluster import LocalExecutor, Progress

    sc = _scene()
    spp = 512            # 8 passes of 64: halves of 256 = 4 passes each, so 4 chunks per half
    prog = Progress(0, quiet=True)
    recs = _reference_job(sc, [0, 3], RES, spp, 12, executor=LocalExecutor(), chunks=4, cache_dir=tmp_path,
                             progress=prog)
    assert [r["frame"] for r in recs] == [0, 3] and not any(r["cached"] or r["failed"] for r in recs)
    assert prog.done == prog.total == 2 * 2 * 4            # 2 frames x 2 halves x 4 chunks
    for r in recs:
        for n, seed in zip(ref.half_spp(spp), (0, 1)):
            serial = ref._render(sc, r["time"], RES, n, 12, seed)
            cached, hit = ref.cached_reference(sc, r["time"], RES, n, 12, tmp_path, seed)
            assert hit and np.array_equal(serial, cached)
    meta = json.loads(next(p for p in tmp_path.iterdir() if p.suffix == ".json").read_text())
    assert meta["chunks"] == 4 and meta["spp"] == 256
    # no lock files left; a second run renders nothing
    assert not [p for p in tmp_path.iterdir() if ".lock" in p.name]
    again = _reference_job(sc, [0, 3], RES, spp, 12, executor=LocalExecutor(), chunks=4, cache_dir=tmp_path)
    assert all(r["cached"] for r in again)


def test_reference_job_on_the_cluster_path_renders_missing_entries_once(ref, tmp_path):
    """Static scene: every frame has the same key, so one entry per half is rendered, as chunks."""
    ex = Pretend.make(workers=4)
    recs = _reference_job(_scene("cornell-static"), 3, RES, 256, 12, executor=ex, cache_dir=tmp_path)
    assert len({r["key"] for r in recs}) == 1 and not any(r["failed"] for r in recs)
    assert len([p for p in tmp_path.iterdir() if p.suffix == ".exr"]) == 2
    meta = [json.loads(p.read_text()) for p in tmp_path.iterdir() if p.suffix == ".json"]
    assert sorted(m["chunks"] for m in meta) == [2, 2]      # auto: 2 tasks per worker over 2 entries, <= passes


# -- the shared-cache lock ---------------------------------------------------------------------------------

def test_threads_asking_for_one_missing_entry_render_it_once(ref, tmp_path, monkeypatch):
    calls = []
    real = ref._render

    def slow(*a):
        calls.append(a)
        time.sleep(0.5)             # long enough for every thread to find the entry missing
        return real(*a)
    monkeypatch.setattr(ref, "_render", slow)
    sc = [_scene("cornell-static") for _ in range(4)]
    out = [None] * 4

    def ask(i):
        out[i] = ref.cached_reference(sc[i], 0.0, RES, 8, 12, tmp_path, 0)
    ts = [threading.Thread(target=ask, args=(i,)) for i in range(4)]
    for t in ts:
        t.start()
    for t in ts:
        t.join()
    assert len(calls) == 1
    assert sum(not hit for _, hit in out) == 1 and all(np.array_equal(out[0][0], o[0]) for o in out)
    assert sorted(p.suffix for p in tmp_path.iterdir()) == [".exr", ".json"]    # lock removed


def _hold_lock(path, ready, release):
    from pathlib import Path

    from dyngi.experiments.references.cache import EntryLock

    lock = EntryLock(Path(path))
    ready.put(lock.acquire())
    release.wait(30)
    lock.release()


def test_lock_between_processes_and_a_dead_holder(ref, tmp_path):
    from dyngi.experiments.references.cache import EntryLock, lock_is_stale

    exr = tmp_path / "scene-key.exr"
    ctx = multiprocessing.get_context("fork")
    ready, release = ctx.Queue(), ctx.Event()
    p = ctx.Process(target=_hold_lock, args=(str(exr), ready, release))
    p.start()
    assert ready.get(timeout=30) is True
    mine = EntryLock(exr)
    assert not mine.acquire() and not mine.stale()         # held by a live process
    release.set()
    p.join(30)
    assert not (tmp_path / "scene-key.lock").exists()      # released by its holder
    assert mine.acquire()
    mine.release()
    # a holder that died without releasing: stale at once on this host, broken by the next one
    ready2, never = ctx.Queue(), ctx.Event()
    p = ctx.Process(target=_hold_lock, args=(str(exr), ready2, never))
    p.start()
    assert ready2.get(timeout=30) is True
    p.kill()
    p.join(30)
    lock_path = tmp_path / "scene-key.lock"
    assert lock_path.exists() and lock_is_stale(lock_path)
    assert mine.break_if_stale() and mine.acquire()
    mine.release()


def test_lock_from_another_machine_is_stale_only_after_its_heartbeat_stops(ref, tmp_path, monkeypatch):
    from dyngi.experiments.references.cache import EntryLock, get_or_render, lock_is_stale

    exr, js = tmp_path / "s-k.exr", tmp_path / "s-k.json"
    lock = tmp_path / "s-k.lock"
    lock.write_text(json.dumps({"host": "another-machine", "pid": 1, "token": "x"}))
    assert not lock_is_stale(lock) and not EntryLock(exr).acquire()
    monkeypatch.setenv("DYNGI_LOCK_STALE", "0.5")
    old = time.time() - 5
    os.utime(lock, (old, old))                          # its holder stopped refreshing it 5 s ago
    assert lock_is_stale(lock)
    img = np.full((RES[1], RES[0], 3), 0.25, np.float32)
    (got, meta), hit = get_or_render(exr, js, "k", RES, lambda: (img, {"key": "k"}))
    assert not hit and np.array_equal(got, img) and not lock.exists()
    (again, _), hit = get_or_render(exr, js, "k", RES, lambda: pytest.fail("rendered twice"))
    assert hit and np.array_equal(again, img)


def test_readers_never_see_a_half_written_entry(ref, tmp_path):
    """The EXR and JSON are moved into place whole (JSON last); an EXR alone, or a temporary file, is a miss."""
    exr, js = tmp_path / "s-k.exr", tmp_path / "s-k.json"
    from dyngi.experiments.references.cache import _load_entry, _store

    img = np.full((RES[1], RES[0], 3), 0.5, np.float32)
    _store(exr, js, img, {"key": "k"})
    assert not [p for p in tmp_path.iterdir() if ".tmp" in p.name]
    assert np.array_equal(_load_entry(exr, js, "k", RES)[0], img)
    js.unlink()
    (tmp_path / ".s-k.123.abcd.tmp.json").write_text('{"key": "k"}')     # a writer still busy
    assert _load_entry(exr, js, "k", RES) is None
    js.write_text('{"key": "other"}')                                      # another entry's sidecar
    assert _load_entry(exr, js, "k", RES) is None


# -- sweeps ------------------------------------------------------------------------------------------------

def test_grid_parsing_and_its_errors(backend):
    from dyngi.experiments.sweep import grid_points, parse_grid, point_label

    g = parse_grid(["hysteresis=0.9, 0.97", "rays_per_probe=64,256", "direct=nee,sky"], "ddgi")
    assert g == {"hysteresis": [0.9, 0.97], "rays_per_probe": [64, 256], "direct": ["nee", "sky"]}
    pts = grid_points(g)
    assert len(pts) == 8 and pts[0] == {"hysteresis": 0.9, "rays_per_probe": 64, "direct": "nee"}
    assert pts[1]["direct"] == "sky" and pts[-1] == {"hysteresis": 0.97, "rays_per_probe": 256, "direct": "sky"}
    assert point_label("ddgi", pts[0]) == "ddgi:hysteresis=0.9:rays_per_probe=64:direct=nee"
    bad = [([], "no --grid given.*valid parameters:.*hysteresis"),
           (["hysteresis"], "expects KEY=V1,V2"),
           (["=1,2"], "no parameter name"),
           (["foo=1,2"], "unknown parameter 'foo' for technique 'ddgi'; valid parameters:.*rays_per_probe"),
           (["hysteresis=0.9", "hysteresis=0.8"], "names 'hysteresis' twice"),
           (["hysteresis="], "empty value"),
           (["hysteresis=0.9,,0.8"], "empty value"),
           (["hysteresis=0.9,1.5"], "hysteresis.*above its maximum"),
           (["rays_per_probe=64,many"], "rays_per_probe.*must be of type int"),
           (["hysteresis=0.9,0.90"], "lists the value 0.9 twice")]
    for items, msg in bad:
        with pytest.raises(DyngiError, match=msg):
            parse_grid(items, "ddgi")
    with pytest.raises(DyngiError, match="both swept .--grid. and fixed .--set."):
        parse_grid(["hysteresis=0.9,0.8"], "ddgi", fixed={"hysteresis": "0.5"})
    with pytest.raises(DyngiError, match="unknown technique"):
        parse_grid(["x=1"], "nope")


SWEEP = dict(frames=2, res=(16, 12), ref_spp=16, metrics=["mse", "relmse"])


def test_sweep_writes_one_report_with_every_point_and_seed(backend, cache, tmp_path):
    from dyngi.experiments.sweep import run_sweep

    out = run_sweep("path", "cornell-moving-light", ["spp=1,2", "max_depth=3,12"], 2, str(tmp_path / "sw"),
                    **SWEEP)
    s = json.loads(open(os.path.join(out, "summary.json")).read())
    assert s["grid"] == {"spp": [1, 2], "max_depth": [3, 12]} and s["seeds"] == 2
    assert len(s["points"]) == 4 and all(len(p["seeds"]) == 2 for p in s["points"]) and not s["failures"]
    p0 = s["points"][0]
    assert p0["params"] == {"spp": 1, "max_depth": 3}
    assert [x["seed"] for x in p0["seeds"]] == [0, 1] and p0["seeds"][0]["mean"]["relmse"] > 0
    assert p0["seeds"][0]["mean"] != p0["seeds"][1]["mean"]               # the seed changes the run
    assert np.isclose(p0["metrics"]["relmse"]["mean"], np.mean([x["mean"]["relmse"] for x in p0["seeds"]]))
    assert p0["ms_per_frame"]["n"] == 2 and all(x["ms_per_frame"] > 0 for x in p0["seeds"])
    best = min(s["points"], key=lambda p: p["metrics"]["mse"]["mean"])
    assert s["best"]["mse"]["params"] == best["params"] and set(s["best"]) >= {"mse", "relmse", "ms_per_frame"}
    assert s["points"][3]["metrics"]["relmse"]["mean"] < s["points"][0]["metrics"]["relmse"]["mean"]
    for f in ("report.html", "summary.md", "metrics.csv", "plots/error_vs_spp.png", "plots/error_vs_max_depth.png"):
        assert os.path.getsize(os.path.join(out, f)) > 100, f
    html = open(os.path.join(out, "report.html")).read()
    assert "Best settings" in html and html.count("data:image/png;base64,") == 2
    rows = open(os.path.join(out, "metrics.csv")).read().splitlines()
    assert rows[0].startswith("spp,max_depth,seed,frame,mse,relmse") and len(rows) == 1 + 4 * 2 * 2


def test_sweep_on_the_cluster_path_gives_the_same_numbers(backend, cache, tmp_path):
    """Tasks that load the scene and make the technique themselves (what a Ray worker does) measure what
    the in-process run measures; the references were rendered as chunk tasks first."""
    from dyngi.experiments.sweep import run_sweep

    grid = ["spp=1,2"]
    a = run_sweep("path", "cornell-moving-light", grid, 2, str(tmp_path / "a"), **SWEEP)
    ex = Pretend.make(workers=2)
    b = run_sweep("path", "cornell-moving-light", grid, 2, str(tmp_path / "b"), executor=ex, **SWEEP)
    sa, sb = (json.loads(open(os.path.join(d, "summary.json")).read()) for d in (a, b))
    assert sb["cluster"]["kind"] == "pretend" and not ex.failures
    for pa, pb in zip(sa["points"], sb["points"]):
        for xa, xb in zip(pa["seeds"], pb["seeds"]):
            assert xa["mean"] == xb["mean"] and xa["E"] == xb["E"]


def test_compare_on_the_cluster_path_gives_the_same_numbers_and_survives_a_failure(backend, cache, tmp_path,
                                                                                    monkeypatch):
    from dyngi.experiments import cluster, compare

    kw = dict(frames=2, res=(16, 12), ref_spp=16, metrics=["mse", "relmse"], tracked=False)
    a = compare.run_compare("cornell-moving-light", ["path:spp=2", "path"], str(tmp_path / "a"), **kw)
    real = compare._sequence_task

    def sometimes(source, label, *rest):
        if label == "path:max_depth=3":
            raise RuntimeError("worker lost")
        return real(source, label, *rest)
    monkeypatch.setattr(compare, "_sequence_task", sometimes)
    ex = Pretend.make(workers=2, retries=1)
    with cluster.use(ex):
        b = compare.run_compare("cornell-moving-light", ["path:spp=2", "path", "path:max_depth=3"],
                                str(tmp_path / "b"), budget="equal-rays", **kw)
    sa, sb = (json.loads(open(os.path.join(d, "summary.json")).read())["techniques"] for d in (a, b))
    assert sa["path:spp=2"]["mean"] == sb["path:spp=2"]["mean"]     # the budget setter: its own settings
    assert set(sb) == {"path:spp=2", "path"}               # the failed one is left out, the rest written
    assert sb["path"]["budget_accounting"]["what"] == "rays"
    assert [f.name for f in ex.failures] == ["path:max_depth=3 on cornell-moving-light (seed 0)"]
    assert ex.failures[0].attempts == 2 and "worker lost" in ex.failures[0].error
    md = open(os.path.join(b, "summary.md")).read()
    assert "failed and left out: path:max_depth=3" in md


def test_sweep_cli_errors_are_one_line(backend, tmp_path, capsys):
    from dyngi.cli import main

    for argv, msg in ((["sweep", "ddgi", "cornell-static", "--grid", "hysteresis=2"], "above its maximum"),
                      (["sweep", "ddgi", "cornell-static"], "no --grid given"),
                      (["sweep", "nope", "cornell-static", "--grid", "a=1"], "unknown technique"),
                      (["sweep", "ddgi", "cornell-static", "--grid", "hysteresis=0.9", "--cluster", "x"],
                       "--cluster 'x' is invalid"),
                      (["sweep", "ddgi", "cornell-static", "--grid", "hysteresis=0.9", "--seeds", "0"],
                       "--seeds must be >= 1")):
        try:
            rc = main(argv + ["--out", str(tmp_path / "o")])
        except SystemExit as e:         # argparse's own checks exit
            rc = e.code
        assert rc == 2
        err = capsys.readouterr().err.strip()
        assert err.startswith("dyngi: error:") and msg in err and "\n" not in err, err


def test_scene_ref_carries_the_scene_options_to_a_worker(monkeypatch):
    """A worker loads the scene with the options in force where the job was made (--fps, --animation), not
    with its own environment: the reference is made inside scene_options and loaded outside it."""
    from dyngi.experiments.cluster import scene_ref
    from dyngi.scene.loaders import OPTIONS_ENV, scene_options

    monkeypatch.delenv(OPTIONS_ENV, raising=False)
    with scene_options(fps=7.5):
        ref = scene_ref("cornell-moving-light")
    assert os.environ.get(OPTIONS_ENV) is None
    assert ref.load().fps == 7.5
    assert scene_ref("cornell-moving-light").load().fps != 7.5

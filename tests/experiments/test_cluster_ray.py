"""The Ray back-end (slow; one local Ray cluster for the whole test session; skipped without the extra).

A reference rendered as 4 chunks on the cluster equals the serial one bit for bit; a sweep (2 keys x 2
values x 2 seeds) gives the numbers of each point run serially; a worker killed mid-job loses no finished
frame and the job completes (its task retried); a second run of the same job renders nothing new.
"""
import json
import os
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

ray = pytest.importorskip("ray", reason="Ray is an optional extra: pip install 'dyngi[ray]'")

pytestmark = pytest.mark.slow
CPUS = 2


@pytest.fixture(scope="session")
def ray_cluster(tmp_path_factory):
    """One local Ray instance (2 CPUs: this machine's cores) for every test of the session."""
    import logging

    started = False
    if not ray.is_initialized():
        ray.init(num_cpus=CPUS, include_dashboard=False, logging_level=logging.WARNING, log_to_driver=False)
        started = True
    yield ray
    if started:
        ray.shutdown()


@pytest.fixture
def executor(ray_cluster, backend):
    from dyngi.experiments.cluster import RayExecutor

    ex = RayExecutor("auto", retries=2)      # attaches to the session's cluster (close() leaves it running)
    yield ex
    ex.close()


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("DYNGI_CACHE", str(tmp_path / "cache"))
    return tmp_path / "cache" / "reference"


def _scene(name="cornell-moving-light"):
    from dyngi.scene import make_builtin

    return make_builtin(name)


def test_reference_in_four_chunks_on_the_cluster_equals_the_serial_one(executor, cache):
    from dyngi.experiments.reference_job import reference_job
    from dyngi.experiments.references import path as ref
    from dyngi.experiments.cluster import Progress

    sc, res, spp = _scene(), (32, 24), 512
    prog = Progress(0, quiet=True)
    recs = reference_job(sc, [2], res, spp, 12, executor=executor, halves=False, seed=7, chunks=4,
                             progress=prog)
    assert prog.done == 4 and not executor.failures and not recs[0]["failed"]
    img, hit = ref.cached_reference(sc, recs[0]["time"], res, spp, 12, seed=7)
    assert hit and json.loads(open(recs[0]["path"][:-4] + ".json").read())["chunks"] == 4
    serial = ref._render(_scene(), recs[0]["time"], res, spp, 12, 7)
    assert np.array_equal(img, serial)


def test_sweep_on_the_cluster_gives_the_serial_numbers_and_a_second_run_renders_nothing(executor, cache, tmp_path,
                                                                                        monkeypatch):
    from dyngi.experiments import reference_job as job
    from dyngi.experiments.cluster import SceneRef
    from dyngi.experiments.references import path as ref
    from dyngi.experiments.sweep import run_sweep, sweep_point

    grid = ["hysteresis=0.9,0.97", "rays_per_probe=16,32"]
    kw = dict(frames=3, res=(24, 16), ref_spp=32, metrics=["mse", "relmse", "mape"])
    out = run_sweep("ddgi", "cornell-moving-light", grid, 2, str(tmp_path / "a"), executor=executor, **kw)
    s = json.loads(open(os.path.join(out, "summary.json")).read())
    assert s["cluster"]["kind"] == "ray" and s["cluster"]["workers"] == CPUS and not s["failures"]
    assert len(s["points"]) == 4 and all(len(p["seeds"]) == 2 for p in s["points"])
    depth = s["ref_depth"]
    for p in s["points"]:                  # each point and seed run serially, in this process
        for x in p["seeds"]:
            r = sweep_point(SceneRef("cornell-moving-light"), "ddgi", p["params"], kw["frames"], kw["res"],
                            x["seed"], kw["ref_spp"], depth, kw["metrics"])
            assert r["mean"] == x["mean"] and r["E"] == x["E"] and r["E_prime"] == x["E_prime"], p["label"]
    # the same job again: every reference is a cache hit, nothing is rendered (here or on a worker)
    calls = []
    monkeypatch.setattr(ref, "_render", lambda *a: calls.append(a))
    monkeypatch.setattr(ref, "render_passes", lambda *a, **k: calls.append(a))
    monkeypatch.setattr(job, "_render", lambda *a: calls.append(a))
    monkeypatch.setattr(job, "render_passes", lambda *a, **k: calls.append(a))
    recs = job.reference_job(_scene(), kw["frames"], kw["res"], kw["ref_spp"], depth, executor=executor)
    assert all(r["cached"] for r in recs) and not calls
    before = sorted(p.stat().st_mtime_ns for p in cache.iterdir())
    out2 = run_sweep("ddgi", "cornell-moving-light", grid, 2, str(tmp_path / "b"), executor=executor, **kw)
    s2 = json.loads(open(os.path.join(out2, "summary.json")).read())
    assert [p["metrics"]["relmse"]["mean"] for p in s2["points"]] == [p["metrics"]["relmse"]["mean"]
                                                                      for p in s["points"]]
    assert sorted(p.stat().st_mtime_ns for p in cache.iterdir()) == before


def _busy_workers(prefix: str) -> list[int]:
    """Pids of Ray worker processes running a task whose name starts with ``prefix`` (their process title
    is ``ray::<task name>`` while they run it)."""
    out = []
    for pid in os.listdir("/proc"):
        if not pid.isdigit():
            continue
        try:
            with open(f"/proc/{pid}/cmdline", "rb") as f:
                title = f.read().split(b"\0")[0].decode(errors="replace")
        except OSError:
            continue
        if title.startswith("ray::" + prefix):
            out.append(int(pid))
    return out


def test_a_killed_worker_loses_no_finished_frame_and_the_job_completes(executor, cache):
    from dyngi.experiments.reference_job import reference_job
    from dyngi.experiments.references import path as ref

    sc, res, spp, frames = _scene(), (64, 48), 256, 6
    box = {}

    def run():
        box["recs"] = reference_job(sc, frames, res, spp, 12, executor=executor, chunks=1)
    job = threading.Thread(target=run)
    job.start()
    killed, finished_at_kill = None, {}
    deadline = time.time() + 300
    while job.is_alive() and time.time() < deadline:
        done = {p: p.stat().st_mtime_ns for p in cache.glob("*.json")} if cache.exists() else {}
        busy = _busy_workers("reference_cornell")
        if done and busy:               # at least one frame finished, another being rendered: kill its worker
            finished_at_kill = done
            killed = busy[0]
            os.kill(killed, 9)
            break
        time.sleep(0.05)
    job.join(300)
    assert killed is not None, "no worker was caught mid-task"
    recs = box["recs"]
    assert not executor.failures and not any(r["failed"] for r in recs)
    assert executor.retried and max(executor.retried.values()) == 2          # the killed task, tried again
    entries = {p: p.stat().st_mtime_ns for p in cache.glob("*.json")}
    assert len(entries) == 2 * frames                                          # every half of every frame
    for p, t in finished_at_kill.items():
        assert entries[p] == t, f"{p.name} was rendered again"                 # nothing finished was lost
    for r in recs:
        img, hit = ref.cached_reference(sc, r["time"], res, spp // 2, 12, seed=0)
        assert hit and np.all(np.isfinite(img))


def test_cli_sweep_with_cluster_auto_uses_the_running_cluster(ray_cluster, cache, tmp_path):
    """The new-user command, small: 'auto' finds the session's cluster; the report opens (is written)."""
    env = dict(os.environ, DYNGI_CACHE=str(cache.parent))
    r = subprocess.run([sys.executable, "-m", "dyngi", "sweep", "ddgi", "cornell-moving-light",
                        "--grid", "hysteresis=0.9,0.97", "--grid", "rays_per_probe=16,32", "--seeds", "2",
                        "--frames", "2", "--res", "16x12", "--ref-spp", "16", "--metrics", "relmse",
                        "--cluster", "auto", "--quiet", "--out", str(tmp_path / "sw")],
                       capture_output=True, text=True, env=env, timeout=600)
    assert r.returncode == 0, r.stderr
    assert "report.html" in r.stdout
    s = json.loads((tmp_path / "sw" / "summary.json").read_text())
    assert s["cluster"]["kind"] == "ray" and not s["cluster"]["started_here"] and len(s["points"]) == 4
    assert (tmp_path / "sw" / "report.html").stat().st_size > 1000


def test_compare_on_the_cluster_equals_the_local_run(executor, cache, tmp_path):
    """Sequences come back from the workers (images writable: the report writes them as EXR) with the
    numbers of the in-process run."""
    from dyngi.experiments import cluster
    from dyngi.experiments.compare import run_compare

    kw = dict(frames=3, res=(24, 16), ref_spp=32, metrics=["mse", "relmse"], tracked=False)
    a = run_compare("cornell-moving-light", ["ddgi", "path"], str(tmp_path / "a"), **kw)
    with cluster.use(executor):
        b = run_compare("cornell-moving-light", ["ddgi", "path"], str(tmp_path / "b"), **kw)
    sa, sb = (json.loads(open(os.path.join(d, "summary.json")).read())["techniques"] for d in (a, b))
    for t in ("ddgi", "path"):
        assert sa[t]["mean"] == sb[t]["mean"] and sa[t]["E"] == sb[t]["E"], t
    assert os.path.getsize(os.path.join(b, "ddgi", "frame_0002.exr")) > 0 and not executor.failures


def test_cli_reference_on_the_cluster_fills_the_cache_a_second_run_hits_it(ray_cluster, cache, tmp_path):
    env = dict(os.environ, DYNGI_CACHE=str(cache.parent))
    cmd = [sys.executable, "-m", "dyngi", "reference", "cornell-moving-light", "--frames", "2", "--spp", "256",
           "--res", "16x12", "--chunks", "2", "--cluster", "auto", "--quiet"]
    r = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=600)
    assert r.returncode == 0, r.stderr
    assert "holds 2 of 2 frame(s)" in r.stdout and "(0 already cached)" in r.stdout
    metas = [json.loads(p.read_text()) for p in cache.glob("*.json")]
    assert len(metas) == 4 and all(m["chunks"] == 2 for m in metas)
    r = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=600)
    assert r.returncode == 0 and "(2 already cached)" in r.stdout, r.stderr

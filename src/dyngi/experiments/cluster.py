"""Executors: run a job's independent tasks in-process or on a Ray cluster, behind one interface.

A *job* is a list of :class:`Task` s (a name, a module-level function and its arguments) whose results
do not depend on one another: the frames or spp chunks of a reference (:mod:`~dyngi.experiments.reference_job`),
the technique sequences of a comparison (:mod:`~dyngi.experiments.compare`), the grid points x seeds of a
sweep (:mod:`~dyngi.experiments.sweep`), the independent runs of a reproduction
(:mod:`~dyngi.experiments.reproduce`). :meth:`Executor.map` runs them and returns one outcome per task,
in order: the task's return value, or a :class:`TaskFailure` (its name, its error, the attempts).

Back-ends (``--cluster`` on ``reference``, ``compare``, ``sweep``, ``reproduce``; else ``$DYNGI_CLUSTER``):

``local``          (default) :class:`LocalExecutor`: the tasks run one after another in this process, on
                   every core, exactly as before executors existed; the first error ends the job as it
                   always did (``fail_fast``; no retries).
``auto``           :class:`RayExecutor` on the Ray cluster this process is attached to or can find
                   (``ray.init(address="auto")``: ``$RAY_ADDRESS`` or a cluster started on this machine
                   with ``ray start``), else on a new local Ray instance sized to the machine (one worker per
                   core), shut down at the end.
``ray://HOST:PORT`` :class:`RayExecutor` on a remote cluster through Ray Client (the head's client
                   server, port 10001 by default).

Each Ray task takes :data:`THREADS_ENV` (default 1) CPUs and runs Dr.Jit on as many threads
(``dr.set_thread_count``), so N workers use N cores without oversubscription. The worker gets this
process's Mitsuba variant and ``$DYNGI_CACHE`` (the reference cache must be a directory every worker
can reach: shared storage on a multi-machine cluster; docs/cluster.md).

Failures: a task that raises (or whose worker process dies) is submitted again, up to ``retries`` times
(:data:`RETRIES_ENV`, default :data:`DEFAULT_RETRIES`); a :class:`~dyngi.errors.DyngiError` (bad input:
deterministic) is not retried. A task that still fails is reported by name with its error in the outcome
list and in :attr:`Executor.failures`, and the rest of the job runs on. Progress: one bar for the whole
job (:class:`Progress`: tasks done / total, ETA, retries, failures), shared by the phases of a job.

Ray is optional: ``pip install 'dyngi[ray]'``; without it a Ray back-end is one :class:`DyngiError`
naming the extra.
"""
from __future__ import annotations

import abc
import contextlib
import contextvars
import json
import os
import re
import sys
from dataclasses import dataclass, field
from typing import Any, Callable

from ..errors import DyngiError
from ..scene.library import builtin_names
from ..scene.loaders import ambient_options

# This module loads no Dr.Jit at import: a Ray worker unpickles :func:`dyngi_task` from it and must set the
# driver's environment ($DYNGI_BLAS_THREADS, read when dyngi.backend loads) and variant first
# (:func:`_prepare_worker`). So the dyngi modules that load Dr.Jit (backend, scene, io, references) are
# imported inside the functions that need them, and only there (tests/test_layers.py, FUNCTION_IMPORTS_WHY).

CLUSTER_ENV = "DYNGI_CLUSTER"
"""Environment variable naming the default back-end (``local``, ``auto`` or ``ray://HOST:PORT``)."""
RETRIES_ENV = "DYNGI_RETRIES"
"""Environment variable: how often a failed task is tried again on a cluster (default :data:`DEFAULT_RETRIES`)."""
THREADS_ENV = "DYNGI_WORKER_THREADS"
"""Environment variable: CPUs (= Dr.Jit threads) per Ray task (default 1)."""
DEFAULT_RETRIES = 2
RAY_EXTRA = "pip install 'dyngi[ray]'"
_RAY_URL = re.compile(r"^ray://[^\s:/]+:\d+$")


@dataclass
class Task:
    """One unit of work: ``fn(*args, **kwargs)``; ``fn`` must be a module-level function (Ray pickles it by
    reference) and the arguments picklable, unless the job only ever runs in-process."""

    name: str
    fn: Callable
    args: tuple = ()
    kwargs: dict = field(default_factory=dict)


@dataclass
class TaskFailure:
    """A task that failed after ``attempts`` tries; ``error`` is one line (exception type and message)."""

    name: str
    error: str
    attempts: int

    def __str__(self) -> str:
        return f"{self.name}: {self.error} (after {self.attempts} attempt{'s' if self.attempts != 1 else ''})"


def failed(outcome) -> bool:
    return isinstance(outcome, TaskFailure)


def describe_error(e: BaseException) -> str:
    """One line for an exception (a Ray task error is unwrapped to its cause)."""
    cause = getattr(e, "cause", None)
    if cause is not None and cause is not e and isinstance(cause, BaseException):
        e = cause
    msg = str(e).strip().splitlines()
    text = msg[-1] if msg else ""
    name = type(e).__name__
    if name.startswith("RayTaskError(") and name.endswith(")"):
        name = name[len("RayTaskError("):-1]
    return f"{name}: {text}" if text else name


def _is_user_error(e: BaseException) -> bool:
    """A DyngiError (bad input) is deterministic: retrying it cannot help."""
    return isinstance(e, DyngiError) or isinstance(getattr(e, "cause", None), DyngiError)


# -- scenes for workers ------------------------------------------------------------------------------

@dataclass(frozen=True)
class SceneRef:
    """How a worker gets the scene: a built-in name or a scene file's absolute path (on a multi-machine
    cluster the same path on every machine: shared storage), and whether textures are averaged
    (``--untextured``). A worker loads it afresh (:meth:`load`); :meth:`load_shared` reuses one load per
    worker process, for tasks that only render (references)."""

    source: str
    untextured: bool = False
    options: str = ""          # the scene options (--fps, --camera, --animation, --loop) as JSON

    def load(self):
        from ..scene import load_scene
        from .io import exr_threads

        with exr_threads():        # a scene file may hold EXR textures
            scene = load_scene(self.source, **(json.loads(self.options) if self.options else {}))
        if self.untextured:
            from ..scene.untextured import make_untextured
            make_untextured(scene)
        return scene

    def load_shared(self):
        key = ("scene", self)
        if key not in _WORKER_STATE:
            _WORKER_STATE[key] = self.load()
        return _WORKER_STATE[key]


def _carried_options() -> str:
    """The scene options in force (:func:`~dyngi.scene.loaders.scene_options`) as JSON, the animation
    file's path made absolute, so a worker on another machine (shared storage) loads the same animated scene."""
    opts = ambient_options()
    if opts.get("animation"):
        opts["animation"] = os.path.abspath(opts["animation"])
    return json.dumps(opts, sort_keys=True) if opts else ""


def scene_ref(scene, untextured: bool = False) -> SceneRef:
    """A :class:`SceneRef` for a scene name, a scene file path, or a loaded Scene; it carries the scene
    options in force (``--fps``, ``--camera``, ``--animation``, ``--loop``)."""
    opts = _carried_options()
    builtins = set(builtin_names())   # loads the built-in modules (BUILTINS alone may be empty yet)
    if isinstance(scene, (str, os.PathLike)):
        text = os.fspath(scene)
        return SceneRef(text if text in builtins else os.path.abspath(text), bool(untextured), opts)
    src = getattr(scene, "source", None)
    if src == "builtin" and scene.name in builtins:
        return SceneRef(scene.name, bool(untextured), opts)
    if src and src != "builtin" and os.path.isfile(src):
        return SceneRef(os.path.abspath(src), bool(untextured), opts)
    raise DyngiError(f"scene '{getattr(scene, 'name', scene)}' cannot be sent to cluster workers (built in "
                     "Python, not loaded by name or from a file); pass its name or file, or use --cluster local")


# -- progress -----------------------------------------------------------------------------------

class Progress:
    """One bar for a whole job (all phases, all workers): tasks done / total with tqdm's ETA, retries and
    failures in the postfix. ``quiet``: no bar, the counts are still kept."""

    def __init__(self, total: int, desc: str = "job", quiet: bool = True, unit: str = "task"):
        self.total, self.done, self.retries, self.failures = int(total), 0, 0, 0
        self.bar = None
        if not quiet:
            from tqdm import tqdm
            self.bar = tqdm(total=self.total, desc=desc, unit=unit, file=sys.stderr)

    def _post(self):
        if self.bar is not None and (self.retries or self.failures):
            self.bar.set_postfix_str(f"retried {self.retries}, failed {self.failures}")

    def task_done(self, ok: bool = True) -> None:
        self.done += 1
        if not ok:
            self.failures += 1
        if self.bar is not None:
            self.bar.update(1)
        self._post()

    def task_retried(self) -> None:
        self.retries += 1
        self._post()

    def add(self, n: int) -> None:
        """Grow the total (a phase whose size was not known when the bar was made)."""
        self.total += int(n)
        if self.bar is not None:
            self.bar.total = self.total
            self.bar.refresh()

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
            self.bar = None


# -- executors ------------------------------------------------------------------------------------

class Executor(abc.ABC):
    """Runs a job's tasks; see the module docstring. Subclasses implement :meth:`map`."""

    kind = "executor"
    in_process = True       # tasks run in this process (they may receive live, unpicklable objects)
    workers = 1             # tasks that can run at once

    def __init__(self, retries: int = 0, fail_fast: bool = False):
        self.retries = int(retries)
        self.fail_fast = bool(fail_fast)
        self.failures: list[TaskFailure] = []
        self.retried: dict[str, int] = {}     # task name -> attempts, for every task tried more than once

    @abc.abstractmethod
    def map(self, tasks: list[Task], on_done: Callable[[int, Any], None] | None = None,
            progress: Progress | None = None) -> list:
        """Run ``tasks``; results in task order (each back-end implements it)."""

    def describe(self) -> dict:
        return {"kind": self.kind, "workers": self.workers, "retries": self.retries}

    def close(self) -> None:
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def _record_failure(self, f: TaskFailure, progress: Progress | None) -> TaskFailure:
        self.failures.append(f)
        if progress is not None:
            progress.task_done(ok=False)
        return f


class LocalExecutor(Executor):
    """Tasks in order, in this process, on all cores (Dr.Jit's own thread pool).

    ``fail_fast=True`` (the ``--cluster local`` default): an exception propagates unchanged, as before
    executors existed. ``fail_fast=False``: retried up to ``retries`` times, then a :class:`TaskFailure`."""

    kind = "local"
    in_process = True
    workers = 1

    def __init__(self, retries: int = 0, fail_fast: bool = True):
        super().__init__(retries, fail_fast)

    def map(self, tasks, on_done=None, progress=None) -> list:
        out = []
        for i, t in enumerate(tasks):
            attempt = 1
            while True:
                try:
                    val = t.fn(*t.args, **t.kwargs)
                except Exception as e:
                    if self.fail_fast:
                        raise
                    if not _is_user_error(e) and attempt <= self.retries:
                        attempt += 1
                        self.retried[t.name] = attempt
                        if progress is not None:
                            progress.task_retried()
                        continue
                    out.append(self._record_failure(TaskFailure(t.name, describe_error(e), attempt), progress))
                    break
                out.append(val)
                if on_done is not None:
                    on_done(i, val)
                if progress is not None:
                    progress.task_done()
                break
        return out


def require_ray(what: str = "a Ray cluster"):
    """Import and return ``ray``, or a DyngiError naming the extra."""
    try:
        import ray
    except ImportError:
        raise DyngiError(f"{what} needs Ray, an optional extra of dyngi: {RAY_EXTRA} "
                         "(or use --cluster local)") from None
    return ray


_WORKER_STATE: dict = {}


def _prepare_worker(env: dict, variant: str | None, threads: int) -> None:
    """In a Ray worker: the driver's cache location and Mitsuba variant, Dr.Jit pinned to ``threads``."""
    os.environ.update(env)
    want = (variant, int(threads))
    if _WORKER_STATE.get("config") == want:
        return
    from ..backend import dr, mi

    if variant and mi.variant() != variant:
        mi.set_variant(variant)
    if threads > 0:
        dr.set_thread_count(int(threads))
    _WORKER_STATE["config"] = want


def dyngi_task(fn, args, kwargs, env, variant, threads):
    """The function every Ray task runs: prepare the worker, then ``fn(*args, **kwargs)``."""
    _prepare_worker(env, variant, threads)
    return fn(*args, **kwargs)


def _worker_env() -> dict:
    """What workers need of this process's environment: where the reference cache is."""
    from .references.cache import default_cache_dir

    env = {"DYNGI_CACHE": str(default_cache_dir().parent)}
    for k in ("DYNGI_BLAS_THREADS",):
        if k in os.environ:
            env[k] = os.environ[k]
    return env


class RayExecutor(Executor):
    """Tasks as Ray tasks (one CPU and one Dr.Jit thread each by default); see the module docstring.

    ``address``: ``None`` or ``"auto"`` (attach to a running cluster, else start a local one with
    ``num_cpus`` CPUs, default every core), or ``"ray://HOST:PORT"`` (Ray Client). A Ray instance this
    executor started is shut down by :meth:`close`; one it attached to is left running.
    """

    kind = "ray"
    in_process = False

    def __init__(self, address: str | None = "auto", num_cpus: int | None = None, retries: int | None = None,
                 threads: int | None = None, quiet: bool = True):
        super().__init__(default_retries() if retries is None else retries, fail_fast=False)
        if (address or "").startswith("ray://") and "RAY_AUTH_MODE" not in os.environ and (
                os.environ.get("RAY_AUTH_TOKEN") or os.path.isfile(os.path.expanduser("~/.ray/auth_token"))):
            os.environ["RAY_AUTH_MODE"] = "token"   # Ray Client sends the token only when told to (read at import)
        ray = require_ray(f"--cluster {address or 'auto'}")
        self.address = address or "auto"
        self.threads = worker_threads() if threads is None else int(threads)
        self._started = False
        self._connected_here = False
        import logging

        init_kw = dict(logging_level=logging.WARNING, log_to_driver=False)
        if ray.is_initialized():
            pass                                      # already attached (a test's session cluster, a notebook)
        elif self.address.startswith("ray://"):
            try:
                ray.init(address=self.address, **init_kw)
            except ValueError as e:                   # Ray Client needs ray[client] (grpcio)
                if "ray[client]" in str(e):
                    raise DyngiError(f"--cluster {self.address} needs Ray Client: {RAY_EXTRA}") from None
                raise DyngiError(f"cannot connect to the Ray cluster at {self.address}: {e}") from None
            except ConnectionError as e:
                raise DyngiError(f"cannot connect to the Ray cluster at {self.address}: {e}") from None
            self._connected_here = True
            if not os.environ.get("DYNGI_CACHE"):
                print("dyngi: warning: $DYNGI_CACHE is not set: the cluster's workers will not share this "
                      "machine's reference cache (set it to a directory on shared storage; docs/cluster.md)",
                      file=sys.stderr)
        else:
            try:
                ray.init(address="auto", **init_kw)
                self._connected_here = True
            except ConnectionError:
                n = int(num_cpus or os.cpu_count() or 1)
                # Ray's notice that the instance it starts uses token authentication: ours lives as long as
                # this command, on this machine only
                notice = logging.getLogger("ray._private.authentication.authentication_token_setup")
                level = notice.level
                notice.setLevel(logging.ERROR)
                try:
                    ray.init(num_cpus=n, include_dashboard=False, **init_kw)
                finally:
                    notice.setLevel(level)
                self._started = True
        self._ray = ray
        cpus = ray.cluster_resources().get("CPU", 1)
        self.workers = max(1, int(cpus // max(self.threads, 1)))
        self._remote = ray.remote(dyngi_task)

    def describe(self) -> dict:
        return {"kind": self.kind, "address": self.address, "started_here": self._started,
                "workers": self.workers, "threads_per_worker": self.threads, "retries": self.retries}

    def map(self, tasks, on_done=None, progress=None) -> list:
        from ..backend import mi

        ray = self._ray
        env, variant = _worker_env(), mi.variant()
        out: list = [None] * len(tasks)
        pending: dict = {}

        def submit(i: int, attempt: int):
            t = tasks[i]
            ref = self._remote.options(num_cpus=max(self.threads, 1), max_retries=0,
                                       name=_ray_name(t.name)).remote(t.fn, t.args, t.kwargs, env, variant,
                                                                       self.threads)
            pending[ref] = (i, attempt)

        try:
            for i in range(len(tasks)):
                submit(i, 1)
            while pending:
                ready, _ = ray.wait(list(pending), num_returns=1)
                for ref in ready:
                    i, attempt = pending.pop(ref)
                    try:
                        val = _writable(ray.get(ref))
                    except Exception as e:   # the task raised, or its worker (or node) died
                        if not _is_user_error(e) and attempt <= self.retries:
                            self.retried[tasks[i].name] = attempt + 1
                            if progress is not None:
                                progress.task_retried()
                            submit(i, attempt + 1)
                            continue
                        out[i] = self._record_failure(TaskFailure(tasks[i].name, describe_error(e), attempt),
                                                      progress)
                        continue
                    out[i] = val
                    if on_done is not None:
                        on_done(i, val)
                    if progress is not None:
                        progress.task_done()
        except BaseException:
            for ref in pending:
                with contextlib.suppress(Exception):
                    ray.cancel(ref, force=True)
            raise
        return out

    def close(self) -> None:
        ray = self._ray
        if (self._started or self._connected_here) and ray.is_initialized():
            ray.shutdown()     # a local instance we started stops; a cluster we attached to keeps running
        self._started = self._connected_here = False


def _writable(value):
    """``value`` with its NumPy arrays as ordinary writable copies: Ray hands arrays back as read-only views
    of its object store, which in-place NumPy code and Mitsuba's bindings (``mi.Bitmap``) refuse."""
    import pickle

    return pickle.loads(pickle.dumps(value, protocol=4))      # protocol 5 would keep them read-only


def _ray_name(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.=,:+-]+", "_", name)[:120] or "task"


def default_retries() -> int:
    text = os.environ.get(RETRIES_ENV)
    if text is None:
        return DEFAULT_RETRIES
    try:
        v = int(text)
    except ValueError:
        raise DyngiError(f"{RETRIES_ENV} must be an integer >= 0, got '{text}'") from None
    if v < 0:
        raise DyngiError(f"{RETRIES_ENV} must be an integer >= 0, got '{text}'")
    return v


def worker_threads() -> int:
    text = os.environ.get(THREADS_ENV, "1")
    try:
        v = int(text)
    except ValueError:
        raise DyngiError(f"{THREADS_ENV} must be an integer >= 1, got '{text}'") from None
    if v < 1:
        raise DyngiError(f"{THREADS_ENV} must be an integer >= 1, got '{text}'")
    return v


# -- choosing one -------------------------------------------------------------------------------------

def resolve_cluster(spec: str | None = None) -> str:
    """The back-end asked for: ``spec``, else ``$DYNGI_CLUSTER``, else ``local``; validated."""
    text = (spec if spec is not None else os.environ.get(CLUSTER_ENV, "")).strip() or "local"
    if text in ("local", "auto") or _RAY_URL.match(text):
        return text
    src = "--cluster" if spec is not None else f"${CLUSTER_ENV}"
    raise DyngiError(f"{src} '{text}' is invalid; use local (default), auto, or ray://HOST:PORT "
                     "(e.g. ray://head-node:10001)")


def make_executor(spec: str | None = None, quiet: bool = True) -> Executor:
    """The executor for ``spec`` (see :func:`resolve_cluster`); close it when done (or use ``with``)."""
    text = resolve_cluster(spec)
    if text == "local":
        return LocalExecutor()
    return RayExecutor(address=text, quiet=quiet)


_CURRENT: contextvars.ContextVar[Executor | None] = contextvars.ContextVar("dyngi_executor", default=None)


def current() -> Executor:
    """The executor of the running job (:func:`use`), else a fresh :class:`LocalExecutor` (fail-fast)."""
    ex = _CURRENT.get()
    return ex if ex is not None else LocalExecutor()


@contextlib.contextmanager
def use(executor: Executor):
    """Make ``executor`` the one :func:`current` returns inside the block (not closed here)."""
    token = _CURRENT.set(executor)
    try:
        yield executor
    finally:
        _CURRENT.reset(token)


def run_named(names: list[str], fn: Callable, args_list: list[tuple], desc: str = "job", quiet: bool = True,
              executor: Executor | None = None) -> dict:
    """``{name: fn(*args)}`` for every run that succeeded, run on ``executor`` (default :func:`current`).

    Failed runs are left out; the executor's :attr:`~Executor.failures` names them (under ``local`` the
    first error propagates, as before). Used by the reproductions for their independent runs."""
    ex = executor if executor is not None else current()
    tasks = [Task(n, fn, tuple(a)) for n, a in zip(names, args_list)]
    prog = Progress(len(tasks), desc, quiet=quiet or ex.in_process)
    try:
        res = ex.map(tasks, progress=prog)
    finally:
        prog.close()
    return {n: r for n, r in zip(names, res) if not failed(r)}


def failure_lines(executor: Executor | None = None) -> list[str]:
    """One line per task that failed in the current job (for reports)."""
    ex = executor if executor is not None else current()
    return [str(f) for f in ex.failures]


def failure_notes(executor: Executor | None = None) -> list[str]:
    """Markdown lines naming the failed runs of the current job (none when nothing failed)."""
    lines = failure_lines(executor)
    if not lines:
        return []
    return ["## Failed runs", "", "Left out after the executor's retries; everything else was run and written.",
            ""] + [f"* {x}" for x in lines] + [""]


def report_failures(executor: Executor, stream=None) -> int:
    """Print the failed tasks of a job (one line each) to stderr; 1 if any, else 0."""
    if not executor.failures:
        return 0
    stream = stream or sys.stderr
    print(f"dyngi: FAILED: {len(executor.failures)} task(s) failed after retries; the rest of the job was "
          "written:", file=stream)
    for f in executor.failures:
        print(f"  {f}", file=stream)
    return 1

import os
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SHARED_SCENES = os.path.join(os.path.dirname(ROOT), "shared", "scenes")


@pytest.fixture(scope="session")
def backend():
    from dyngi import backend as b

    b.set_device("cpu")
    return b


def shared_scene(rel: str) -> str:
    """Path of a scene under ../shared/scenes, skipping the test when absent."""
    p = os.path.join(SHARED_SCENES, rel)
    if not os.path.exists(p):
        pytest.skip(f"shared scene {rel} not available")
    return p


sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))


CI_GRIDS = {
    # slow grids over every built-in scene: CI's subset keeps this many of their cases, evenly spread
    "tests/techniques/test_ddgi.py::test_no_nan_500_frames_every_builtin[": 2,
    "tests/experiments/test_indirect_reference.py::test_agrees_with_mitsuba_difference_on_every_builtin_scene[": 3,
}
BATTERY = "tests/techniques/test_battery.py::"
CI_EXCLUDE = {
    # dr.freeze (path:freeze=true, opt-in): Dr.Jit 1.5 aborted the whole process once while recording (a
    # garbage collection inside the frozen call); a crash would take CI's run down, so it runs under a plain
    # ``-m slow`` only
    "tests/techniques/test_path.py::test_frozen_static_frames_are_bit_identical",
}


def pytest_collection_modifyitems(session, config, items):
    """With ``DYNGI_SLOW_SUBSET=ci`` (set by ``.ci/run``) only CI's fixed slow subset is kept
    (:func:`_ci_subset`); a plain ``-m slow`` runs everything."""
    if os.environ.get("DYNGI_SLOW_SUBSET") == "ci":
        kept, dropped = _ci_subset(items)
        if dropped:
            config.hook.pytest_deselected(items=dropped)
        items[:] = kept


def _ci_subset(items):
    """The fixed, representative slow subset CI runs every time: every slow test except (a) the battery's
    grid, of which only the cases marked ``ci_slow`` run (one heavy check per technique, another than the
    fast suite's: tests/techniques/test_battery.py, ``HEAVY_KINDS``), and (b) the grids over every built-in
    scene in :data:`CI_GRIDS`, of which a few evenly spread cases run; (c) :data:`CI_EXCLUDE`. Deterministic: the same commit always
    runs the same subset."""
    keep, drop = [], []
    groups: dict = {}
    for it in items:
        if it.nodeid in CI_EXCLUDE:
            drop.append(it)
            continue
        if it.nodeid.startswith(BATTERY):
            (keep if it.get_closest_marker("ci_slow") or not it.get_closest_marker("slow") else drop).append(it)
            continue
        prefix = next((p for p in CI_GRIDS if it.nodeid.startswith(p)), None)
        if prefix is None:
            keep.append(it)
        else:
            groups.setdefault(prefix, []).append(it)
    for prefix, its in groups.items():
        n = CI_GRIDS[prefix]
        chosen = {round(k * (len(its) - 1) / max(n - 1, 1)) for k in range(n)} if len(its) > n else set(range(len(its)))
        for k, it in enumerate(its):
            (keep if k in chosen else drop).append(it)
    return keep, drop


def pytest_runtest_logreport(report):
    """With ``DYNGI_TEST_TIMES=FILE``, append ``nodeid<TAB>seconds`` for each test's call (and set-up)
    as it finishes: the per-test costs that keep the fast suite in CI's budget, readable even from a
    run that is stopped before pytest's own ``--durations`` table."""
    path = os.environ.get("DYNGI_TEST_TIMES")
    if path and report.when in ("setup", "call"):
        with open(path, "a") as f:
            f.write(f"{report.nodeid}\t{report.when}\t{report.duration:.2f}\t{report.outcome}\n")

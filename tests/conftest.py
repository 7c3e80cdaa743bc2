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


BATTERY_SLOW = "tests/techniques/test_battery.py::test_finite_slow"
BATTERY_GRIDS = tuple(f"tests/techniques/test_battery.py::{t}[" for t in (
    "test_furnace", "test_furnace_depth_limited", "test_indirect_of_a_directly_lit_plane_is_zero"))


def pytest_collection_modifyitems(session, config, items):
    """The battery's 200-frame runs on every built-in scene (``test_finite_slow``: techniques x scenes,
    the bulk of ``-m slow``) run after every other test, so a time-capped slow run always covers the
    statistical tests first. Stable: the order within each group is kept. With
    ``DYNGI_SLOW_SUBSET=ci`` (``.ci/run``) only a fixed sample of them runs (:func:`_ci_battery_sample`)."""
    if os.environ.get("DYNGI_SLOW_SUBSET") == "ci":
        kept, dropped = _ci_battery_sample(items)
        if dropped:
            config.hook.pytest_deselected(items=dropped)
        items[:] = kept
    last = [it for it in items if it.nodeid.startswith(BATTERY_SLOW)]
    if last:
        keep = [it for it in items if not it.nodeid.startswith(BATTERY_SLOW)]
        items[:] = keep + last


def _ci_battery_sample(items):
    """The fixed, representative slow subset CI runs every time (``DYNGI_SLOW_SUBSET=ci``, set by
    ``.ci/run``): every slow test except the battery's 200-frame ``test_finite_slow`` runs; of those
    (techniques x scenes) each technique keeps one scene, rotated over the scene list by the
    technique's sorted position so that the sample covers as many scenes as techniques. Deterministic:
    the same commit always runs the same subset."""
    battery = [it for it in items if it.nodeid.startswith(BATTERY_SLOW)]
    pairs = {}
    for it in battery:
        name, scene = it.callspec.params["name"], it.callspec.params["scene_name"]
        pairs.setdefault(name, []).append((scene, it))
    keep, drop = [], []
    for i, name in enumerate(sorted(pairs)):
        scenes = sorted(pairs[name], key=lambda p: p[0])
        chosen = scenes[i % len(scenes)][1]
        keep.append(chosen)
        drop.extend(it for _, it in scenes if it is not chosen)
    rest = [it for it in items if not it.nodeid.startswith(BATTERY_SLOW)]
    # the battery's other grids (furnace kinds, furnace depths, plane lights) are sampled in the fast
    # suite already (tests/techniques/test_battery.py, _sampled); their remaining pairs run under a plain
    # ``-m slow``, not in CI's subset
    grid = [it for it in rest if it.nodeid.startswith(BATTERY_GRIDS)]
    rest = [it for it in rest if not it.nodeid.startswith(BATTERY_GRIDS)]
    return rest + keep, drop + grid


def pytest_runtest_logreport(report):
    """With ``DYNGI_TEST_TIMES=FILE``, append ``nodeid<TAB>seconds`` for each test's call (and set-up)
    as it finishes: the per-test costs that keep the fast suite in CI's budget, readable even from a
    run that is stopped before pytest's own ``--durations`` table."""
    path = os.environ.get("DYNGI_TEST_TIMES")
    if path and report.when in ("setup", "call"):
        with open(path, "a") as f:
            f.write(f"{report.nodeid}\t{report.when}\t{report.duration:.2f}\t{report.outcome}\n")

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


def pytest_collection_modifyitems(session, config, items):
    """The battery's 200-frame runs on every built-in scene (``test_finite_slow``: techniques x scenes,
    the bulk of ``-m slow``) run after every other test, so a time-capped slow run (CI stops it after
    45 minutes) always covers the statistical tests first. Stable: the order within each group is kept."""
    last = [it for it in items if it.nodeid.startswith("tests/techniques/test_battery.py::test_finite_slow")]
    if last:
        keep = [it for it in items if not it.nodeid.startswith("tests/techniques/test_battery.py::test_finite_slow")]
        items[:] = keep + last

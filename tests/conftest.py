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

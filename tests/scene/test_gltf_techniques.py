"""Every registered technique runs, unchanged, on a user's animated glTF scene (the example box: a node
translating, a child rotating about a hinge, an emissive mesh riding on it, a sun and a point light): a few
frames at a tiny size, all pixels finite and non-negative, and the moving frames differ."""
from __future__ import annotations

import os
import runpy

import numpy as np
import pytest

from dyngi.experiments.runner import run_sequence
from dyngi.scene import load_scene
from dyngi.techniques.base import create_technique, technique_names

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


@pytest.fixture(scope="module")
def box(tmp_path_factory):
    path = str(tmp_path_factory.mktemp("gltf") / "box.gltf")
    return runpy.run_path(os.path.join(ROOT, "examples", "animated_box.py"))["write"](path)


def _run(box, spec):
    sc = load_scene(box, fps=2)                 # frames 0, 1, 2 are t = 0, 0.5, 1 s: the box moves
    tech = create_technique(spec, sc)
    seq = run_sequence(sc, tech, 3, (16, 12), seed=0)
    imgs = np.stack(seq.images)
    assert np.all(np.isfinite(imgs)) and imgs.min() >= 0.0, spec
    assert np.abs(imgs[0] - imgs[-1]).mean() > 0.0, spec
    return imgs


def test_ddgi_runs_on_the_gltf_box(backend, box):
    _run(box, "ddgi")


@pytest.mark.slow
@pytest.mark.parametrize("name", technique_names())
def test_every_technique_runs_on_the_gltf_box(backend, box, name):
    _run(box, name)

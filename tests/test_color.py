"""The one luminance (:mod:`dyngi.color`): its weights are Mitsuba's ``mi.luminance``
(Rec. 709's Y) on the device and on the host, and no other module of dyngi spells the weights out.

The static check reads every module's float literals (AST, so docstrings and comments do not count):
a literal within 1e-4 of 0.2126, 0.7152 or 0.0722 outside ``color.py`` is a copy of the weights."""
from __future__ import annotations

import ast
import os

import numpy as np

SRC = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "src", "dyngi")
WEIGHTS = (0.2126, 0.7152, 0.0722)


def test_weights_equal_mitsuba_on_random_colours(backend):
    from dyngi.backend import mi
    from dyngi.color import LUMINANCE, luminance

    rng = np.random.default_rng(7)
    c = rng.uniform(0.0, 10.0, (4096, 3)).astype(np.float32)
    mitsuba = np.asarray(mi.luminance(mi.Color3f(c[:, 0], c[:, 1], c[:, 2])), np.float64)
    dev = np.asarray(luminance(mi.Color3f(c[:, 0], c[:, 1], c[:, 2])), np.float64)
    host = luminance(c)
    assert np.array_equal(dev, mitsuba)                         # device: Mitsuba's own function
    assert host.dtype == np.float64 and host.shape == (4096,)
    assert np.allclose(host, mitsuba, rtol=2e-7, atol=0.0)      # host: same weights, float64 vs float32
    # the weights themselves: Mitsuba's on the unit colours (to float32), white sums to 1
    unit = np.asarray(mi.luminance(mi.Color3f([1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0])))
    assert np.array_equal(LUMINANCE.astype(np.float32), unit.astype(np.float32))
    assert abs(LUMINANCE.sum() - 1.0) < 1e-5 and np.isclose(luminance([0.0, 1.0, 0.0]), 0.71516)


def _weight_literals(path: str) -> list[int]:
    tree = ast.parse(open(path, encoding="utf-8").read(), path)
    return [node.lineno for node in ast.walk(tree)
            if isinstance(node, ast.Constant) and isinstance(node.value, float)
            and any(abs(node.value - w) < 1e-4 for w in WEIGHTS)]


def _copies() -> dict[str, list[int]]:
    out = {}
    for root, _, files in os.walk(SRC):
        for f in files:
            if f.endswith(".py"):
                path = os.path.join(root, f)
                rel = os.path.relpath(path, SRC).replace(os.sep, "/")
                lines = _weight_literals(path)
                if lines and rel != "color.py":
                    out[rel] = lines
    return out


def test_no_module_copies_the_weights():
    copies = _copies()
    assert not copies, f"use dyngi.color.luminance instead of the Rec. 709 weights (module: lines): {copies}"


def test_the_check_finds_copies(tmp_path):
    f = tmp_path / "x.py"
    f.write_text('"""Y = 0.2126 R."""\nY = 0.212671 * r + 0.715160 * g\nk = 0.072\n')
    assert _weight_literals(str(f)) == [2, 2]
    assert _weight_literals(os.path.join(SRC, "color.py"))       # color.py itself holds them

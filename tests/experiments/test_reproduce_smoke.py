"""Every registered reproduction at its smoke size: ``dyngi reproduce NAME --smoke``
exits 0 and writes the top-level ``report.html`` its last line names, which opens in headless Chromium
(a non-blank screenshot, its figures loaded). The smoke size (``reproduce.SMOKE``) takes the ``--quick``
code path at a tiny configuration (~10-45 s each on the shared 2-core box, references included)."""
import io
import json
import os
import subprocess
import sys

import numpy as np
import pytest

from dyngi.experiments.reproduce import EXPERIMENTS, SMOKE, experiment_names, smoke_size

DYNGI = [sys.executable, "-m", "dyngi.cli"]


def test_every_experiment_has_a_smoke_size_that_restores_quick():
    import importlib

    names = experiment_names()
    assert names and set(names) == set(SMOKE), (names, sorted(SMOKE))
    for n in names:
        module, attr, settings = SMOKE[n]
        cfg = getattr(importlib.import_module(module), attr)
        before = dict(cfg)
        assert set(settings) <= set(cfg), n
        with smoke_size(n) as inside:
            assert inside is cfg and all(cfg[k] == v for k, v in settings.items())
        assert cfg == before, n
    assert EXPERIMENTS


def test_smoke_size_restores_after_a_failure():
    from dyngi.experiments.reproduce import DDGI_QUICK

    before = dict(DDGI_QUICK)
    with pytest.raises(RuntimeError):
        with smoke_size("ddgi"):
            raise RuntimeError("midway")
    assert DDGI_QUICK == before


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    return str(tmp_path_factory.mktemp("cache"))


@pytest.mark.slow
@pytest.mark.timeout(300)
@pytest.mark.parametrize("name", experiment_names())
def test_reproduction_smoke_run_and_report(name, tmp_path, cache):
    from PIL import Image

    from dyngi.viewer.browser import Chromium, find_chromium

    out = tmp_path / name
    r = subprocess.run(DYNGI + ["reproduce", name, "--smoke", "--quiet", "--out", str(out)], capture_output=True,
                       text=True, env=dict(os.environ, DYNGI_CACHE=cache), timeout=280)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-3000:]
    report = out / "report.html"
    assert f"(open {report})" in r.stdout.strip().splitlines()[-1]
    assert report.exists() and (out / "summary.json").exists()
    claims = json.load(open(out / "summary.json")).get("claims", [])
    if name != "ddgi":       # every paper reproduction decides its claims; a smoke run never decides
        assert claims and all(c["verdict"] == "undecided (quick)" for c in claims), claims
        assert all(f"{c['claim']} ({c['where']}): undecided (quick)" in r.stdout for c in claims), r.stdout[-2000:]
    if find_chromium() is None:
        if os.environ.get("CI"):
            pytest.fail("CI must run the browser tests: Debian's chromium is not installed")
        pytest.skip("Debian's chromium is not installed (bash run.sh installs it as root)")
    with Chromium() as br:
        page = br.new_page(f"file://{report}", width=1100, height=800)
        page.wait_for("Array.from(document.images).every(i => i.complete)", 30)
        widths = page.evaluate("Array.from(document.images).map(i => i.naturalWidth)")
        text = page.evaluate("document.body.innerText")
        png = page.screenshot()
    assert all(w > 0 for w in widths), widths
    assert f"reproduce {name}" in text
    shot = np.asarray(Image.open(io.BytesIO(png)).convert("L"), np.float64)
    assert shot.std() > 5.0, "blank screenshot"

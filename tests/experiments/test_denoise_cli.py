"""``--denoise`` on ``render`` and ``compare`` (Intel OIDN)."""
import json
import os

import pytest

from dyngi.errors import DyngiError


@pytest.fixture
def cache(tmp_path, monkeypatch, backend):
    monkeypatch.setenv("DYNGI_CACHE", str(tmp_path / "cache"))
    return tmp_path


def _need_oidn():
    from dyngi.experiments.denoise import available
    if not available():
        pytest.skip("pyoidn not installed")


@pytest.mark.slow   # CI budget (10-30 s on a cold cache); runs in CI's slow subset
def test_compare_reports_raw_and_denoised_side_by_side(cache):
    _need_oidn()
    from dyngi.experiments.compare import run_compare

    out = cache / "cmp"
    run_compare("cornell-static", ["path", "ddgi"], str(out), frames=2, res=(48, 36), ref_spp=64, quiet=True,
                metrics=["mse", "relmse"], grid_frames=[], denoise=True)
    with open(os.path.join(out, "summary.json")) as f:
        js = json.load(f)
    assert set(js["techniques"]) == {"path", "ddgi", "path+denoise", "ddgi+denoise"}
    with open(os.path.join(out, "metrics.csv")) as f:
        text = f.read()
    assert "path+denoise" in text and "ddgi+denoise" in text
    # the denoised row is the same run's frames denoised, not a new run: same time per frame
    assert js["techniques"]["path+denoise"]["ms_per_frame"] == js["techniques"]["path"]["ms_per_frame"]
    # a 1-spp path frame is far noisier than the denoiser leaves it (relMSE: the light's edge pixels
    # dominate MSE, see tests/techniques/test_restir_denoise.py for the error away from them)
    assert js["techniques"]["path+denoise"]["mean"]["relmse"] < js["techniques"]["path"]["mean"]["relmse"]
    assert "substitute for the OptiX denoiser" in (out / "summary.md").read_text()


def test_render_writes_denoised_frames(cache):
    _need_oidn()
    from dyngi.experiments.render import render_to_dir

    out = cache / "r"
    render_to_dir("cornell-static", "path", str(out), frames=1, res=(32, 24), quiet=True, denoise=True)
    assert (out / "frame_0000_denoised.exr").exists() and (out / "frame_0000_denoised.png").exists()


def test_missing_oidn_is_one_clear_error(cache, monkeypatch):
    from dyngi.experiments import denoise
    from dyngi.experiments.compare import run_compare

    monkeypatch.setattr(denoise, "available", lambda: False)
    with pytest.raises(DyngiError, match="pip install 'pyoidn"):
        run_compare("cornell-static", ["path"], str(cache / "x"), frames=1, res=(16, 12), quiet=True,
                    denoise=True)
    assert not (cache / "x").exists()       # nothing half-written


def test_denoise_spec_key_denoises_that_spec_only(cache):
    _need_oidn()
    from dyngi.experiments.compare import run_compare
    from dyngi.techniques.base import parse_spec

    assert parse_spec("path:denoise=true:spp=2").denoise and parse_spec("path:spp=2").params == {"spp": 2}
    with pytest.raises(DyngiError, match="denoise must be true or false"):
        parse_spec("path:denoise=maybe")
    out = cache / "spec"
    run_compare("cornell-static", ["path", "path:denoise=true"], str(out), frames=1, res=(32, 24), ref_spp=32,
                quiet=True, metrics=["mse"], grid_frames=[])
    with open(os.path.join(out, "summary.json")) as f:
        assert set(json.load(f)["techniques"]) == {"path", "path:denoise=true", "path:denoise=true+denoise"}

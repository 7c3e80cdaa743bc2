"""compare's reference depth for techniques of fixed path depth (``REFERENCE_DEPTH``; nee-pt: 3).

nee-pt traces the VLC paper's fixed 5-ray path (path depth 3), so it is measured against a reference of depth 3. Without
``--ref-depth`` a comparison of fixed-depth techniques must therefore render its reference at that depth
(else its MSE measures the missing longer paths, not noise), a mixed comparison keeps the scene's depth
and says which techniques are truncated, and an explicit ``--ref-depth`` always wins.
"""
from __future__ import annotations


def _prepare(tmp_path, techniques, ref_depth=None):
    from dyngi.experiments.compare import prepare
    return prepare("cornell-static", techniques, str(tmp_path / "out"), 2, "equal-frames", 16, None, None,
                   ref_depth, False)


def test_fixed_depth_techniques_set_the_reference_depth(backend, tmp_path):
    from dyngi.experiments.references.path import scene_max_depth
    run = _prepare(tmp_path, ["nee-pt:lights=uniform", "nee-pt"])
    assert run["ref_depth"] == 3
    assert any("depth 3" in w and "nee-pt" in w for w in run["warnings"]), run["warnings"]
    assert scene_max_depth(run["scene"]) != 3        # the default would have differed


def test_mixed_comparison_keeps_the_scene_depth_and_names_the_truncated(backend, tmp_path):
    from dyngi.experiments.references.path import scene_max_depth
    run = _prepare(tmp_path, ["path", "nee-pt"])
    assert run["ref_depth"] == scene_max_depth(run["scene"])
    notes = [w for w in run["warnings"] if w.startswith("nee-pt:")]
    assert len(notes) == 1 and "--ref-depth 3" in notes[0], run["warnings"]
    assert not any(w.startswith("path:") for w in run["warnings"])


def test_explicit_ref_depth_wins(backend, tmp_path):
    run = _prepare(tmp_path, ["nee-pt"], ref_depth=5)
    assert run["ref_depth"] == 5 and not run["warnings"]

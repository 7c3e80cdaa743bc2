"""``dyngi reproduce smcir --only SEQ:SEEDS`` (some runs of the full reproduction, each saved and skipped when
saved before) and ``--table`` (Table 1 / Table 2 from the runs finished so far)."""
from __future__ import annotations

import json
import os

import pytest

from dyngi.cli import main
from dyngi.experiments.reproductions import smcir
from dyngi.experiments.reproductions.smcir_table import table_markdown


def _fake_figures(scale: float) -> dict:
    """figures.json's figures for the full configuration's specs, smcir best by ``scale``."""
    out = {}
    for i, spec in enumerate(smcir.SMCIR_FULL["specs"]):
        e = (0.02 + 0.01 * i) * (scale if spec.startswith("smcir") else 1.0)
        out[spec] = {"E_tracked": e, "E_prime_tracked": e / 2, "brightness": 1.0 + 0.01 * i,
                     "ms_per_frame": 100.0 + i, "stage_ms": {k: 1.0 for k in smcir.TABLE2_STAGES}}
    return out


def _write_run(root, scene: str, seed: int, scale: float):
    d = os.path.join(root, scene, f"seed{seed}")
    os.makedirs(d)
    key = smcir._pair_key(scene, smcir.SMCIR_FULL, seed, "path", False, True)
    with open(os.path.join(d, smcir.FIGURES_FILE), "w") as f:
        json.dump({"key": key, "wall_s": 60.0 * (seed + 1), "figures": _fake_figures(scale)}, f)


def test_table_from_the_finished_runs(tmp_path, capsys):
    """One row group per finished sequence with its seeds; the paper's Table 1 beside ours; smcir's |E'|
    rank per seed and the stability verdict; Table 2's stage columns."""
    assert table_markdown(str(tmp_path)) == ""
    for sd in (0, 1, 2):
        _write_run(tmp_path, "maze", sd, 0.1)
    _write_run(tmp_path, "atrium-sun", 0, 5.0)
    md = table_markdown(str(tmp_path))
    assert "| maze (0, 1, 2) | abs E |" in md and "| atrium-sun (0) | abs E |" in md
    assert "corridor-walk" not in md                              # no run: no row
    maze = md.split("| maze (0, 1, 2)")[1].split("| atrium-sun")[0]
    assert "0.0287 / 0.0869 / 0.0380 / 0.0221" in maze            # the paper's Table 1 beside ours
    assert "lowest, stable" in maze                               # smcir 10x below every other row
    atrium = md.split("| atrium-sun (0)")[1]
    assert "not lowest" in atrium and "one seed: not judged" in atrium
    assert all(v in md for v in smcir.TABLE2_STAGES)
    assert main(["reproduce", "smcir", "--out", str(tmp_path), "--table"]) == 0
    assert capsys.readouterr().out.strip() == md.strip()


def test_only_runs_the_named_pairs_and_skips_saved_ones(tmp_path, monkeypatch, capsys):
    ran = []

    def fake_run_scene(scene, cfg, out_dir, quiet, reference, untextured, tracked, seed):
        ran.append((scene, seed))
        os.makedirs(out_dir, exist_ok=True)     # the real one writes its report there
        return _fake_figures(1.0)
    monkeypatch.setattr(smcir, "run_scene", fake_run_scene)
    monkeypatch.setattr("dyngi.cli._setup", lambda args: None)
    argv = ["reproduce", "smcir", "--out", str(tmp_path), "--only", "maze:0,2", "street-canyon", "--quiet"]
    assert main(argv) == 0
    assert ran == [("maze", 0), ("maze", 2), ("street-canyon", 0)]
    recs = [json.loads(line) for line in capsys.readouterr().out.splitlines() if line.startswith("{")]
    assert [r["cached"] for r in recs] == [False, False, False]
    assert main(argv) == 0                                         # saved: nothing runs again
    assert len(ran) == 3
    assert all(json.loads(line)["cached"] for line in capsys.readouterr().out.splitlines()
               if line.startswith("{"))
    assert "| maze (0, 2) |" in table_markdown(str(tmp_path))


@pytest.mark.parametrize("argv, needle", [
    (["--only", "nowhere:0"], "unknown smcir sequence 'nowhere'; valid sequences: corridor-walk"),
    (["--only", "maze:x"], "seeds must be comma-separated integers"),
    (["--only", "maze:-1"], "seeds must be comma-separated integers"),
    (["--only", "maze", "--table"], "give one of them"),
    (["--table"], "no finished smcir runs"),
])
def test_bad_parts_are_one_line(tmp_path, capsys, argv, needle):
    assert main(["reproduce", "smcir", "--out", str(tmp_path / "o")] + argv) == 2
    err = capsys.readouterr().err
    assert needle in err and err.count("\n") == 1


def test_only_belongs_to_smcir(tmp_path, capsys):
    assert main(["reproduce", "ddgi", "--out", str(tmp_path), "--table"]) == 2
    assert "belong to the smcir reproduction" in capsys.readouterr().err

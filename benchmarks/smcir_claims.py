"""Table 1's two claims of SMC-IR at a reduced scale, and the ablation of smcir's |E| against mir.

``paper-budget``: the claims' five rows only (mir, the paper's IR, tcas, both readings of smcir) at the
paper's VPL budgets (2048; the maze 512), otherwise as ``table``. ``table``: ``reproduce_smcir`` on the five sequences with every row of the full configuration at an equal
budget of 512 VPLs (the maze's own; the paper: 2048 elsewhere), ``--res`` (32x18), ``--frames`` (8), 64-spp
image references, tracked pixels at 65,536 spp, seeds 0-2: the claims' verdicts in ``OUT/summary.md``, the
table by ``dyngi reproduce smcir --out OUT --table``. ``ablation``: the maze with smcir's rows of the |E|
ablation (Eq. 8's readings, ``density_k=32``, ``radiosity_spp=256``, ``max_moves=0``) beside mir, the paper's
IR and tcas, at the same scale. Each (sequence, seed) is saved as it ends and skipped when saved (resumable).

    nice .venv/bin/python benchmarks/smcir_claims.py table OUT [--res 32x18 --frames 8]
    nice .venv/bin/python benchmarks/smcir_claims.py paper-budget OUT   # the claims' rows at 2048 / 512 VPLs
    nice .venv/bin/python benchmarks/smcir_claims.py ablation OUT

The full-size run (160x90, 60 frames, the paper's budgets: hours on 2 cores) is ``dyngi reproduce smcir``.
Recorded in docs/techniques/smcir.md ("Table 1's claims decided", "Why smcir's |E| lost").
"""
from __future__ import annotations

import argparse
import json
import os
import time

V = ":vpls=512"
TABLE_SPECS = tuple(s + V for s in ("mir", "ir:photons=qmc", "ir", "ir:photons=halton", "ir:photons=fixed", "tcas",
                                    "smcir")) + ("smcir" + V + ":eq8=text",)
PAPER_BUDGET_SPECS = ("mir", "ir:photons=qmc", "tcas", "smcir", "smcir:eq8=text")
ABLATION_SPECS = tuple(s + V for s in ("mir", "ir:photons=qmc", "tcas", "smcir", "smcir:eq8=text",
                                       "smcir:density_k=32", "smcir:radiosity_spp=256", "smcir:max_moves=0"))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("what", choices=("table", "paper-budget", "ablation"))
    ap.add_argument("out")
    ap.add_argument("--res", default="32x18")
    ap.add_argument("--frames", type=int, default=8)
    ap.add_argument("--scenes", default="", help="comma-separated sequences (default: all five; ablation: maze)")
    args = ap.parse_args()
    import numpy as np

    from dyngi.experiments.reproductions.smcir import SEQUENCES, reproduce_smcir

    w, h = (int(x) for x in args.res.split("x"))
    scenes = tuple(args.scenes.split(",")) if args.scenes else (
        tuple(s for s, _ in SEQUENCES) if args.what != "ablation" else ("maze",))
    specs = {"table": TABLE_SPECS, "paper-budget": PAPER_BUDGET_SPECS, "ablation": ABLATION_SPECS}[args.what]
    cfg = {"scenes": scenes, "res": (w, h), "frames": args.frames, "ref_spp": 64, "seeds": (0, 1, 2), "specs": specs}
    t0 = time.time()
    print("start", time.strftime("%H:%M:%S"), "load", os.getloadavg(), flush=True)
    out = reproduce_smcir(args.out, config=cfg, quiet=True)
    print("done", round(time.time() - t0), "s, load", os.getloadavg(), flush=True)
    d = json.load(open(os.path.join(out, "paper.json")))
    for sc, runs in d["figures"].items():
        for lab in specs:
            def g(k):
                return float(np.mean([r[lab][k] for r in runs]))
            print(f"{sc} {lab:36s} abs E {g('E_tracked'):.4f} / brightness {g('E_tracked_norm'):.4f}  abs E' "
                  f"{g('E_prime_tracked'):.4f} / brightness {g('E_prime_tracked_norm'):.4f}  brightness "
                  f"{g('brightness'):.3f}", flush=True)


if __name__ == "__main__":
    main()

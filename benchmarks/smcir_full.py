"""Run the full ``dyngi reproduce smcir`` configuration one (sequence, seed) at a time, resumable.

Each finished (sequence, seed) leaves ``OUT/SEQ/seedN/figures.json`` (what
:func:`dyngi.experiments.reproductions.smcir.run_scene` returns, plus its wall time); a pair whose file
exists is skipped, so the run can be stopped, resumed or split over processes. ``dyngi reproduce smcir
--out OUT`` (or ``reproduce_smcir(OUT)``) then reads the finished pairs back instead of rerunning them.

    nice .venv/bin/python benchmarks/smcir_full.py OUT street-canyon:0 atrium-sun:0 maze:0,1,2

Recorded in ``docs/techniques/smcir.md`` ("Table 1 and Table 2 at full size, 3 seeds"), beside the command,
resolution, seeds and machine load of each run.
"""
from __future__ import annotations

import json
import os
import sys
import time


def main(argv=None) -> int:
    from dyngi.experiments.reproductions.smcir import SMCIR_FULL, run_pair

    argv = sys.argv[1:] if argv is None else argv
    if len(argv) < 2:
        print(__doc__)
        return 2
    out = argv[0]
    for item in argv[1:]:
        scene, _, seeds = item.partition(":")
        for sd in (int(s) for s in (seeds or "0").split(",")):
            t0 = time.time()
            got, cached = run_pair(scene, SMCIR_FULL, out, sd, quiet=True)
            print(json.dumps({"scene": scene, "seed": sd, "cached": cached, "wall_s": round(time.time() - t0, 1),
                              "uptime": os.getloadavg()[0],
                              "E'": {k: round(v["E_prime_tracked"], 4) for k, v in got.items()}}), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

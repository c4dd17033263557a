"""The grain tracer's jumps side by side on one database: matched grains against stitched cells.

    python3 validation/rcfd/compare_jumps.py RUN_DIR [--paths 5] [--horizon 1] [--lp-half]

The same seeded paths from the database's last state, each jump variant in turn: 'match' (grains paired by
position, app/rcfd/matching.py; its matchings from RUN_DIR/rcfd/matchings.h5 where a run stored them), and the
stitch (app/rcfd/stitch.py) on the half cells and on the cells with the potential flow, and with the min-cost
flow on the cells (--lp-half: on the half cells too; slow above 20,000 half cells). Per variant: the seconds spent
building the jumps, the mean cell index and Lacey's index over the paths. Prints one JSON line.
"""
from __future__ import annotations

import argparse
import json
import pathlib
import sys
import time

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[2]))

from app.rcfd import commands  # noqa: E402
from app.rcfd.database import load  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("run")
    ap.add_argument("--paths", type=int, default=5)
    ap.add_argument("--horizon", type=float, default=1.0)
    ap.add_argument("--lp-half", action="store_true")
    a = ap.parse_args()
    db = load(a.run)
    s = db.n_states - 1
    c0 = commands.initial_concentration(db, s, None)
    n = int(round(a.horizon / db.frame_interval))
    variants = [("match", "auto", "auto"), ("stitch", "half", "potential"), ("stitch", "cells", "potential"),
                ("stitch", "cells", "lp")] + ([("stitch", "half", "lp")] if a.lp_half else [])
    out = {"run": a.run, "grains": int(db.cells.shape[1]), "cells": int(db.n_cells), "paths": a.paths,
           "horizon": a.horizon, "variants": []}
    st0 = None
    for jump, grid, flow in variants:
        t = time.perf_counter()
        e = commands.Engine(db, st0, jump=jump, jump_grid=grid, stitch_flow=flow)
        st0 = e.st
        ps = [e.path(n, s, (1, i)) for i in range(a.paths)]
        r = [e.transport(p, c0, s) for p in ps]
        row = {"jump": jump, "grid": "half cells" if e.half else "cells", "seconds": time.perf_counter() - t,
               "jump_seconds": e.stitch_seconds, "mean_index": float(np.mean([np.nanmean(x["M"]) for x in r])),
               "mean_lacey": float(np.mean([np.nanmean(x["lacey"]) for x in r])),
               "moved_share_mean": float(np.mean([m for x in r for m in x["moved"]]))}
        if jump == "stitch":
            row["flow"] = e.jump_stitcher.flow
        out["variants"].append(row)
        print(json.dumps(row), file=sys.stderr, flush=True)
    print(json.dumps(out))


if __name__ == "__main__":
    main()

"""How far the jump targets R picks are from the closest states in grain occupancy.

    python3 validation/rcfd/jump_targets_tv.py RUN_DIR [--l-mean 100]

For every state s with a jump target: the share of the grains that must change half cell (and cell) to turn s's
occupancy into the target's (half the L1 distance of the grain counts over the grain count), against the least such
share over every state the jump could take (outside the exclusion window, with a long enough run after it), and
the same between consecutive states (one frame). Prints the means.
"""
from __future__ import annotations

import argparse
import dataclasses
import pathlib
import sys

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[2]))

from app.rcfd import commands  # noqa: E402
from app.rcfd.database import load  # noqa: E402
from app.rcfd.paths import run_lengths  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("run")
    ap.add_argument("--l-mean", type=int, default=100)
    a = ap.parse_args()
    db = load(a.run)
    e = commands.Engine(db)
    e = commands.Engine(db, e.st, dataclasses.replace(e.params, l_mean=a.l_mean))
    B, G = db.cells.shape
    fine = e.fine if e.half else db.cells
    counts = {"half cells": np.stack([np.bincount(fine[b], minlength=int(fine.max()) + 1) for b in range(B)]),
              "cells": np.stack([np.bincount(db.cells[b], minlength=db.n_cells) for b in range(B)])}
    target = e.targets[0]
    cand = db.b0[run_lengths(e.successor) >= e.params.l_min]
    for name, c in counts.items():
        c = c.astype(float)
        tv = lambda s, j: 0.5 * np.abs(c[s] - c[j]).sum() / G  # noqa: E731
        at, best = [], []
        for s in range(B):
            if target[s] < 0:
                continue
            ok = cand[np.abs(cand - s) >= e.params.window]
            at.append(tv(s, db.b0[target[s]]))
            best.append(min(tv(s, j) for j in ok))
        step = np.mean([tv(b, b + 1) for b in range(B - 1)])
        print(f"{name}: at R's target {np.mean(at):.3f}, the least possible {np.mean(best):.3f}, one frame {step:.3f}")


if __name__ == "__main__":
    main()

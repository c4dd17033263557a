"""The stitch's two flows (app/rcfd/stitch.py), min-cost ('lp') and potential, side by side.

    python3 validation/rcfd/bench_stitch.py [RUN_DIR] [--max-lp-cells 40000] [--paths 20] [--l-mean 100]

1. Synthetic grids from 2,048 to 86,016 cells (the last the poppy-seed bed's 32 x 32 cells below 0.25 m): a noisy
   bed of the lower 60%, a blob at 30% height emptied to a fifth and its volume laid on the two layers above the
   bed, with 10% noise; a tagged bottom layer (30% of the height). Per flow: the time to build S, to apply it, the
   volume x distance moved, how far S a_from is from a_to, and the tagged layer's mixing index after the stitch.
   The min-cost flow runs up to --max-lp-cells.
2. With RUN_DIR (validate's run A, grain cells and octants recorded): the grain tracer with stitched jumps on half
   cells ('--jump stitch'), once per flow, on the same seeded paths of 1 s from the database's last state: the
   stitches' build time, the volume they move, the index change per jump and the mean index over the paths.
Prints one JSON line.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import pathlib
import sys
import time

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from app.rcfd import commands  # noqa: E402
from app.rcfd.database import load  # noqa: E402
from app.rcfd.engine import Engine  # noqa: E402
from app.rcfd.stitch import Stitcher  # noqa: E402
from app.rcfd.transport import mixing_index  # noqa: E402

SHAPES = [(8, 8, 32), (16, 16, 42), (24, 24, 63), (32, 32, 84)]


def synthetic(shape: tuple, rng) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    n = int(np.prod(shape))
    I = np.indices(shape).reshape(3, -1).T
    a_from = np.where(I[:, 2] < 0.6 * shape[2], 1.0, 0.0) * (0.5 + rng.random(n))
    a_to = a_from.copy()
    blob = np.linalg.norm(I - np.array(shape) * [0.5, 0.5, 0.3], axis=1) < shape[0] * 0.2
    a_to[blob] *= 0.2
    top = (I[:, 2] >= int(0.6 * shape[2])) & (I[:, 2] < int(0.6 * shape[2]) + 2)
    a_to[top] += 0.8 * a_from[blob].sum() / top.sum()
    a_to *= (1 + 0.1 * rng.standard_normal(n)) * (a_to > 0)
    return a_from, a_to, a_from * (I[:, 2] < 0.3 * shape[2])


def grids(max_lp: int) -> list:
    rng = np.random.default_rng(0)
    out = []
    for shape in SHAPES:
        a_from, a_to, m = synthetic(shape, rng)
        n = int(np.prod(shape))
        row = {"shape": list(shape), "cells": n}
        for flow in ("lp", "potential"):
            if flow == "lp" and n > max_lp:
                continue
            st = Stitcher(shape, np.ones(shape, bool), 1.0, flow)
            t = time.perf_counter()
            S, info = st.operator(a_from, a_to)
            t_build = time.perf_counter() - t
            t = time.perf_counter()
            m2, b2 = S @ m, S @ a_from
            t_apply = 0.5 * (time.perf_counter() - t)
            target = a_to * a_from.sum() / a_to.sum()
            row[flow] = {"build_s": t_build, "apply_s": t_apply, "volume_distance": info["volume_distance"],
                         "fit_error": float(np.abs(b2 - target).max() / target.max()),
                         "index_before": mixing_index(m, a_from - m), "index_after": mixing_index(m2, b2 - m2)}
        if "lp" in row:
            row["volume_distance_ratio"] = row["potential"]["volume_distance"] / row["lp"]["volume_distance"]
        out.append(row)
        print(json.dumps(row), file=sys.stderr, flush=True)
    return out


def database(run: str, n_paths: int, l_mean: int) -> dict:
    db = load(run)
    base = Engine(db, jump="stitch")
    params = dataclasses.replace(base.params, l_mean=l_mean)
    s = db.n_states - 1
    n = int(round(1.0 / db.frame_interval))
    c0 = commands.initial_concentration(db, s, None)
    out = {}
    for flow in ("lp", "potential"):
        e = Engine(db, base.st, params, jump="stitch", stitch_flow=flow)
        ps = [e.path(n, s, (1, i)) for i in range(n_paths)]
        res = [e.transport(p, c0, s) for p in ps]
        st = e.jump_stitcher
        infos = [v[1] for v in st.cache.values()]
        out[flow] = {"flow": st.flow, "grid_cells": st.n, "stitches": len(infos), "build_s_total": e.stitch_seconds,
                     "moved_share_mean": float(np.mean([i["moved_share"] for i in infos])),
                     "volume_distance_mean": float(np.mean([i["volume_distance"] for i in infos])),
                     "fit_error_max": float(max(i["fit_error"] for i in infos)),
                     "jump_dM_mean": float(np.mean([x for r in res for x in r["jump_dM"]])),
                     "mean_index": float(np.mean([np.nanmean(r["M"]) for r in res])),
                     "mean_lacey": float(np.mean([np.nanmean(r["lacey"]) for r in res])),
                     "final_index": float(np.mean([r["M"][-1] for r in res])),
                     "drift_max": float(max(r["drift"] for r in res))}
        print(json.dumps({flow: out[flow]}), file=sys.stderr, flush=True)
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("run", nargs="?")
    ap.add_argument("--max-lp-cells", type=int, default=40_000)
    ap.add_argument("--paths", type=int, default=20)
    ap.add_argument("--l-mean", type=int, default=100)
    a = ap.parse_args()
    out = {"grids": grids(a.max_lp_cells)}
    if a.run:
        out["database"] = {"run": a.run, "paths": a.paths, "l_mean": a.l_mean, **database(a.run, a.paths, a.l_mean)}
    print(json.dumps(out))


if __name__ == "__main__":
    main()

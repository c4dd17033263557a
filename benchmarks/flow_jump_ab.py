"""One flow-matching jump built by two trees of fbed, alternated: the seconds of GrainMatcher.operator, A against B.

Each round runs, in turn, one process per tree (``--a``, ``--b``: checkouts, e.g. `git worktree add /tmp/old
<commit>`); each process draws the same synthetic jump (benchmarks/flow_matching.py's states: grains in three volume
classes displaced by a smooth field of one cell plus noise) and builds it twice with different seeds, the first
build counted cold (as a prefetch worker's first jump) and the second warm. Both trees must give the same share of
the grain volume moved. Per case: medians over ``--rounds`` of each tree's seconds and of the paired ratio A/B
(> 1: B faster). Appends to benchmarks/RESULTS.md.

    git worktree add /tmp/old af2472c && python3 benchmarks/flow_jump_ab.py --a /tmp/old --b .
"""
from __future__ import annotations

import argparse
import inspect
import json
import pathlib
import statistics
import subprocess
import sys
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
CASES = ("7000:32x8x32", "958000:32x32x84", "958000:64x64x168")


def one(tree: str, grains: int, shape: tuple) -> dict:
    """In a child process: the jump built by ``tree``'s code."""
    sys.path[:0] = [str(pathlib.Path(tree) / "benchmarks"), str(tree)]
    import numpy as np

    import app
    from app.rcfd.flowmatch import FlowGraph
    from app.rcfd.matching import GrainMatcher, grid_centres
    from app.rcfd.stitch import face_edges
    from flow_matching import states

    assert pathlib.Path(app.__file__).resolve().is_relative_to(pathlib.Path(tree).resolve()), app.__file__
    cells, vol = states(grains, shape, 1.0, np.random.default_rng(1))
    args = (int(np.prod(shape)), face_edges(shape, np.ones(shape, bool)))
    takes_shape = "shape" in inspect.signature(FlowGraph).parameters  # (the grid's shape: since the multigrid)
    graph = FlowGraph(*args, shape) if takes_shape else FlowGraph(*args)
    out = {}
    for name, seed in (("cold", 2), ("warm", 3)):
        m = GrainMatcher(cells, grid_centres(shape, np.zeros(3), 1.0), vol, seed=seed, graph=graph)
        t = time.perf_counter()
        out["moved"] = m.operator(0, 1)[1]["moved_share"]
        out[name] = time.perf_counter() - t
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--a", required=True, help="tree A (the baseline)")
    ap.add_argument("--b", default=str(ROOT), help="tree B (default: this checkout)")
    ap.add_argument("--cases", nargs="+", default=list(CASES), help="GRAINS:NXxNYxNZ")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--child", help=argparse.SUPPRESS)
    ap.add_argument("--dry", action="store_true", help="print, do not append to RESULTS.md")
    a = ap.parse_args(argv)
    if a.child:
        tree, case = a.child.split("@")
        grains, shape = case.split(":")
        print(json.dumps(one(tree, int(grains), tuple(int(s) for s in shape.split("x")))))
        return 0
    rows = []
    for case in a.cases:
        got = {"A": [], "B": []}
        for _ in range(a.rounds):
            for name, tree in (("A", a.a), ("B", a.b)):
                res = subprocess.run([sys.executable, __file__, "--a", a.a, "--child", f"{tree}@{case}"], check=True,
                                     capture_output=True, text=True, cwd="/")
                got[name].append(json.loads(res.stdout.strip().splitlines()[-1]))
        moved = {name: {round(r["moved"], 12) for r in runs} for name, runs in got.items()}
        row = {"grains": case.split(":")[0], "grid": case.split(":")[1], "rounds": a.rounds,
               "volume moved A / B": "/".join(f"{next(iter(m)):.4f}" if len(m) == 1 else "varies"
                                              for m in moved.values())}
        for kind in ("cold", "warm"):
            ta, tb = [r[kind] for r in got["A"]], [r[kind] for r in got["B"]]
            row[f"{kind} A [s]"] = f"{statistics.median(ta):.3g}"
            row[f"{kind} B [s]"] = f"{statistics.median(tb):.3g}"
            row[f"{kind} A/B (min-max)"] = (f"{statistics.median(x / y for x, y in zip(ta, tb)):.2f} "
                                           f"({min(x / y for x, y in zip(ta, tb)):.2f}-"
                                           f"{max(x / y for x, y in zip(ta, tb)):.2f})")
        rows.append(row)
        print(row, flush=True)
    sys.path.insert(0, str(ROOT))
    from app.bench.common import append_results

    append_results(f"rCFD flow-matching jump, two trees alternated (A = {a.a}, B = {a.b}; synthetic jumps of one "
                   "cell, 3 volume classes; whole processes in turn, medians)", rows, "cpu", dry=a.dry)
    return 0


if __name__ == "__main__":
    sys.exit(main())

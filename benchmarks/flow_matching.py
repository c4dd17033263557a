"""The grain tracer's jump at growing size: the dense matching against the flow matching (app/rcfd/flowmatch.py).

Synthetic jumps (no database): grains uniform in the lower 60% of a box of grid cells, in three volume classes
(35/32/33%, as the poppy seeds); the target state is the same grains displaced by a smooth field of ``--amp`` cells
plus noise of half that, so that about the share of grains a real jump moves changes cell. Per case and method:
the seconds one GrainMatcher.operator takes (the methods alternated, ``--repeats`` times, medians), the share of
the grain volume that changes cell, the RMS distance moved [cells] and the total squared distance against the
dense matching's. The dense matching is run up to ``--dense-max`` grains (its cost grows as the cube of the grains
that change cell). Appends to benchmarks/RESULTS.md.

    python3 benchmarks/flow_matching.py                 # the default cases, up to the poppy bed's 958,000 grains
"""
from __future__ import annotations

import argparse
import pathlib
import statistics
import sys
import time

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.bench.common import append_results  # noqa: E402
from app.rcfd.flowmatch import FlowGraph  # noqa: E402
from app.rcfd.matching import GrainMatcher, grid_centres  # noqa: E402
from app.rcfd.stitch import face_edges  # noqa: E402

# (grains, grid): rcfd_bubbling's half cells, the 7,000-grain bed's, a 30,000-grain bed, the poppy bed on its 3 mm
# cells (86,016 below 0.25 m) and on its half cells
CASES = ((3400, (16, 4, 32)), (7000, (32, 8, 32)), (30000, (32, 16, 40)), (958000, (32, 32, 84)),
         (958000, (64, 64, 168)))


def states(grains: int, shape: tuple, amp: float, rng) -> tuple[np.ndarray, np.ndarray]:
    """(cells (2, grains), volume (grains,)): a state and its displaced target, three volume classes."""
    pos = rng.random((grains, 3)) * [1.0, 1.0, 0.6]
    h = 1.0 / np.array(shape)
    disp = amp * h * (np.sin(2 * np.pi * 3 * pos[:, [2, 0, 1]]) + 0.5 * rng.standard_normal((grains, 3)))
    out = []
    for p in (pos, np.clip(pos + disp, 0.0, 1.0 - 1e-9)):
        i = (p * shape).astype(np.int64)
        out.append((i[:, 0] * shape[1] + i[:, 1]) * shape[2] + i[:, 2])
    vol = rng.choice([0.919, 1.050, 1.269], grains, p=[0.35, 0.32, 0.33]) ** 3
    return np.stack(out), vol


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--amp", type=float, default=1.0, help="the displacement's amplitude [cells]")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--dense-max", type=int, default=7000, help="the dense matching up to this many grains")
    ap.add_argument("--max-grains", type=int, default=10**7, help="skip the larger cases")
    ap.add_argument("--dry", action="store_true", help="print, do not append to RESULTS.md")
    a = ap.parse_args(argv)
    rows = []
    for grains, shape in CASES:
        if grains > a.max_grains:
            continue
        cells, vol = states(grains, shape, a.amp, np.random.default_rng(1))
        centres = grid_centres(shape, np.zeros(3), 1.0)
        graph = FlowGraph(int(np.prod(shape)), face_edges(shape, np.ones(shape, bool)))
        methods = {"flow": graph} | ({"dense": None} if grains <= a.dense_max else {})
        walls, res = {m: [] for m in methods}, {}
        repeats = a.repeats if grains < 100_000 else 1
        for _ in range(repeats):
            for m, g in methods.items():
                matcher = GrainMatcher(cells, centres, vol, seed=2, graph=g)
                t = time.perf_counter()
                res[m] = matcher.operator(0, 1)
                walls[m].append(time.perf_counter() - t)
        d2 = {m: np.sum((centres[cells[1]] - centres[cells[0][perm]]) ** 2, 1) for m, (perm, _) in res.items()}
        sq = {m: float(d.sum()) for m, d in d2.items()}
        must = least(cells, vol)
        for m, (perm, info) in res.items():
            rows.append({"grains": grains, "grid": "x".join(map(str, shape)), "method": m,
                         "seconds (median)": f"{statistics.median(walls[m]):.3g}",
                         "min-max": f"{min(walls[m]):.3g}-{max(walls[m]):.3g}", "repeats": repeats,
                         "volume moved": f"{info['moved_share']:.3f}",
                         "least that must move": f"{must:.3f}",
                         "rms distance [cells]": f"{np.sqrt(sq[m] / max(1, np.count_nonzero(d2[m]))):.2f}",
                         "squared distance / dense": f"{sq[m] / sq['dense']:.3f}" if "dense" in sq else ""})
            print(rows[-1], flush=True)
    append_results(f"rCFD grain jumps: dense matching against flow matching (synthetic jumps of {a.amp:g} cells, "
                   "3 volume classes; methods alternated, medians)", rows, "cpu", dry=a.dry)
    return 0


def least(cells: np.ndarray, vol: np.ndarray) -> float:
    """The share of the grain volume that must change cell: 0.5 sum |a_s - a_j| / sum a, per volume class."""
    n = int(cells.max()) + 1
    tot = 0.0
    for v in np.unique(vol):
        k = vol == v
        tot += 0.5 * v * np.abs(np.bincount(cells[0][k], minlength=n) - np.bincount(cells[1][k], minlength=n)).sum()
    return tot / vol.sum()


if __name__ == "__main__":
    sys.exit(main())

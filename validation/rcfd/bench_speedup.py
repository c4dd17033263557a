"""rCFD's marginal speed-up measured side by side: the full CFD-DEM run and rCFD's transport alternated.

    python3 validation/rcfd/bench_speedup.py RUN_DIR [--rounds 3] [--segment 0.2] [--paths 20] [--l-mean 100]

RUN_DIR: validate's database run A (its rcfd.h5 and final checkpoint). Each round
1. resumes a fresh copy of RUN_DIR for ``segment`` simulated seconds (`python3 -m app run --resume`, recording as
   the database run did) and takes c_full, its wall time per simulated second from run.h5's wall_time series
   (stepping and callbacks, recording included; start-up and compilation excluded: the series starts after them,
   and the first 20 ms are dropped);
2. just before and just after it, moves the tracer along ``paths`` seeded 1 s paths from the database's last state, with the operators built
   and cached beforehand, as `fbed rcfd run` does (app.rcfd.engine.Engine), and takes c_r, the median path's
   transport wall per simulated second (indices after every frame included).
The machine's load drifts between and within rounds; the paired ratio c_full / c_r of each round is what counts.
Prints one JSON line with each round's figures and the medians.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import pathlib
import shutil
import subprocess
import sys
import tempfile
import time

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from app.rcfd import commands  # noqa: E402
from app.rcfd.database import load  # noqa: E402
from app.rcfd.engine import Engine  # noqa: E402


def full_segment(run_dir: pathlib.Path, segment: float) -> float:
    tmp = pathlib.Path(tempfile.mkdtemp()) / "A"
    shutil.copytree(run_dir, tmp)
    t1 = json.loads((run_dir / "summary.json").read_text())["time"]
    r = subprocess.run([sys.executable, "-m", "app", "run", "--resume", str(tmp), "--set",
                        f"run.duration={t1 + segment!r}", "--arch", "cpu"], cwd=ROOT, capture_output=True, text=True)
    if r.returncode != 0:
        raise SystemExit(r.stderr[-2000:])
    c = commands.full_cost_per_second(tmp, t1 + 0.02, t1 + segment)
    shutil.rmtree(tmp.parent)
    return c


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("run")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--segment", type=float, default=0.2)
    ap.add_argument("--paths", type=int, default=20)
    ap.add_argument("--l-mean", type=int, default=100)
    a = ap.parse_args()
    rd = pathlib.Path(a.run)
    db = load(rd)
    e = Engine(db)
    e = Engine(db, e.st, dataclasses.replace(e.params, l_mean=a.l_mean))
    s = db.n_states - 1
    n = int(round(1.0 / db.frame_interval))
    ps = [e.path(n, s, (1, i)) for i in range(a.paths)]
    c0 = commands.initial_concentration(db, s, None)
    for p in ps:  # operators built and cached, as after `fbed rcfd run`'s preparation
        e.transport(p, c0, s)
    rounds = []
    for _ in range(a.rounds):  # c_r just before and just after the full segment, c_full between
        t = time.perf_counter()
        walls = [e.transport(p, c0, s)["wall"] for p in ps]
        c_full = full_segment(rd, a.segment)
        walls += [e.transport(p, c0, s)["wall"] for p in ps]
        rounds.append({"c_full": c_full, "c_r": float(np.median(walls)), "seconds": time.perf_counter() - t})
        rounds[-1]["marginal"] = c_full / rounds[-1]["c_r"]
    out = {"run": str(rd), "segment": a.segment, "paths": a.paths, "l_mean": a.l_mean, "jump": e.jump,
           "rounds": rounds, "c_full_median": float(np.median([r["c_full"] for r in rounds])),
           "c_r_median": float(np.median([r["c_r"] for r in rounds])),
           "marginal_median": float(np.median([r["marginal"] for r in rounds])),
           "marginal_range": [float(min(r["marginal"] for r in rounds)), float(max(r["marginal"] for r in rounds))]}
    print(json.dumps(out))


if __name__ == "__main__":
    main()

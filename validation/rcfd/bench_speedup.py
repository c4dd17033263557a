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
In CPU time as well (fairer on a shared machine, where a process waits for a core): the full run's from the CPU
time of the segment's process less that of a 20 ms segment (start-up and compilation), the transport's from this
process's CPU time over the paths.
Prints one JSON line with each round's figures and the medians.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import pathlib
import shutil
import resource
import subprocess
import sys
import tempfile
import time

import numpy as np

SHORT = 0.02  # [s] simulated by the short segment whose CPU time (start-up, compilation) is taken off
ROOT = pathlib.Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from app.rcfd import commands  # noqa: E402
from app.rcfd.database import load  # noqa: E402
from app.rcfd.engine import Engine  # noqa: E402


def full_segment(run_dir: pathlib.Path, segment: float) -> tuple[float, float]:
    """(wall per simulated second from run.h5's series, CPU seconds of the whole process) of a resumed segment."""
    tmp = pathlib.Path(tempfile.mkdtemp()) / "A"
    shutil.copytree(run_dir, tmp)
    t1 = json.loads((run_dir / "summary.json").read_text())["time"]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    r = subprocess.run([sys.executable, "-m", "app", "run", "--resume", str(tmp), "--set",
                        f"run.duration={t1 + segment!r}", "--arch", "cpu"], cwd=ROOT, capture_output=True, text=True)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if r.returncode != 0:
        raise SystemExit(r.stderr[-2000:])
    c = commands.full_cost_per_second(tmp, t1 + 0.02, t1 + segment)
    shutil.rmtree(tmp.parent)
    return c, (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)


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
    def paths_cost():  # (median path's transport wall, CPU time per path) per simulated second
        c = time.process_time()
        walls = [e.transport(p, c0, s)["wall"] for p in ps]
        return float(np.median(walls)), (time.process_time() - c) / len(ps)

    for _ in range(a.rounds):  # c_r just before and just after the full segments, c_full between
        r0 = paths_cost()
        c_full, cpu_long = full_segment(rd, a.segment)
        _, cpu_short = full_segment(rd, SHORT)
        r1 = paths_cost()
        c_r, c_r_cpu = 0.5 * (r0[0] + r1[0]), 0.5 * (r0[1] + r1[1])
        c_full_cpu = (cpu_long - cpu_short) / (a.segment - SHORT)
        rounds.append({"c_full": c_full, "c_r": c_r, "marginal": c_full / c_r, "c_full_cpu": c_full_cpu,
                       "c_r_cpu": c_r_cpu, "marginal_cpu": c_full_cpu / c_r_cpu})
    out = {"run": str(rd), "segment": a.segment, "paths": a.paths, "l_mean": a.l_mean, "jump": e.jump,
           "rounds": rounds, "c_full_median": float(np.median([r["c_full"] for r in rounds])),
           "c_r_median": float(np.median([r["c_r"] for r in rounds])),
           "marginal_median": float(np.median([r["marginal"] for r in rounds])),
           "marginal_range": [float(min(r["marginal"] for r in rounds)), float(max(r["marginal"] for r in rounds))],
           "marginal_cpu_median": float(np.median([r["marginal_cpu"] for r in rounds])),
           "marginal_cpu_range": [float(min(r["marginal_cpu"] for r in rounds)),
                                  float(max(r["marginal_cpu"] for r in rounds))]}
    print(json.dumps(out))


if __name__ == "__main__":
    main()

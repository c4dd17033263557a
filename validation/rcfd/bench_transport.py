"""The grain tracer's cost per path per simulated second, before and after, side by side in one process.

    python3 validation/rcfd/bench_transport.py RUN_DIR [--before COMMIT] [--rounds 9] [--paths 20] [--l-mean 100]

RUN_DIR: a run that recorded rcfd.h5 with grain cells (validate's A). Variants, timed in turn in every round
(A B C D A B C D ...) with their operators built and cached first, so only the transport is timed, as in
`fbed rcfd run`'s marginal cost:
- before:  app/rcfd/engine.py and sequence.py at COMMIT (default: the branch's base; at fb52dd6, half-cell
           stitches and the index summed over every grain at every state);
- stitch:  this tree's engine with the stitch at jumps (the movers' index, and Lacey's as well);
- direct:  this tree, matched jumps, the index summed over every grain at every state (SequenceIndex's fallback);
- after:   this tree as `fbed rcfd run` runs it (matched jumps, the movers' index).
Prints one JSON line: per variant, in wall and in CPU time of this process (the fairer figure on a shared machine,
where a process waits for a core), the median over rounds of the ms per path per simulated second and the median
of the paired ratios to 'before'.
"""
from __future__ import annotations

import argparse
import dataclasses
import importlib.util
import json
import pathlib
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


def engine_at(commit: str):
    """The Engine class of app/rcfd/engine.py at ``commit``, with app/rcfd/sequence.py at the same commit (its other
    relative imports on this tree's modules)."""
    def source(name: str, required: bool = True) -> str:
        src = subprocess.run(["git", "show", f"{commit}:app/rcfd/{name}.py"], cwd=ROOT, capture_output=True,
                             text=True, check=required).stdout
        return src.replace("from . import", "from app.rcfd import").replace("from .", "from app.rcfd.")

    tmp = pathlib.Path(tempfile.mkdtemp())
    seq = source("sequence", required=False)
    src = source("engine")
    if seq:  # a commit before sequence.py has none to pin
        (tmp / "sequence_before.py").write_text(seq)
        src = src.replace("from app.rcfd.sequence import", "from sequence_before import")
        sys.path.insert(0, str(tmp))
    path = tmp / "engine_before.py"
    path.write_text(src)
    spec = importlib.util.spec_from_file_location("engine_before", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.Engine


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("run")
    ap.add_argument("--before", default="fb52dd6")
    ap.add_argument("--rounds", type=int, default=9)
    ap.add_argument("--paths", type=int, default=20)
    ap.add_argument("--l-mean", type=int, default=100)
    a = ap.parse_args()
    db = load(a.run)
    after = Engine(db)
    params = dataclasses.replace(after.params, l_mean=a.l_mean)
    engines = {"before": engine_at(a.before)(db, after.st, params),
               "stitch": Engine(db, after.st, params, jump="stitch"),
               "direct": Engine(db, after.st, params),
               "after": Engine(db, after.st, params)}
    q = engines["direct"].seq
    q.sequence = lambda w, s_prev, states: np.stack([q.tagged(w, b) for b in np.concatenate([[s_prev], states])])
    s = db.n_states - 1
    n = int(round(1.0 / db.frame_interval))  # 1 s paths
    ps = [engines["after"].path(n, s, (1, i)) for i in range(a.paths)]  # with --l-mean's sequences
    c0 = commands.initial_concentration(db, s, None)
    for e in engines.values():  # operators built and cached
        for p in ps:
            e.transport(p, c0, s)
    wall, cpu = {k: [] for k in engines}, {k: [] for k in engines}
    for _ in range(a.rounds):
        for k, e in engines.items():
            t, c = time.perf_counter(), time.process_time()
            for p in ps:
                e.transport(p, c0, s)
            wall[k].append(1e3 * (time.perf_counter() - t) / a.paths)
            cpu[k].append(1e3 * (time.process_time() - c) / a.paths)
    out = {"run": a.run, "before": a.before, "rounds": a.rounds, "paths": a.paths, "l_mean": a.l_mean,
           "grains": int(db.cells.shape[1]), "frames_per_second": n}
    for name, cost in (("wall", wall), ("cpu", cpu)):
        b = np.array(cost["before"])
        out[name] = {"ms_per_path_second_median": {k: float(np.median(v)) for k, v in cost.items()},
                     "ratio_to_before_median": {k: float(np.median(np.array(v) / b)) for k, v in cost.items()},
                     "ratio_to_before_range": {k: [float(np.min(np.array(v) / b)), float(np.max(np.array(v) / b))]
                                               for k, v in cost.items()}}
    print(json.dumps(out))


if __name__ == "__main__":
    main()

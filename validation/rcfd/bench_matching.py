"""`fbed rcfd run`'s wall time with the matched jumps computed afresh and taken from the store, side by side.

    python3 validation/rcfd/bench_matching.py RUN_DIR [--rounds 3] [--paths 20] [--horizon 1] [--out FILE]

RUN_DIR: a run that recorded rcfd.h5 with grain cells and octants (validate's A). Variants, run in turn in every
round (cold, warm, other-seed, cold, ...), each a whole commands.run_paths call with a fresh Engine (R, targets,
operators, paths, transport, outputs: what `fbed rcfd run` does after reading its arguments):
- cold:  no store (Engine(matchings=None)): every matching a path needs is computed, as before this change;
- warm:  the store of a first, untimed run with the same seed and horizon (a rerun: another tag, more outputs);
- other: the same store, paths of another seed (seed + 1): only the pairs the first seed never took are computed.
Every variant's mixing curves are checked to equal cold's (same seed) exactly: the store changes no result.
Prints one JSON line (and writes it to --out): per variant, the median wall and CPU time over rounds, the median of
the matching seconds, the matchings computed, and the median of the paired ratios cold / variant.
"""
from __future__ import annotations

import argparse
import json
import pathlib
import shutil
import sys
import tempfile
import time

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from app.rcfd import commands  # noqa: E402
from app.rcfd.database import load  # noqa: E402
from app.rcfd.engine import Engine  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("run")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--paths", type=int, default=20)
    ap.add_argument("--horizon", type=float, default=1.0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--out", default=None)
    a = ap.parse_args()
    tmp = pathlib.Path(tempfile.mkdtemp(prefix="bench_matching_"))
    db = load(a.run)
    store = tmp / "matchings.h5"

    def once(matchings, seed, name):
        t, c = time.perf_counter(), time.process_time()
        eng = Engine(db, matchings=matchings)
        s = commands.run_paths(a.run, a.horizon, a.paths, seed, None, out=str(tmp / name), engine=eng, log=lambda m: 0)
        wall, cpu = time.perf_counter() - t, time.process_time() - c
        M = np.loadtxt(tmp / name / "mixing.csv", delimiter=",", skiprows=1)
        return {"wall": wall, "cpu": cpu, "matching_seconds": eng.stitch_seconds,
                "computed": len(eng.matcher.fresh) + s.get("matchings", {}).get("stored", 0), "M": M}

    first = once(store, a.seed, "first")  # fills the store (untimed)
    ref_other = once(None, a.seed + 1, "ref_other")["M"]
    rows = {"cold": [], "warm": [], "other": []}
    for r in range(a.rounds):
        for v in rows:
            if v == "cold":
                res = once(None, a.seed, f"cold{r}")
            else:
                st = tmp / f"store_{v}{r}.h5"
                shutil.copy(store, st)  # each round from the first run's store only
                res = once(st, a.seed + (v == "other"), f"{v}{r}")
            ref = first["M"] if v != "other" else ref_other
            assert np.array_equal(res["M"], ref), f"{v}: the mixing differs from the direct matching's"
            rows[v].append(res)
            print(f"round {r} {v}: wall {res['wall']:.2f} s, cpu {res['cpu']:.2f} s, matching "
                  f"{res['matching_seconds']:.2f} s ({res['computed']} computed)", file=sys.stderr, flush=True)
    out = {"run": a.run, "paths": a.paths, "horizon": a.horizon, "rounds": a.rounds, "date": time.strftime("%Y-%m-%d"),
           "matchings_in_store": int(first["computed"])}
    for v, rs in rows.items():
        out[v] = {k: float(np.median([x[k] for x in rs])) for k in ("wall", "cpu", "matching_seconds", "computed")}
        if v != "cold":
            out[v]["speedup_wall"] = float(np.median([c["wall"] / x["wall"] for c, x in zip(rows["cold"], rs)]))
            out[v]["speedup_cpu"] = float(np.median([c["cpu"] / x["cpu"] for c, x in zip(rows["cold"], rs)]))
    line = json.dumps(out)
    print(line)
    if a.out:
        pathlib.Path(a.out).write_text(json.dumps(out, indent=2) + "\n")
    shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()

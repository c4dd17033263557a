"""Start-up cost of a run with and without the front end's memos (app/sim/frontend.py), whole processes in turn.

Each process runs ``fbed run PRESET`` for one fluid step on the CPU (``run.start_from`` emptied: the preset's
own fill), with the memos (``on``) or with Taichi's own front end (``off``, ``frontend.uninstall()`` before
anything is compiled). Pairs alternate off, on, off, on ... after one warm-up process of each, so both find the
same warm offline cache (the memos change no cache key: no process compiles anew). Reported: the medians of
the time to "kernels ready" (the progress line: start-up, fill, compilation or cache reads, first step) and of
the whole process, the time spent turning kernels' Python into IR (``Kernel.materialize``, timed in the process:
the part the memos work on), and the medians of the per-pair ratios off / on.

    python benchmarks/startup_cost.py --preset presets/boyce.toml --pairs 3
"""
from __future__ import annotations

import argparse
import pathlib
import re
import statistics
import subprocess
import sys
import tempfile
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.bench.common import append_results  # noqa: E402

CHILD = ("import atexit, sys, time\n"
         "from app.sim import frontend\n"
         "from taichi.lang import kernel_impl\n"
         "if sys.argv[1] == 'off':\n"
         "    frontend.uninstall()\n"
         "spent = [0.0]\n"
         "materialize = kernel_impl.Kernel.materialize\n"
         "def timed(self, *a, **k):\n"
         "    t = time.perf_counter()\n"
         "    try:\n"
         "        return materialize(self, *a, **k)\n"
         "    finally:\n"
         "        spent[0] += time.perf_counter() - t\n"
         "kernel_impl.Kernel.materialize = timed\n"
         "atexit.register(lambda: print(f'front end {spent[0]:.3f} s', file=sys.stderr))\n"
         "from app.cli import main\n"
         "sys.exit(main(sys.argv[2:]))\n")


def one(mode: str, preset: pathlib.Path, out: pathlib.Path) -> tuple[float, float, float]:
    cmd = [sys.executable, "-c", CHILD, mode, "run", str(preset), "--set", "run.duration=0.001", "--set",
           "run.step=0.001", "--set", 'run.start_from=""', "--set", "video.enabled=false", "--arch", "cpu",
           "--out", str(out)]
    t = time.perf_counter()
    r = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
    wall = time.perf_counter() - t
    if r.returncode != 0:
        raise SystemExit(f"startup_cost: {mode} run failed:\n{r.stderr[-2000:]}")
    m = re.search(r"kernels ready after (\d+) s", r.stdout + r.stderr)
    fe = re.search(r"front end ([0-9.]+) s", r.stderr)
    return (float(m.group(1)) if m else float("nan")), wall, float(fe.group(1))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--preset", type=pathlib.Path, default=ROOT / "presets" / "boyce.toml")
    ap.add_argument("--pairs", type=int, default=3)
    ap.add_argument("--dry", action="store_true", help="print, do not append to RESULTS.md")
    args = ap.parse_args(argv)
    res = {"off": [], "on": []}
    with tempfile.TemporaryDirectory() as tmp:
        for mode in ("off", "on"):  # warm-up: both find the cache filled
            one(mode, args.preset, pathlib.Path(tmp) / f"w{mode}")
        for i in range(args.pairs):
            for mode in ("off", "on"):
                res[mode].append(one(mode, args.preset, pathlib.Path(tmp) / f"{mode}{i}"))
                print(mode, res[mode][-1], flush=True)
    def med(k, i):
        return statistics.median(r[i] for r in res[k])

    def span(k, i):
        return f"{med(k, i):.2f} ({min(r[i] for r in res[k]):.2f}-{max(r[i] for r in res[k]):.2f})"

    rows = [{"front end": k, "AST to IR s (median, min-max)": span(k, 2), "kernels ready s": f"{med(k, 0):.0f}",
             "whole process s (median, min-max)": span(k, 1)} for k in ("off", "on")]
    rows.append({"front end": "off / on, per pair (median)",
                 "AST to IR s (median, min-max)": f"{statistics.median(a[2] / b[2] for a, b in zip(res['off'], res['on'])):.2f}",
                 "kernels ready s": "",
                 "whole process s (median, min-max)": f"{statistics.median(a[1] / b[1] for a, b in zip(res['off'], res['on'])):.3f}"})
    append_results(f"Start-up, Taichi's own front end (off) against the memos (on): {args.preset.name}, one fluid "
                   f"step (cpu, warm offline cache; {args.pairs} whole-process pairs in turn)", rows, "cpu",
                   dry=args.dry)
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Host reads per fluid step of a whole run, split into the step itself and the callbacks (series, guard,
probes, writers, progress), counted as benchmarks/gas_counts.py counts them.

    python benchmarks/series_reads.py presets/verma_small.toml --set run.duration=0.12
    PYTHONPATH=/path/to/other/tree python benchmarks/series_reads.py ...   # the same count of another tree

A host read is a kernel launch that returns a value, a to_numpy() or a Python-scope element read of a field
or ndarray (tests/kernel_counter.py, around every kernel of app.sim). The run goes through ``app.run.run``
(headless, CPU unless --arch) into a temporary folder; the steps' and the callbacks' reads are counted per
step, after the first ``--warmup`` steps. Prints the medians, means and the callbacks' reads by name, and
appends a table to benchmarks/RESULTS.md (unless --dry).
"""
from __future__ import annotations

import argparse
import collections
import importlib
import pathlib
import pkgutil
import statistics
import subprocess
import sys
import tempfile

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "tests"))
from kernel_counter import KernelCounter  # noqa: E402

import app  # noqa: E402
import app.sim  # noqa: E402
from app import run as runmod  # noqa: E402
from app.bench.common import append_results  # noqa: E402
from app.sim.simulation import Simulation  # noqa: E402


def sim_modules():
    """Every module of app.sim imported now (a module imported later would hold unwrapped kernels)."""
    for info in pkgutil.walk_packages(app.sim.__path__, "app.sim."):
        importlib.import_module(info.name)
    return [m for n, m in sorted(sys.modules.items()) if n.startswith("app.sim") and m is not None]


def tree_commit() -> str:
    root = pathlib.Path(app.__file__).resolve().parents[1]
    r = subprocess.run(["git", "-C", str(root), "rev-parse", "--short", "HEAD"], capture_output=True, text=True)
    return r.stdout.strip() or str(root)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("preset")
    ap.add_argument("--set", action="append", default=[], dest="overrides")
    ap.add_argument("--arch", default="cpu", choices=("cpu", "cuda"))
    ap.add_argument("--warmup", type=int, default=5)
    ap.add_argument("--label", default="")
    ap.add_argument("--dry", action="store_true")
    a = ap.parse_args(argv)
    counts = {"step": [], "callbacks": []}
    by_name: collections.Counter = collections.Counter()
    step0, fire0 = Simulation.step, Simulation._fire
    kc = KernelCounter(sim_modules())

    def step(self):
        r = kc.reads
        step0(self)
        counts["step"].append(kc.reads - r)

    def fire(self, start=False):
        r, names = kc.reads, collections.Counter(kc.reads_by)
        fire0(self, start)
        if not start:
            counts["callbacks"].append(kc.reads - r)
            if len(counts["callbacks"]) > a.warmup:
                by_name.update(collections.Counter(kc.reads_by) - names)

    Simulation.step, Simulation._fire = step, fire
    with tempfile.TemporaryDirectory() as out, kc:
        code = runmod.run(a.preset, a.overrides, out=str(pathlib.Path(out) / "run"), arch=a.arch)
    Simulation.step, Simulation._fire = step0, fire0
    if code != 0:
        print(f"the run exited {code}", file=sys.stderr)
        return code
    s, c = counts["step"][a.warmup:], counts["callbacks"][a.warmup:]
    steps = len(c)
    row = {"label": a.label or tree_commit(), "steps counted": steps,
           "step reads (median, mean)": f"{statistics.median(s):g}, {statistics.mean(s):.2f}",
           "callback reads (median, mean)": f"{statistics.median(c):g}, {statistics.mean(c):.2f}",
           "callback reads by name, per step": ", ".join(f"{k} {v / steps:.2f}" for k, v in by_name.most_common(6))}
    print(row, flush=True)
    title = (f"Host reads per fluid step of `{pathlib.Path(a.preset).name}` {' '.join(a.overrides)} ({a.arch}; "
             f"after {a.warmup} steps)")
    append_results(title, [row], a.arch, dry=a.dry)
    return 0


if __name__ == "__main__":
    sys.exit(main())

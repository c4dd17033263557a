"""Cold compile time per kernel, two trees side by side: each scene's first launches in fresh processes with an
EMPTY Taichi offline cache (what CI and a user's first run pay), trees alternated A B A B ...

A kernel's first launch compiles it (Taichi's IR passes and LLVM, plus the front end); every launch of 0.3 s or
more is recorded under the kernel's name. Scenes (CPU, float32, one thread, i.e. the serial compiled forms):
``gas``, one step of the flow_throughput bed on 8x8x16 cells (cut cells, inlet, outlet); ``dem``, one advance of a
5000-grain frictional bed with epsd rolling (sorted: n >= dem.sort_min_grains); ``coupling``, one coupling step
(deposit with the void fraction, exchange with the drag on the gas) of coupled_step.py's bed at 2000 grains.
Medians over ``--pairs``.

    git archive HEAD~1 app | tar -x -C /tmp/old
    python benchmarks/compile_cost.py --a /tmp/old --b . --scenes gas dem coupling --pairs 1
"""
from __future__ import annotations

import argparse
import json
import os
import pathlib
import statistics
import subprocess
import sys
import tempfile

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.bench.common import append_results  # noqa: E402

CHILD = r"""
import json, sys, time
tree, scene, bench = sys.argv[1], sys.argv[2], sys.argv[3]
sys.path[:0] = [tree, bench, bench + "/liggghts"]
from app.sim import runtime
runtime.init("cpu", "float32", 1)
import taichi as ti
from taichi.lang import kernel_impl
times = {}
def timing(fn, name_of):
    # fn, recording under name_of(self) every call of 0.3 s or more
    def timed(self, *a):
        t0 = time.perf_counter()
        try:
            return fn(self, *a)
        finally:
            dt = time.perf_counter() - t0
            if dt > 0.3:
                times[name_of(self)] = times.get(name_of(self), 0.0) + dt
    return timed
kernel_impl.Kernel.launch_kernel = timing(kernel_impl.Kernel.launch_kernel, lambda k: k.func.__qualname__)
try:  # a kernel's later template instances compile in the plan's fetch (app.sim.launch), not in Taichi's launch
    from app.sim import launch as _launch
    _launch.FastKernel._compiled_data = timing(_launch.FastKernel._compiled_data, lambda k: k.__name__)
except (ImportError, AttributeError):
    pass
t0 = time.perf_counter()
if scene == "gas":
    import flow_throughput as ft
    s, bed, eps, rng = ft.scene((8, 8, 16), 1e-6)
    s.step(ft.DT)
elif scene == "coupling":
    import coupled_step
    from app.scene import build_simulation
    sim = build_simulation(coupled_step.scene_for(2000, "float32", 1))
    t0 = time.perf_counter()  # the coupling's kernels only (the scene's set-up compiles others)
    times.clear()
    sim.coupler.step(4e-4)
else:
    import dem_ab
    dem = dem_ab.solver("app", 5000, False, "float32", rolling=True)
    dem.advance(1)
ti.sync()
times["(whole first step)"] = time.perf_counter() - t0
print("RESULT " + json.dumps(times))
"""


def cold(tree: str, scene: str) -> dict:
    with tempfile.TemporaryDirectory(prefix="ticache_") as cache:
        env = dict(os.environ, TI_OFFLINE_CACHE_FILE_PATH=cache)
        out = subprocess.run([sys.executable, "-c", CHILD, str(pathlib.Path(tree).resolve()), scene,
                              str(ROOT / "benchmarks")], capture_output=True, text=True, env=env, cwd=tempfile.gettempdir())
    for line in out.stdout.splitlines():
        if line.startswith("RESULT "):
            return json.loads(line[7:])
    raise SystemExit(f"{tree} {scene}: no result\n{out.stderr[-3000:]}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--a", required=True, help="tree A (a folder holding app/)")
    ap.add_argument("--b", default=str(ROOT), help="tree B (default: this one)")
    ap.add_argument("--scenes", nargs="+", default=["gas", "dem"], choices=("gas", "dem", "coupling"))
    ap.add_argument("--pairs", type=int, default=1)
    ap.add_argument("--top", type=int, default=8, help="kernels listed per scene (the slowest in A)")
    ap.add_argument("--no-append", action="store_true")
    a = ap.parse_args(argv)
    rows = []
    for scene in a.scenes:
        runs = {"A": [], "B": []}
        for p in range(a.pairs):
            for k in (("A", "B") if p % 2 == 0 else ("B", "A")):
                runs[k].append(cold(a.a if k == "A" else a.b, scene))
                print(scene, k, runs[k][-1], flush=True)
        names = sorted(runs["A"][0], key=lambda n: -runs["A"][0][n])[:a.top + 1]
        for name in names:
            va = statistics.median(r.get(name, 0.0) for r in runs["A"])
            vb = statistics.median(r.get(name, 0.0) for r in runs["B"])
            rows.append({"scene": scene, "kernel (first launch)": name, "A s": f"{va:.1f}", "B s": f"{vb:.1f}",
                         "A/B": f"{va / vb:.2f}" if vb > 0 else "-"})
    title = (f"Cold compile time per kernel (cpu, float32, one thread; empty offline cache; A = {a.a}, B = {a.b}; "
             f"median of {a.pairs} alternated process(es) each)")
    append_results(title, rows, "cpu", dry=a.no_append)


if __name__ == "__main__":
    main()

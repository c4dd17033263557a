"""Which of the host's calls let another Python thread run (release the GIL): what a thread beside the hot loop,
such as the rCFD probe's writer (app/rcfd_probe.py), can overlap. For each call, a pure-Python counting loop on a
second thread is timed while the main thread repeats the call for ``--seconds``, against the same loop with the
main thread asleep: a ratio near 1 says the call lets the loop run, near 0 that it holds the GIL throughout.

Calls: a Taichi kernel on the CPU backend (one thread), its ``to_numpy`` copy, and the numpy and h5py work of the
probe's frame boundary on a million grains (``np.bincount`` with weights, ``np.unique`` with the inverse, a stable
``np.argsort``, a gzip-1 + shuffle HDF5 append of 4 MB).

    python3 benchmarks/gil_hold.py --seconds 1.0
"""
from __future__ import annotations

import argparse
import pathlib
import sys
import tempfile
import threading
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from app.bench.common import append_results  # noqa: E402


def loop_rate(call, seconds: float) -> float:
    """Counts a second of a pure-Python loop on a second thread while the main thread repeats ``call``."""
    stop, count = threading.Event(), [0]

    def spin():
        while not stop.is_set():
            count[0] += 1

    th = threading.Thread(target=spin)
    th.start()
    time.sleep(0.05)
    c0, t0 = count[0], time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        call()
    c1, t1 = count[0], time.perf_counter()
    stop.set()
    th.join()
    return (c1 - c0) / (t1 - t0)


def calls(n: int, tmp: str) -> list:
    import h5py
    import taichi as ti

    ti.init(arch=ti.cpu, cpu_max_num_threads=1, log_level=ti.WARN, offline_cache=False)
    a = ti.field(ti.f32, n)

    @ti.kernel
    def work():
        for i in a:
            s = 0.0
            for k in range(64):
                s += ti.sin(i * 1e-3 + k)
            a[i] = s

    work()
    rng = np.random.default_rng(0)
    cells = rng.integers(0, 86016, n)
    w = rng.uniform(4e-10, 1.1e-9, n)
    keys = rng.integers(0, 86016 ** 2, n // 10)
    f = h5py.File(f"{tmp}/g.h5", "w")
    ds = f.create_dataset("c", shape=(0, n), maxshape=(None, n), dtype="i4", chunks=(1, n), compression="gzip",
                          compression_opts=1, shuffle=True)
    c32 = cells.astype(np.int32)

    def append():
        ds.resize((ds.shape[0] + 1, n))
        ds[-1] = c32

    def kernel():
        work()
        ti.sync()

    return [("Taichi kernel call (cpu, 1 thread)", kernel), ("Taichi to_numpy", a.to_numpy),
            ("np.bincount, weights", lambda: np.bincount(cells, weights=w, minlength=86016)),
            ("np.unique, return_inverse (n/10 keys)", lambda: np.unique(keys, return_inverse=True)),
            ("np.argsort, stable (n/10 keys)", lambda: np.argsort(keys, kind="stable")),
            ("h5py append, gzip 1 + shuffle (4 MB)", append)], f


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=1000000)
    ap.add_argument("--seconds", type=float, default=1.0)
    ap.add_argument("--no-append", action="store_true")
    a = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        todo, f = calls(a.n, tmp)
        free = loop_rate(lambda: time.sleep(0.01), a.seconds)
        rows = []
        for name, call in todo:
            call()  # warm (to_numpy compiles its copy on the first call)
            t0 = time.perf_counter()
            call()
            one = time.perf_counter() - t0
            r = loop_rate(call, a.seconds)
            rows.append({"call": name, "one call ms": f"{1e3 * one:.1f}", "loop beside it / beside a sleep":
                         f"{r / free:.3f}"})
            print(rows[-1], flush=True)
        f.close()
    append_results(f"The GIL: a pure-Python loop on a second thread while the main thread repeats a call, against "
                   f"while it sleeps (cpu; {a.n} elements; {a.seconds:g} s each)", rows, "cpu", dry=a.no_append)
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""The rCFD recording probe's host work per frame (app/rcfd_probe.py) for a million grains: each grain's cell and
octant, and the frame's volume shifts, as the probe did them before 2026-12-06 (two floors; np.unique over every
grain's (start cell, end cell) pair) against now (one floor on the half-cells; ``shift_sums``, which sorts only
the grains that changed cell). Numpy only; the same arrays are checked equal.

The grains: ``--n`` at random in the poppy-seed column's recorded region (32 x 32 x 84 cells of 3 mm), a fraction
``--moved`` of them one to three cells from where they started the frame. Medians of ``--repeats``, alternated.

    python3 benchmarks/rcfd_frame_cost.py --n 1000000 --moved 0.1

``--h5`` times instead the probe's host work at a frame boundary (``RcfdRecorder._boundary``: cells, octants,
the three per-cell volume sums, the volume shifts and the appends to rcfd.h5, with ``app.rcfd_probe.H5_FILTERS``)
over ``--frames`` frames, for grains numbered at random and in cell order (as a fill numbers them): all of it waited
for in the loop, against the probe as it runs (its writer thread's share overlapping the next frame's steps), set by
set in turn. ``--between`` seconds stand for a frame's fluid steps: ``--steps sleep`` (the GIL free, as while the
host waits on a GPU outside Python) or ``--steps python`` (a pure-Python loop, the GIL held, as while the host
launches kernels: Taichi holds the GIL for a whole kernel call, measured on its CPU backend). Each frame gives the
calling thread's time in the boundary and the frame's wall time beyond the steps' own (what the writer thread took
from a GIL-holding loop counts there). Checks that the files hold the same arrays. The solvers are a stand-in (the
probe's numpy floors for the cells, radii, a bed height).

``--device`` times the probe's read of a frame's grains from a real DEM (``--arch``, float32): the positions and
flags read back and the cells, octants and tag computed in numpy (the probe before 2026-12-06) against
``DemSolver.tracked_cells`` (computed on the device, ~6 bytes a grain read back), on ``--n`` grains of the poppy
seeds at random in the poppy column, nine in ten of them tracked; checks both give the same integers.
"""
from __future__ import annotations

import argparse
import pathlib
import statistics
import sys
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from app.bench.common import alternated_ms, append_results  # noqa: E402
from app.rcfd_probe import RcfdRecorder, shift_sums  # noqa: E402


def before(rec, x, c_start, vol):
    q = np.floor((x - rec.origin) / rec.h).astype(np.int64)
    for a in range(3):
        np.clip(q[:, a], 0, rec.shape[a] - 1, out=q[:, a])
    cells = (q[:, 0] * rec.shape[1] + q[:, 1]) * rec.shape[2] + q[:, 2]
    q = np.floor((x - rec.origin) / (0.5 * rec.h)).astype(np.int64)
    for a in range(3):
        np.clip(q[:, a], 0, 2 * rec.shape[a] - 1, out=q[:, a])
    octant = (((q[:, 0] & 1) << 2) | ((q[:, 1] & 1) << 1) | (q[:, 2] & 1)).astype(np.uint8)
    keys, inv = np.unique(c_start * rec.n + cells, return_inverse=True)
    return cells, octant, keys, np.bincount(inv, weights=vol)


def after(rec, x, c_start, vol):
    cells, octant = rec.cells_and_octants(x)
    keys, w = shift_sums(c_start, cells, vol, rec.n)
    return cells, octant, keys, w


class _Stand:
    """What the probe reads from a simulation, from numpy: the tracked grains' cells (the probe's own floors),
    their radii, a bed height."""

    def __init__(self, x, r):
        self.x, self.r, self.time, self.ids = x, r, 0.0, None

    def read(self, what):
        if what == "alive":
            return np.ones(len(self.x), bool)
        if what == "track":
            return self.track
        if what == "cells":
            return self.cells
        if what == "radii":
            return self.r
        if what == "bed_height":
            return 0.13
        raise KeyError(what)

    def track(self, ids):
        self.ids = ids

    def cells(self, origin, h, shape, tag):
        from app.rcfd.database import tag_mask

        rec = RcfdRecorder.__new__(RcfdRecorder)
        rec.origin, rec.h, rec.shape = origin, h, shape
        x = self.x[self.ids]
        c, o = rec.cells_and_octants(x)
        return c, o, np.ones(len(x), bool), tag_mask("xyz"[tag[0]] + tag[1] + repr(tag[2]), x)


def python_steps(seconds: float):
    """A stand-in for a frame's fluid steps that holds the GIL, as a host-bound launch loop does: a pure-Python
    loop of as many iterations as take about ``seconds``. Returns the function that runs it and its median time
    alone (timed here, the writer thread idle)."""
    def spin(k):
        x = 0
        for i in range(k):
            x += i & 7
        return x

    def timed(k):
        t0 = time.perf_counter()
        spin(k)
        return time.perf_counter() - t0

    timed(200_000)  # warm
    k = int(200_000 * seconds / min(timed(200_000) for _ in range(3)))
    alone = statistics.median(timed(k) for _ in range(5))  # what the frame's steps take alone
    return (lambda: spin(k)), alone


def h5_frames(path, filters, frames, r, eps, shape, origin, h, in_loop, between, steps="sleep"):
    """Run the probe's boundary work over ``frames`` (positions) into ``path`` with ``filters``: per frame, the ms
    the calling thread spends in the boundary, and the ms the frame (boundary and steps) takes beyond the steps
    alone. ``in_loop``: each boundary's work waited for at once (as the probe wrote before its writer thread); else
    the writer thread's share overlaps ``between`` seconds standing for the next frame's fluid steps: ``steps``
    "sleep" (the GIL free, as while a GPU works and the host waits outside Python) or "python" (the GIL held, as
    while the host launches kernels: :func:`python_steps`)."""
    import app.rcfd_probe as probe

    rec = RcfdRecorder.__new__(RcfdRecorder)
    rec.origin, rec.h, rec.shape = origin, h, shape
    rec.n = int(np.prod(shape))
    rec.spf, rec.step, rec.t0, rec.tag, rec.axis = 5, 1e-3, 0.0, "z<0.065", np.zeros(2)
    rec.fluxes, rec.grain_cells, rec.path = False, True, pathlib.Path(path)
    rec.rate_sq_frame, rec.rate_samples_frame, rec.prev_boundary_eps, rec.open_frame = 0.0, 0, None, None
    rec._tracking, rec._writer, rec._pending, rec.samples, rec.log = None, None, None, 0, None
    rec._flushed = time.perf_counter()
    kept, read = probe.H5_FILTERS, probe.read_solvers
    probe.H5_FILTERS = filters
    probe.read_solvers = lambda sim, what: sim.read(what)
    try:
        rec._open(np.ones(shape, np.float32), None)
        rec._boundaries, rec._shifts = 0, 0
        stand, times, excess = _Stand(frames[0], r), [], []
        run_steps, alone = python_steps(between) if steps == "python" else ((lambda: time.sleep(between)), between)
        for k, x in enumerate(frames):
            stand.x, stand.time = x, 5e-3 * k
            t0 = time.perf_counter()
            rec._boundary(stand, eps)
            if in_loop:
                rec._drain()
                rec.f.flush()
            t1 = time.perf_counter()
            run_steps()
            t2 = time.perf_counter()
            times.append(t1 - t0)
            excess.append(t2 - t0 - alone)  # the boundary, and what the writer thread took from the steps
        rec.finish(None, "done")
    finally:
        probe.H5_FILTERS, probe.read_solvers = kept, read
    return [1e3 * t for t in times], [1e3 * t for t in excess]


def h5_main(a) -> int:
    import tempfile

    import h5py

    import app.rcfd_probe as probe

    shape, origin, h = (32, 32, 84), np.array([-0.048, -0.048, 0.0]), 0.003
    hi = np.array([0.048, 0.048, 0.252])
    rng = np.random.default_rng(2)
    r = rng.choice([0.4595e-3, 0.525e-3, 0.6345e-3], a.n)
    x0 = origin + rng.uniform(0.0, 1.0, (a.n, 3)) * (hi - origin)
    eps = rng.uniform(0.4, 1.0, shape)
    variants = (("in the loop", probe.H5_FILTERS, True), ("writer thread", probe.H5_FILTERS, False))
    rows, same = [], True
    for order in ("random", "cell"):
        x = x0 if order == "random" else x0[np.lexsort((x0[:, 2], x0[:, 1], x0[:, 0]))]
        frames = [x]
        for _ in range(a.frames - 1):
            step = rng.choice([-1, 1], (a.n, 3)) * h * (rng.uniform(size=(a.n, 1)) < a.moved)
            frames.append(np.clip(frames[-1] + step, origin, hi - 1e-9).astype(np.float32))
        with tempfile.TemporaryDirectory() as tmp:
            t = {v[0]: ([], []) for v in variants}
            for rep in range(a.repeats):
                for i, (name, filt, in_loop) in enumerate(variants):
                    bound, excess = h5_frames(f"{tmp}/{i}.h5", filt, frames, r, eps, shape, origin, h, in_loop,
                                              a.between, a.steps)
                    t[name][0].extend(bound)
                    t[name][1].extend(excess)
            sizes = [pathlib.Path(f"{tmp}/{i}.h5").stat().st_size / a.frames / 1e6 for i in range(len(variants))]
            files = [h5py.File(f"{tmp}/{i}.h5") for i in range(len(variants))]
            names = []
            files[0].visititems(lambda n, o: names.append(n) if isinstance(o, h5py.Dataset) else None)
            eq = all(np.array_equal(files[0][n][...], g[n][...]) for g in files[1:] for n in names)
            for g in files:
                g.close()
        same &= eq
        row = {"N": a.n, "grain order": order, "frames": a.frames, "steps": a.steps}
        for (name, _, _), size in zip(variants, sizes):
            row[f"{name}: boundary ms"] = f"{statistics.median(t[name][0]):.1f}"
            row[f"{name}: frame ms beyond the steps"] = f"{statistics.median(t[name][1]):.1f}"
        row["MB/frame"] = f"{sizes[-1]:.2f}"
        row["same arrays"] = "yes" if eq else "NO"
        rows.append(row)
        print(row, flush=True)
    stand = "sleep" if a.steps == "sleep" else "a pure-Python loop (the GIL held)"
    append_results(f"rCFD recording probe, the calling thread's time per frame boundary and the frame's time beyond "
                   f"its steps, incl. the rcfd.h5 appends (numpy and h5py; grains in the poppy column's 32 x 32 x 84 "
                   f"cells, {a.moved:g} of them one cell further each frame; {a.between:g} s of {stand} between "
                   f"boundaries for the fluid steps; median over {a.repeats} x {a.frames} frames)", rows, "cpu",
                   dry=a.no_append)
    return 0 if same else 1


def device_main(a) -> int:
    from mri_frame_cost import poppy_dem  # benchmarks/, this script's folder

    from app.config import load
    from app.rcfd.database import parse_tag, tag_mask
    from app.sim import runtime

    arch = runtime.init(a.arch, "float32")
    cfg = load(ROOT / "presets" / "mri_poppy.toml")
    rng = np.random.default_rng(1)
    dem = poppy_dem(cfg, a.n, 0.3, rng)
    rec = RcfdRecorder.__new__(RcfdRecorder)
    rec.origin, rec.h, rec.shape = np.array([-0.048, -0.048, 0.0]), 0.003, (32, 32, 84)
    tag = "z<0.065"
    ids = np.nonzero(rng.uniform(size=a.n) < 0.9)[0]
    dem.track(ids)

    def host():
        x, alive = dem.read("position"), dem.read("alive").astype(bool)
        xi = x[ids]
        c, o = rec.cells_and_octants(xi)
        return c, o, alive[ids], tag_mask(tag, xi)

    def device():
        return dem.tracked_cells(rec.origin, rec.h, rec.shape, parse_tag(tag))

    same = all(np.array_equal(u, v) for u, v in zip(host(), device()))
    ms = alternated_ms({"host": host, "device": device}, a.repeats)
    h, d = ms["host"], ms["device"]
    row = {"N": a.n, "tracked": ids.size, "host ms/frame": f"{h:.1f}", "device ms/frame": f"{d:.1f}",
           "host / device": f"{h / d:.2f}", "same integers": "yes" if same else "NO"}
    print(row, flush=True)
    append_results(f"rCFD recording probe, a frame's grain cells: positions read back and numpy against "
                   f"DemSolver.tracked_cells ({arch}, float32; random poppy seeds in the poppy column's 32 x 32 x 84 "
                   f"cells of 3 mm; median of {a.repeats})", [row], arch, dry=a.no_append)
    return 0 if same else 1


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=1000000)
    ap.add_argument("--moved", type=float, default=0.1, help="fraction of the grains that change cell in the frame")
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--no-append", action="store_true")
    ap.add_argument("--h5", action="store_true", help="the whole boundary work with the rcfd.h5 appends, filters before/after")
    ap.add_argument("--frames", type=int, default=6, help="with --h5: frames per set")
    ap.add_argument("--between", type=float, default=0.3, help="with --h5: seconds between boundaries (the steps)")
    ap.add_argument("--steps", default="sleep", choices=("sleep", "python"),
                    help="with --h5: what stands for the steps: a sleep (the GIL free) or a Python loop (held)")
    ap.add_argument("--device", action="store_true", help="a frame's grain cells from a real DEM: host against device")
    ap.add_argument("--arch", default="cpu", choices=("cpu", "cuda"), help="with --device")
    a = ap.parse_args(argv)
    if a.h5:
        return h5_main(a)
    if a.device:
        return device_main(a)
    rec = RcfdRecorder.__new__(RcfdRecorder)
    rec.origin, rec.h, rec.shape = np.array([-0.048, -0.048, 0.0]), 0.003, (32, 32, 84)
    rec.n = int(np.prod(rec.shape))
    rng = np.random.default_rng(2)
    hi = np.array([0.048, 0.048, 0.252])
    x0 = (rec.origin + rng.uniform(0.0, 1.0, (a.n, 3)) * (hi - rec.origin)).astype(np.float32)
    step = rng.choice([-1, 1], (a.n, 3)) * rng.integers(1, 4, (a.n, 3)) * rec.h * (rng.uniform(size=(a.n, 1)) < a.moved)
    x = (x0 + step).astype(np.float32)
    vol = rng.choice([4.07e-10, 6.06e-10, 1.07e-9], a.n)
    c_start = rec.cells_and_octants(x0)[0]
    same = all(np.array_equal(u, v) for u, v in zip(before(rec, x, c_start, vol), after(rec, x, c_start, vol)))
    ms = alternated_ms({"before": lambda: before(rec, x, c_start, vol), "after": lambda: after(rec, x, c_start, vol)},
                       a.repeats)
    b, c = ms["before"], ms["after"]
    moved = float(np.mean(c_start != rec.cells_and_octants(x)[0]))
    row = {"N": a.n, "grains that changed cell": f"{moved:.2f}", "before ms/frame": f"{b:.1f}",
           "after ms/frame": f"{c:.1f}", "before / after": f"{b / c:.2f}", "same arrays": "yes" if same else "NO"}
    print(row, flush=True)
    append_results(f"rCFD recording probe, host work per frame: cells, octants and volume shifts (numpy; random "
                   f"grains in the poppy column's 32 x 32 x 84 recorded cells; median of {a.repeats})", [row], "cpu",
                   dry=a.no_append)
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())

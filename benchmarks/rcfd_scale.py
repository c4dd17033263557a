"""`fbed rcfd analyze` and `fbed rcfd run` on a synthetic database the size of the poppy-seed bed's, on the CPU.

The device plan's mri_rcfd stage (benchmarks/device_run.sh) runs these two commands on the million-grain database a
GPU run records (issue 20). This builds a database of that size without one and times the commands on it, with their
peak memory, so what does not scale shows here first, not in a 10-minute device command. The grains: ``--grains``
in three volume classes (35/32/33%, as the poppy seeds) in a 96 mm cylinder of 3 mm cells, 130 mm deep, recorded
below 0.25 m (32 x 32 x 84 cells); each moves with a recurring circulation (two counter-rotating rolls that
swell and shrink with a period of 0.25 s, 3 mm amplitude) plus a random walk (0.3 mm a frame), so states recur
and the bed mixes; ``--states`` boundaries 5 ms apart, no gas fluxes. Not a bed's physics: the sizes, the shares
of grains that change cell per frame (printed), and the commands' costs.

    python3 benchmarks/rcfd_scale.py                       # 958,000 grains, 300 states, 5 paths of 10 s
    python3 benchmarks/rcfd_scale.py --grains 50000 --states 120 --horizon 2 --dry

Appends to benchmarks/RESULTS.md (unless --dry): the database's build time and size, each command's wall time and
peak memory (its process's maximum resident set), and the run's own account (prep, jumps, transport).
"""
from __future__ import annotations

import argparse
import json
import os
import pathlib
import resource
import subprocess
import sys
import time

import h5py
import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.bench.common import append_results  # noqa: E402

H = 3.0e-3  # [m] cell
SHAPE = (32, 32, 84)  # 96 mm x 96 mm x 252 mm
RADIUS, DEPTH = 0.048, 0.13  # [m]
DT = 5.0e-3  # [s] frame


def positions(grains: int, states: int, rng):
    """Yield each state's (grains, 3) positions [m]: circulation plus a random walk, kept in the bed."""
    r = RADIUS * np.sqrt(rng.random(grains)) * 0.98
    a = 2 * np.pi * rng.random(grains)
    base = np.stack([r * np.cos(a), r * np.sin(a), DEPTH * rng.random(grains)], 1)
    walk = np.zeros_like(base)
    for b in range(states):
        phase = 2 * np.pi * b * DT / 0.25
        x, z = base[:, 0] / RADIUS, base[:, 2] / DEPTH
        roll = 3e-3 * np.sin(phase) * np.stack([np.sin(np.pi * x) * np.cos(np.pi * z), 0 * x,
                                                -np.cos(np.pi * x) * np.sin(np.pi * z)], 1)
        walk += 3e-4 * rng.standard_normal(walk.shape)
        p = base + walk + roll
        rr = np.hypot(p[:, 0], p[:, 1])
        out = rr > RADIUS * 0.98  # reflected into the cylinder and the bed
        p[out, :2] *= ((2 * RADIUS * 0.98 - rr[out]) / rr[out])[:, None]
        p[:, 2] = np.abs(p[:, 2])
        p[:, 2] = np.where(p[:, 2] > DEPTH, 2 * DEPTH - p[:, 2], p[:, 2])
        walk = p - base - roll
        yield p


def write_database(path: pathlib.Path, grains: int, states: int, seed: int = 1) -> dict:
    """rcfd.h5 in app/rcfd/database.py's layout; the share of the grain volume that changes cell per frame."""
    rng = np.random.default_rng(seed)
    origin = np.array([-RADIUS, -RADIUS, 0.0])
    n = int(np.prod(SHAPE))
    idx = np.indices(SHAPE).reshape(3, -1).T
    centre = origin + (idx + 0.5) * H
    open_volume = (np.hypot(centre[:, 0], centre[:, 1]) < RADIUS).astype(np.float32).reshape(SHAPE)
    vol = (rng.choice([0.919, 1.050, 1.269], grains, p=[0.35, 0.32, 0.33]) * 1e-3) ** 3 * np.pi / 6
    tag0 = None
    moved = []
    with h5py.File(path, "w") as f:
        f.attrs.update(h=H, origin=origin, shape=SHAPE, frame_interval=DT, step=1e-3, axis=[0.0, 0.0],
                       tag="z<0.065", rcfd_from=0.0, settings=json.dumps({}), grains=grains,
                       frame_check="ok", taylor_time=0.05, taylor_time_frame=0.05, taylor_samples=states)
        f["geometry/open_volume"] = open_volume
        ds = {k: f.create_dataset(f"boundary/{k}", (states, n), "f4", chunks=(1, n), compression="gzip")
              for k in ("solid", "tag_now", "tagged")}
        eps = f.create_dataset("boundary/eps", (states,) + SHAPE, "f4", chunks=(1,) + SHAPE, compression="gzip")
        cells_ds = f.create_dataset("boundary/cells", (states, grains), "i4", chunks=(1, grains), compression="gzip")
        oct_ds = f.create_dataset("boundary/octant", (states, grains), "u1", chunks=(1, grains), compression="gzip")
        f["grains_counted"] = np.arange(grains, dtype=np.int32)
        f["grains_volume"] = vol
        c0s, c1s, ws, off, last, heights = [], [], [], [0], None, []
        for b, p in enumerate(positions(grains, states, rng)):
            ijk = np.clip(((p - origin) / H).astype(np.int64), 0, np.array(SHAPE) - 1)
            c = (ijk[:, 0] * SHAPE[1] + ijk[:, 1]) * SHAPE[2] + ijk[:, 2]
            frac = (p - origin) / H - ijk
            cells_ds[b] = c
            oct_ds[b] = ((frac[:, 0] >= 0.5) * 4 + (frac[:, 1] >= 0.5) * 2 + (frac[:, 2] >= 0.5)).astype(np.uint8)
            solid = np.bincount(c, vol, n)
            ds["solid"][b] = solid
            tag_now = p[:, 2] < 0.065
            tag0 = tag_now if tag0 is None else tag0
            ds["tag_now"][b] = np.bincount(c, vol * tag_now, n)
            ds["tagged"][b] = np.bincount(c, vol * tag0, n)
            eps[b] = np.clip(1.0 - solid / (H ** 3), 0.3, 1.0).reshape(SHAPE)
            heights.append(float(np.percentile(p[:, 2], 95)))
            if last is not None:
                keys, inv = np.unique(last * n + c, return_inverse=True)
                c0s.append(keys // n), c1s.append(keys % n), ws.append(np.bincount(inv, vol))
                off.append(off[-1] + keys.size)
                moved.append(float(vol[last != c].sum() / vol.sum()))
            last = c
        f["grains_tagged"] = np.nonzero(tag0)[0].astype(np.int32)
        f["boundary/time"] = np.arange(states) * DT
        f["boundary/bed_height"] = np.asarray(heights)
        f["frame/b0"] = np.arange(states - 1, dtype=np.int32)
        f["frame/b1"] = np.arange(1, states, dtype=np.int32)
        f["frame/offset"] = np.asarray(off, np.int64)
        f["shift/c0"] = np.concatenate(c0s).astype(np.int32)
        f["shift/c1"] = np.concatenate(c1s).astype(np.int32)
        f["shift/w"] = np.concatenate(ws)
    return {"moved_share_per_frame": float(np.mean(moved))}


def _reused(path: pathlib.Path, a) -> dict | None:
    """The info of the database at ``path`` when an earlier call built it with these grains and states."""
    try:
        with h5py.File(path, "r") as f:
            info = json.loads(f.attrs["synthetic"])
            return info if f.attrs["grains"] == a.grains and info["states"] == a.states else None
    except (OSError, KeyError, ValueError):
        return None


def timed(cmd: list[str]) -> dict:
    """Run a command: its wall time [s], peak resident memory [GB] and rc. The peak is the largest resident set of
    any process this script has waited for so far (the OS keeps no other): analyze's, then the larger of analyze's
    and run's."""
    t = time.perf_counter()
    r = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
    peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    if r.returncode:
        print(r.stdout[-2000:], r.stderr[-4000:], file=sys.stderr)
    return {"seconds": time.perf_counter() - t, "peak_GB": peak / 1e6, "rc": r.returncode,
            "out": r.stdout}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--grains", type=int, default=958_000)
    ap.add_argument("--states", type=int, default=300)
    ap.add_argument("--horizon", type=float, default=10.0, help="[s] each path's")
    ap.add_argument("--paths", type=int, default=5)
    ap.add_argument("--out", default="runs/rcfd_scale", help="the database's run folder")
    ap.add_argument("--reuse", action="store_true", help="keep the database of an earlier call of the same size")
    ap.add_argument("--dry", action="store_true", help="print, do not append to RESULTS.md")
    a = ap.parse_args(argv)
    od = ROOT / a.out
    od.mkdir(parents=True, exist_ok=True)
    (od / "rcfd").mkdir(exist_ok=True)
    (od / "rcfd" / "matchings.h5").unlink(missing_ok=True)  # cold: every jump built
    t = time.perf_counter()
    info = _reused(od / "rcfd.h5", a) if a.reuse else None
    if info is None:
        info = write_database(od / "rcfd.h5", a.grains, a.states)
        with h5py.File(od / "rcfd.h5", "a") as f:
            f.attrs["synthetic"] = json.dumps(info | {"states": a.states})
    build = time.perf_counter() - t
    size = (od / "rcfd.h5").stat().st_size / 1e9
    print(f"database: {a.grains:,} grains, {a.states} states, {size:.2f} GB in {build:.0f} s; "
          f"{info['moved_share_per_frame']:.3f} of the grain volume changes cell per frame", flush=True)
    an = timed([sys.executable, "-m", "app", "rcfd", "analyze", str(od)])
    print(f"analyze: {an['seconds']:.1f} s, {an['peak_GB']:.2f} GB, exit {an['rc']}", flush=True)
    name = f"scale_T{a.horizon:g}_N{a.paths}"
    run = timed([sys.executable, "-m", "app", "rcfd", "run", str(od), "--horizon", str(a.horizon), "--paths",
                 str(a.paths), "--seed", "1", "--name", name])
    print(f"run: {run['seconds']:.1f} s, {run['peak_GB']:.2f} GB, exit {run['rc']}", flush=True)
    s = json.loads((od / "rcfd" / name / "summary.json").read_text()) if run["rc"] == 0 else {}
    keys = [k for k in s if any(w in k for w in ("seconds", "jump", "matchings", "cost"))]
    account = {k: s[k] for k in keys}
    print(json.dumps(account, indent=1)[:3000])
    row = {"grains": f"{a.grains:,}", "states": a.states, "paths x horizon": f"{a.paths} x {a.horizon:g} s",
           "workers": len(os.sched_getaffinity(0)), "database GB": f"{size:.2f}",
           "built in s": "reused" if a.reuse and build < 1 else f"{build:.0f}",
           "changes cell per frame": f"{info['moved_share_per_frame']:.3f}",
           "analyze s (peak GB)": f"{an['seconds']:.0f} ({an['peak_GB']:.1f})",
           "run s (peak GB)": f"{run['seconds']:.0f} ({run['peak_GB']:.1f})",
           "jumps built": s.get("matchings", {}).get("used", "-"),
           "jumps s (wall)": f"{s['cost']['stitch_seconds']:.0f}" if "cost" in s else "-",
           "transport s per path-second": f"{s['cost']['rcfd_wall_per_simulated_second_per_path']:.2f}"
           if "cost" in s else "-"}
    print(row)
    if an["rc"] == 0 and run["rc"] == 0:
        append_results("rCFD at the poppy bed's size: `fbed rcfd analyze` and `run` on a synthetic database "
                       "(benchmarks/rcfd_scale.py)", [row], "cpu", dry=a.dry)
    return 0 if an["rc"] == 0 and run["rc"] == 0 else 1


if __name__ == "__main__":
    sys.exit(main())

"""Shared by the benchmarks (the scripts in benchmarks/ and the benches of this package): the commit and the
machine a figure was measured on, appending a table to benchmarks/RESULTS.md, and the fairness helpers of a
side-by-side benchmark (a contact count any code can be judged by, the A B A B order, the pairwise ratio).

The scripts import it from the installed package (``pip install -e .``): ``from app.bench.common import
append_results``.
"""
from __future__ import annotations

import datetime
import os
import pathlib
import platform
import statistics
import subprocess
import time

import numpy as np
from scipy.spatial import cKDTree

ROOT = pathlib.Path(__file__).resolve().parents[2]   # the checkout (an editable install runs from it)
RESULTS = ROOT / "benchmarks" / "RESULTS.md"


def commit(dirty: bool = True) -> str:
    """The checkout's short commit hash, with '+dirty' when tracked files differ from it (``dirty``), or
    $FBED_COMMIT where the checkout has no .git (a snapshot, the GPU machine's copy), or 'unknown'."""
    if os.environ.get("FBED_COMMIT"):
        return os.environ["FBED_COMMIT"]
    try:
        out = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                             cwd=ROOT, timeout=10).stdout.strip()
        changed = dirty and subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"],
                                           capture_output=True, text=True, cwd=ROOT, timeout=10).stdout.strip()
        return out + ("+dirty" if changed else "") if out else "unknown"
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def cpu_model() -> str:
    try:
        for line in pathlib.Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def gpu_name() -> str:
    try:
        out = subprocess.run(["nvidia-smi", "--query-gpu=name", "--format=csv,noheader"], capture_output=True,
                             text=True, timeout=10).stdout.strip()
        return out.splitlines()[0] if out else "none"
    except (OSError, subprocess.TimeoutExpired):
        return "none"


def machine_line(arch: str) -> str:
    return f"CPU {cpu_model()} ({os.cpu_count()} cores); GPU {gpu_name() if arch == 'cuda' else 'not used'}"


def append_results(title: str, rows: list[dict], arch: str, dry: bool = False) -> str:
    if not rows:
        return ""
    cols = list(rows[0])
    lines = [f"### {title}", "",
             f"{datetime.date.today().isoformat()}, commit {commit()}, {machine_line(arch)}", "",
             "| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    lines += ["| " + " | ".join(str(r.get(c, "")) for c in cols) + " |" for r in rows]
    text = "\n".join(lines) + "\n\n"
    print(text)
    if not dry:
        if not RESULTS.exists():
            RESULTS.write_text("# Benchmark results\n\nAppended by the scripts in this folder; newest last.\n\n")
        with RESULTS.open("a") as f:
            f.write(text)
    return text


def count_contacts(position, radius, cylinder_radius: float | None = None, center=(0.0, 0.0),
                   floor_z: float | None = None) -> dict:
    """Contacts with an overlap > 0, counted from positions alone (the same count for any code).

    ``position`` (N,3) [m], ``radius`` [m] (one value or N); float32 positions are widened to float64
    exactly, so a code's rounding shows in its count. Pairs: centre distance < r_i + r_j (cKDTree).
    Walls, each when given: the floor z = ``floor_z`` (z - r < floor_z) and a z-cylinder of radius
    ``cylinder_radius`` [m] about ``center`` (r_xy + r > R). Returns pairs, floor, cylinder, walls, total.
    """
    pos = np.asarray(position, dtype=np.float64).reshape(-1, 3)
    r = np.broadcast_to(np.asarray(radius, dtype=np.float64), (len(pos),))
    pairs = 0
    if len(pos) > 1:
        ij = cKDTree(pos).query_pairs(2.0 * float(r.max()), output_type="ndarray")
        dx = pos[ij[:, 0]] - pos[ij[:, 1]]
        reach = r[ij[:, 0]] + r[ij[:, 1]]
        pairs = int(np.count_nonzero(np.einsum("ij,ij->i", dx, dx) < reach * reach))
    floor = int(np.count_nonzero(pos[:, 2] - r < floor_z)) if floor_z is not None else 0
    cylinder = 0
    if cylinder_radius is not None:
        rxy = np.hypot(pos[:, 0] - center[0], pos[:, 1] - center[1])
        cylinder = int(np.count_nonzero(rxy + r > cylinder_radius))
    return {"pairs": pairs, "floor": floor, "cylinder": cylinder, "walls": floor + cylinder,
            "total": pairs + floor + cylinder}


def interleaved(first: str, second: str, repeats: int) -> list[tuple[int, str]]:
    """The order in which a side-by-side benchmark runs two codes: (repeat, code) pairs, A B A B ...
    so that a drift in the machine's speed (load from others) falls on both alike."""
    return [(k, code) for k in range(repeats) for code in (first, second)]


def median_ratio(a: list[float], b: list[float]) -> tuple[float, float, float]:
    """Median, min and max of the pair-by-pair ratios a[k] / b[k] (pairs run next to each other)."""
    if len(a) != len(b) or not a:
        raise ValueError("need as many timings of each code, at least one")
    q = [x / y for x, y in zip(a, b)]
    return statistics.median(q), min(q), max(q)


def alternated_ms(calls: dict, repeats: int) -> dict:
    """Median wall time [ms] of each of ``calls`` (name -> callable of no argument), the calls run in turn
    (A B A B ..., as :func:`interleaved`) ``repeats`` times each."""
    t = {name: [] for name in calls}
    for _ in range(repeats):
        for name, f in calls.items():
            t0 = time.perf_counter()
            f()
            t[name].append(time.perf_counter() - t0)
    return {name: 1e3 * statistics.median(v) for name, v in t.items()}

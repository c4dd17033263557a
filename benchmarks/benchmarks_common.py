"""Shared by the benchmark scripts: machine description and appending to RESULTS.md."""
from __future__ import annotations

import datetime
import pathlib
import platform
import subprocess

RESULTS = pathlib.Path(__file__).resolve().parent / "RESULTS.md"


def commit() -> str:
    import os

    if os.environ.get("FBED_COMMIT"):  # set where the checkout has no .git (the GPU machine's copy)
        return os.environ["FBED_COMMIT"]
    try:
        out = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                             cwd=RESULTS.parent).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], capture_output=True,
                               text=True, cwd=RESULTS.parent).stdout.strip()
        return out + ("+dirty" if dirty else "") if out else "unknown"
    except OSError:
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
    import os

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

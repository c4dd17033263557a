"""What a device call would carry, against its 64 MiB: run it before a call, so that none is spent on a refusal.

A call on the lent GPU machine takes the working tree (tracked files and untracked ones git does not ignore) and
the ignored paths named in ``carry``, 64 MiB in all (../shared/device/README.md). The kit (.devkit, Taichi's wheel
for the device's Python) is 56.8 MB of it, so the tree goes with validation/ moved aside (12.5 MB of figures and
runs), and a carried bed must be small (`fbed pack`, 4.4 MB for the poppy bed at 0.5 um).

    python benchmarks/device_carry.py --carry .devkit runs/mri_bed.h5     # exit 1 when it does not fit

Prints the total, what is left, and the largest items.
"""
from __future__ import annotations

import argparse
import os
import pathlib
import subprocess
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]
LIMIT = 64 << 20  # bytes: what one call carries
KIT = 56_800_000  # bytes: .devkit as ../shared/device/prepare.sh built it on 2026-12-07 (when it is not here)


def tree_files(aside: list[str]) -> list[pathlib.Path]:
    """The files of the working tree a call takes: tracked, and untracked ones git does not ignore, less ``aside``."""
    out = subprocess.run(["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"], cwd=ROOT,
                         capture_output=True, check=True).stdout.decode()
    names = [n for n in out.split("\0") if n and not any(n == a.rstrip("/") or n.startswith(a.rstrip("/") + "/")
                                                         for a in aside)]
    return [ROOT / n for n in names if (ROOT / n).is_file()]


def size(p: pathlib.Path) -> int:
    if p.is_file():
        return p.stat().st_size
    return sum(f.stat().st_size for f in p.rglob("*") if f.is_file()) if p.is_dir() else 0


def carry_bytes(aside: list[str], carry: list[str]) -> tuple[int, list[tuple[int, str]]]:
    """(total bytes, [(bytes, item)] largest first): the tree's files by top folder, and each carried path."""
    by_top: dict[str, int] = {}
    for f in tree_files(aside):
        top = f.relative_to(ROOT).parts[0]
        by_top[top] = by_top.get(top, 0) + f.stat().st_size
    items = [(b, f"{t}/" if (ROOT / t).is_dir() else t) for t, b in by_top.items()]
    for c in carry:
        p = ROOT / c
        b = size(p) if p.exists() else (KIT if c.rstrip("/") == ".devkit" else 0)
        items.append((b, f"carry {c}" + ("" if p.exists() else " (not here: the kit's measured size)"
                                         if c.rstrip("/") == ".devkit" else " (not here)")))
    items.sort(reverse=True)
    return sum(b for b, _ in items), items


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--carry", nargs="*", default=[".devkit"], help="the call's carry paths (default: .devkit)")
    ap.add_argument("--aside", nargs="*", default=["validation"], help="folders moved aside before the call")
    a = ap.parse_args()
    total, items = carry_bytes(a.aside, a.carry)
    for b, name in items[:12]:
        print(f"{b / 1e6:9.2f} MB  {name}")
    left = LIMIT - total
    print(f"total {total / 1e6:.2f} MB of {LIMIT / 1e6:.2f} MB (64 MiB): {left / 1e6:.2f} MB "
          + ("left" if left >= 0 else "too much: move more aside or carry less"))
    return 0 if left >= 0 else 1


if __name__ == "__main__":
    os.chdir(ROOT)
    sys.exit(main())

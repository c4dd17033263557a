"""Back from the GPU sessions: their records files into run folders, each case's sessions pooled, the cases compared.

Each GPU session of the MRI study returns its law's records (`$OUT/mri_records_<law>.h5`, benchmarks/run_records.py);
a Verma session its planes (`$OUT/verma_records.h5`). This script does the rest in one command:

    python3 benchmarks/pool_sessions.py s1/mri_records_koch_hill.h5 s2/mri_records_koch_hill.h5 \
        s3/mri_records_beetstra.h5 ... --out runs/laws

- every file is unpacked into OUT/sessions/<name>-<k> (a run folder: run.h5, config.toml, summary.json);
- the sessions are grouped by case: the same preset and overrides, bar how each started, how long it ran and what
  else it recorded (``app.analysis.pooling``); a group is named by the case keys it differs from the others by
  (``coupling.drag``: koch_hill, ...);
- a group of several sessions is pooled into OUT/<name> (`fbed analyze RUN RUN --out`), a single one analysed in
  its own folder, moved to OUT/<name>;
- with several cases of the MRI analysis, they go side by side into OUT/compare (`fbed analyze ... --compare`).

Prints what it did; exits 1 when an analysis fails (its message says why).
"""
from __future__ import annotations

import argparse
import importlib.util
import pathlib
import shutil
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app import config as cfgmod  # noqa: E402
from app.analysis import pooling  # noqa: E402
from app.cli import main as fbed  # noqa: E402


def _records():
    spec = importlib.util.spec_from_file_location("run_records", ROOT / "benchmarks" / "run_records.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def groups_of(run_dirs: list[pathlib.Path]) -> dict[str, list[pathlib.Path]]:
    """The sessions by case, each case named by the values of the case keys that tell the cases apart."""
    cfgs = [cfgmod.load(d / "config.toml") for d in run_dirs]
    keys = pooling.keys_that_differ(cfgs)
    flats = [pooling.flat(c) for c in cfgs]
    out: dict[str, list[pathlib.Path]] = {}
    names: dict[tuple, str] = {}
    for d, f in zip(run_dirs, flats):
        values = tuple(repr(f.get(k)) for k in keys)
        if values not in names:  # named by its values where that reads well, else numbered
            name = "".join(c if c.isalnum() or c in "._-" else "_" for c in "-".join(str(f.get(k)) for k in keys))
            names[values] = name if 0 < len(name) <= 60 and name not in names.values() else f"case-{len(names) + 1}"
        out.setdefault(names[values], []).append(d)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("records", nargs="+", type=pathlib.Path, help="records files the sessions returned")
    ap.add_argument("--out", type=pathlib.Path, required=True, help="folder for the sessions, cases and comparison")
    a = ap.parse_args(argv)
    rr = _records()
    sessions = []
    for k, f in enumerate(a.records):
        d = a.out / "sessions" / f"{f.stem}-{k + 1}"
        rr.unpack(f, d)
        sessions.append(d)
    cases, kinds = {}, set()
    for name, dirs in groups_of(sessions).items():
        target = a.out / name
        kinds.add(cfgmod.load(dirs[0] / "config.toml").probes.analysis)
        if len(dirs) > 1:
            rc = fbed(["analyze", *map(str, dirs), "--out", str(target)])
        else:
            if target.exists():
                shutil.rmtree(target)
            shutil.copytree(dirs[0], target)
            rc = fbed(["analyze", str(target)])
        print(f"pool_sessions: {name}: {len(dirs)} session(s) -> {target} (exit {rc})")
        if rc:
            return 1
        cases[name] = target
    if len(cases) > 1 and kinds == {"mri"}:
        rc = fbed(["analyze", *map(str, cases.values()), "--compare", "--out", str(a.out / "compare")])
        print(f"pool_sessions: {len(cases)} cases side by side -> {a.out / 'compare'} (exit {rc})")
        return 1 if rc else 0
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Every preset key at the edges of its range, on a tiny fluidized bed: the run finishes, or it is refused naming
a key (exit 2), or the guard stops it naming a knob (exit 3). Never a traceback, a kill or a hang.

The schema (app/config/schema.py) gives each number a range; a value inside it must either run or be refused by a
rule that names the key. This sweep takes each scalar key of [run], [particles], [vessel], [contact], [dem],
[output], [guard], [probes], [gas] and [coupling] at its lower and upper bound (or, where a side is open, at 1e30
beyond it), each choice of a closed key and both values of a flag, plus a list of structured cases (inlets,
schedules, jets, periodic faces, probes), each as its own `fbed run` of presets/fluidize.toml cut to 300 grains
and 4 fluid steps, one CPU thread, two runs at a time, 300 s each (a case that fails runs again alone, 900 s, and
both outcomes are listed). [video] is left out (its keys only act with a
renderer; tests/test_render.py covers them).

A stop by the guard (exit 3) is listed for review: a value the schema takes that stops a run at once may want a
rule that refuses it up front (stop 54 turned five of them into rules).

    python3 benchmarks/schema_edges.py [--only SECTION] [--jobs 2]

Writes benchmarks/EDGES.md (the table and the failures) and exits 1 when any case failed the contract.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import pathlib
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from app.bench.common import append_results, machine_line  # noqa: E402
from app.config import schema  # noqa: E402

SECTIONS = {"run": schema.RunConfig, "particles": schema.ParticlesConfig, "vessel": schema.VesselConfig,
            "contact": schema.ContactConfig, "dem": schema.DemConfig, "output": schema.OutputConfig,
            "guard": schema.GuardConfig, "probes": schema.ProbesConfig, "gas": schema.GasConfig,
            "coupling": schema.CouplingConfig}
SKIP = {"run.duration", "run.threads"}  # the sweep's own settings
INLET = "boundary.bottom={kind='velocity_inlet',velocity=[0.0,0.0,1.0]"
STRUCTURED = [
    (INLET.replace("1.0]", "1e6]") + "}",), (INLET.replace("1.0]", "-1.0]") + "}",),
    (INLET + ",schedule=[[0.0,0.0],[0.001,1e9]]}",), (INLET + ",schedule=[[0.002,0.0],[0.001,1.0]]}",),
    (INLET + ",jet_radius=1.0,jet_velocity=[0.0,0.0,50.0]}",),
    (INLET + ",jet_radius=0.003,jet_center=[1.0,1.0],jet_velocity=[0.0,0.0,50.0]}",),
    (INLET + ",jet_radius=0.003,jet_velocity=[0.0,0.0,1e5]}",),
    ("boundary.top={kind='pressure_outlet',pressure=1e30}",), ("boundary.top={kind='wall'}",),
    ("boundary.x-={kind='periodic'}", "boundary.x+={kind='periodic'}", "vessel.shape='box'"),
    ("boundary.z-={kind='periodic'}", "boundary.z+={kind='periodic'}", "vessel.shape='box'"),
    ("domain.gravity=[0.0,0.0,1e6]",), ("domain.hi=[0.0225,0.0225,0.005]",), ("vessel.center=[1.0,1.0]",),
    ("vessel.floor=0.1", "vessel.lid=0.1001"), ("probes.mri_pixel=[1e-9,1e-9]", "probes.mri_interval=0.001"),
    ("probes.mri_pixel=[1.0,1.0]", "probes.mri_interval=0.001"), ("probes.rcfd_from=0.0", "probes.rcfd_interval=0.0005"),
    ("probes.rcfd_from=0.0", "probes.rcfd_tag='q<3'"), ("probes.rcfd_from=0.0", "probes.rcfd_z_max=0.001"),
]


def base_preset() -> str:
    text = (ROOT / "presets" / "fluidize.toml").read_text()
    for a, b in (("count = 5000", "count = 300"), ("duration = 0.55", "duration = 0.004"),
                 ("start = 0.15, ramp = 0.05", "start = 0.0, ramp = 0.001"), ("[run]", "[run]\nthreads = 1")):
        assert a in text, a
        text = text.replace(a, b, 1)
    return text


def edge_values(f) -> list[str]:
    """The values a field is tried at: its bounds (an open one just inside), 1e30 beyond a side it leaves open."""
    m, t = f.metadata, str(f.type)
    if m.get("choices"):
        return [json.dumps(c) if isinstance(c, str) else str(c) for c in m["choices"]]
    lo, hi = m.get("lo"), m.get("hi")
    if t == "bool":
        return ["true", "false"]
    if t == "int":
        return [str(lo if lo is not None else -5), str(hi if hi is not None else 10 ** 9)]
    if t == "float":
        vals = [] if lo is None else [repr(lo * (1 + 1e-9) + 1e-300 if m.get("lo_open") else lo)]
        vals += [repr(hi)] if hi is not None else ["1e30"]
        return vals + (["-1e30"] if lo is None else [])
    return []


def cases(only: str = "") -> list[tuple[str, ...]]:
    out = []
    for name, cls in SECTIONS.items():
        for f in dataclasses.fields(cls):
            key = f"{name}.{f.name}"
            if key == "run.step":  # four steps of it, not the base's 4 ms (4e9 steps of 1e-12 s)
                out += [(f"{key}={v}", f"run.duration={4 * float(v)!r}") for v in edge_values(f)]
            elif key not in SKIP:
                out += [(f"{key}={v}",) for v in edge_values(f)]
    out += STRUCTURED
    return [c for c in out if c[0].startswith(only)]


def run_case(case: tuple[str, ...], preset: pathlib.Path, work: pathlib.Path, timeout: float) -> dict:
    out = work / f"o{abs(hash(case))}"
    args = [a for kv in case for a in ("--set", kv)]
    t0 = time.perf_counter()
    try:
        r = subprocess.run([sys.executable, "-m", "app", "run", str(preset), "--arch", "cpu", *args, "--out", str(out),
                            "--overwrite"], capture_output=True, text=True, timeout=timeout, cwd=work)
        rc, err = r.returncode, r.stderr
    except subprocess.TimeoutExpired:
        rc, err = "timeout", ""
    wall = time.perf_counter() - t0
    subprocess.run(["rm", "-rf", str(out)])
    lines = [ln for ln in err.strip().splitlines() if ln.startswith(("fbed: error", "fbed: stopped", "  hint"))]
    outcome = {0: "finished", 2: "refused", 3: "stopped"}.get(rc, "FAILED")
    if "Traceback" in err:
        outcome = "FAILED"
    return dict(case=" ".join(case), rc=rc, outcome=outcome, wall_s=round(wall, 1),
                message=" ".join(lines)[:400] or (err.strip().splitlines() or [""])[-1][:200])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", default="", help="only the keys that start with this (e.g. gas.)")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--timeout", type=float, default=300.0, help="s per run (a new kernel variant compiles for up to "
                    "two minutes here); a case that fails runs again alone with three times as long, and both "
                    "outcomes are listed")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "EDGES.md"))
    a = ap.parse_args(argv)
    todo = cases(a.only)
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, cwd=ROOT).stdout.strip()
    with tempfile.TemporaryDirectory() as tmp:
        work = pathlib.Path(tmp)
        preset = work / "edges.toml"
        preset.write_text(base_preset())
        with ThreadPoolExecutor(a.jobs) as ex:
            rows = []
            for row in ex.map(lambda c: run_case(c, preset, work, a.timeout), todo):
                rows.append(row)
                print(f"{row['outcome']:9s} {row['case']}" + (f" (exit {row['rc']})" if row["outcome"] == "FAILED"
                                                               else ""), flush=True)
        for i, case in enumerate(todo):  # a failure beside another case (a compile past the limit): once more, alone
            if rows[i]["outcome"] == "FAILED":
                first = f"{rows[i]['rc']}: {rows[i]['message'][:150]}"
                rows[i] = run_case(case, preset, work, 3 * a.timeout) | {"retried": first}
                print(f"{rows[i]['outcome']:9s} {rows[i]['case']} (retried alone; first exit {first})", flush=True)
    failed = [r for r in rows if r["outcome"] == "FAILED"]
    counts = {k: sum(r["outcome"] == k for r in rows) for k in ("finished", "refused", "stopped", "FAILED")}
    md = [f"# Preset keys at their edges (`benchmarks/schema_edges.py`)\n",
          f"{time.strftime('%Y-%m-%d')}, commit {commit} (at the start), {machine_line('cpu')}; {len(rows)} cases, "
          f"{a.jobs} at a time, one thread each, presets/fluidize.toml cut to 300 grains and 4 steps. "
          + ", ".join(f"{v} {k}" for k, v in counts.items()) + ".\n",
          "Contract: finished (exit 0), refused naming a key (exit 2) or stopped by the guard naming a knob "
          "(exit 3); never a traceback, a kill or a hang (FAILED). Stops are for review (a rule could refuse the "
          "value up front).\n", "| case | outcome | exit | wall [s] | message |", "|---|---|---|---|---|"]
    for r in sorted(rows, key=lambda r: (r["outcome"] != "FAILED", r["outcome"] != "stopped", r["case"])):
        msg = r["message"].replace("|", "/")
        again = f" (retried alone; first exit {r['retried']})" if r.get("retried") else ""
        md.append(f"| `{r['case']}` | {r['outcome']}{again} | {r['rc']} | {r['wall_s']} | {msg} |")
    pathlib.Path(a.out).write_text("\n".join(md) + "\n")
    append_results("Preset keys at their edges (benchmarks/schema_edges.py; the table in benchmarks/EDGES.md)",
                   [{"cases": len(rows), **counts, "wall_s": round(sum(r["wall_s"] for r in rows), 1)}], "cpu")
    print(f"{counts}; table in {a.out}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())

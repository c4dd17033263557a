"""The accuracy bench's driver: sweep each case's knobs one at a time, write the CSV, the Pareto plots
and the recommended-settings table (ACCURACY.md).

Owns: the order of the sweep (rows grouped by float precision, so Taichi restarts at most twice),
the knee rule, and the files. The cases own their scenes (:mod:`.dem_cases`,
:mod:`.gas_cases`, :mod:`.bed_cases`); the registry is :func:`all_cases`.

Knee rule: among the values of one knob, the recommended one is the cheapest whose error is within
the case's tolerance; where none is, the cheapest of those within 1% of the smallest error (errors that
close are one error: a sweep whose knob changes nothing must not pick a value by rounding). The default
is "on the knee" when it is the recommended value, or costs at most 1.5x the recommended one while staying
within tolerance.

Resuming: every row is written to accuracy.csv as soon as it is measured, with the size, the arch and the
commit it was measured at; ``resume=True`` keeps the rows already there (same size and arch) and measures
only the missing points, so a bench cut off by a time limit (a lent GPU's call) goes on where it stopped.
A run stopped by a signal (:class:`Interrupted`) records no row.
"""
from __future__ import annotations

import contextlib
import csv
import datetime
import functools
import math
import pathlib
import platform
import signal
import time

from ..config import ConfigError
from ..outputs import out_folder
from ..sim import runtime
from . import bed_cases, dem_cases, gas_cases
from .cases import Case, Interrupted, Unavailable
from .common import commit, gpu_name


def all_cases() -> list[Case]:
    """Every registered case, in a stable order (DEM, gas, then coupled beds)."""
    return [*dem_cases.CASES, *gas_cases.CASES, *bed_cases.CASES]


@functools.lru_cache(maxsize=1)
def _commit() -> str:  # once per process: every row records it
    return commit(dirty=False)


def sweep_points(case: Case) -> list[tuple[str, object, dict]]:
    """(knob, value, settings) of every point of the sweep: the defaults once (knob 'default'), then each knob's
    other values, grouped by float precision (so Taichi restarts at most twice)."""
    points: list[tuple[str, object, dict]] = [("default", "", dict(case.defaults))]
    for knob, values in case.knobs.items():
        for v in values:
            if v == case.defaults[knob]:
                continue
            points.append((knob, v, {**case.defaults, knob: v}))
    points.sort(key=lambda p: p[2].get("precision", "float32") != case.defaults.get("precision", "float32"))
    return points


def sweep_case(case: Case, size: str, arch: str, threads: int | None = 1, log=print, done: dict | None = None,
               on_row=None) -> list[dict]:
    """Rows (one per knob value; the defaults measured once, as every knob's default row). ``done``: rows
    already measured, by (knob, str(value)): reused, not measured again. ``on_row(row)``: called after each
    new row (the runner writes the CSV there)."""
    done = done or {}
    rows = []
    for knob, value, settings in sweep_points(case):
        if (knob, str(value)) in done:
            rows.append(done[(knob, str(value))])
            continue
        runtime.init(arch, settings.get("precision", "float32"), threads)
        t0 = time.perf_counter()
        res = case.measure(settings, size)
        row = {"case": case.name, "knob": knob, "value": value, "error": float(res["error"]),
               "cost": float(res["cost"]), "wall_s": time.perf_counter() - t0,
               **{k: v for k, v in res.items() if k not in ("error", "cost")},
               "size": size, "arch": arch, "commit": _commit()}
        log(f"  {case.name:18s} {knob:16s} {str(value):10s} error {row['error']:.3e}  cost {row['cost']:.4g}")
        rows.append(row)
        if on_row:
            on_row(row)
    return rows


KNEE_TIE = 0.01  # relative: errors closer than this count as equal when none is within tolerance


def knee(case: Case, rows: list[dict], knob: str) -> dict:
    """The recommended value of ``knob`` (see the module's rule) and whether the default is on it."""
    base = next(r for r in rows if r["knob"] == "default")
    cand = [r for r in rows if r["knob"] == knob] + [dict(base, value=case.defaults[knob])]
    ok = [r for r in cand if math.isfinite(r["error"]) and r["error"] <= case.tolerance]
    if ok:
        best = min(ok, key=lambda r: (r["cost"], r["error"]))
    else:
        finite = [r for r in cand if math.isfinite(r["error"])] or cand
        least = min(r["error"] for r in finite)
        near = [r for r in finite if r["error"] <= least * (1 + KNEE_TIE)]
        best = min(near or finite, key=lambda r: (r["cost"], r["error"]))
    on = best["value"] == case.defaults[knob] or (
        base["error"] <= case.tolerance and base["cost"] <= 1.5 * best["cost"])
    return {"knob": knob, "recommended": best["value"], "error": best["error"], "cost": best["cost"],
            "default": case.defaults[knob], "default_error": base["error"], "default_cost": base["cost"],
            "default_on_knee": on}


# Why a default stays where no case binds it (a cheaper value passes in every case that measured one). Each is a
# fact measured elsewhere or a property of the method; a knob bound by some case's tolerance needs no entry.
WHY_DEFAULT = {
    "dt_fraction": "0.05 keeps a 2x margin under dem.max_dt_fraction = 0.1, the largest step fbed accepts: impacts "
                   "up to 32x faster than dem.impact_speed keep 10 or more steps per contact (t_c ~ v^-1/5); at 0.1 "
                   "every impact faster than dem.impact_speed gets fewer",
    "youngs_modulus": "set by the contact-stiffness study (`fbed bench stiffness`), which compares the bed with "
                      "glass-like 1e8 Pa contacts, not with these cases' tolerances",
    "cell_size": "set per preset: in a bed the cell size is part of the model (eps and drag are averaged over a "
                 "cell), so it is not converged away",
    "cells": "the validation preset's own grid: the case measures what its resolution buys",
    "cells_across": "the case's own resolution, not a preset's default",
    "precision": "float32 halves the memory of every field; float64 cost more in the coupled beds",
    "tolerance": "a looser tolerance saved at most 7% in the cavity and the bubbling bed (1e-3, 1e-4) and at most "
                 "14% in the pipe, and a bed's transient was not tested at 1e-3",
    "advection": "MacCormack is second order in space and time; semi-Lagrangian is first order and more diffusive",
}


# Which way a knob's value makes a run cheaper by construction (+1: larger values, -1: smaller): fewer DEM steps,
# fluid steps, cells or iterations. A value on the cheap side counts as a cheaper alternative even when its measured
# cost came out higher (a chaotic bed's cost scatters by a few percent from run to run). Knobs with no such side
# (skin, precision, advection) are judged by the measured cost alone.
CHEAPER_SIDE = {"dt_fraction": +1, "fluid_step": +1, "cell_size": +1, "tolerance": +1, "cells": -1,
                "cells_across": -1, "youngs_modulus": -1}


def _cheaper(knob: str, row: dict, base: dict, default) -> bool:
    side = CHEAPER_SIDE.get(knob)
    by_side = side is not None and isinstance(row["value"], (int, float)) and (row["value"] - default) * side > 0
    return by_side or (math.isfinite(row["cost"]) and row["cost"] < base["cost"])


def defaults_across(cases: list[Case], rows: list[dict]) -> list[dict]:
    """Each knob judged over every case that sweeps it: the knee of one case says only that a value passes that
    case's tolerance, and a default serves them all. A value is a cheaper alternative when it lies on the knob's
    cheap side (CHEAPER_SIDE) or was measured cheaper. Per case, the default is bound (a cheaper alternative fails
    the case's tolerance), passed (one is within tolerance: the one measured cheapest is named), out (the default
    itself fails; an alternative as accurate, within KNEE_TIE, is named), or none cheaper (no alternative was
    measured). The knob's default is on the knee across the cases when some case binds it; otherwise WHY_DEFAULT
    says what keeps it, or nothing does."""
    out: dict[str, dict] = {}
    for case in cases:
        cr = [r for r in rows if r["case"] == case.name]
        base = next((r for r in cr if r["knob"] == "default"), None)
        if base is None:
            continue
        for knob in case.knobs:
            default = case.defaults[knob]
            mine = [r for r in cr if r["knob"] == knob and _cheaper(knob, r, base, default)]
            passing = [r for r in mine if math.isfinite(r["error"]) and r["error"] <= case.tolerance]
            failing = [r for r in mine if r not in passing]
            entry = {"case": case.name, "default": default, "default_error": base["error"],
                     "tolerance": case.tolerance}
            if not math.isfinite(base["error"]) or base["error"] > case.tolerance:
                entry["verdict"] = "out"
                same = [r for r in mine if math.isfinite(r["error"]) and
                        r["error"] <= base["error"] * (1 + KNEE_TIE)] if math.isfinite(base["error"]) else []
                if same:
                    best = min(same, key=lambda r: r["cost"])
                    entry.update(value=best["value"], error=best["error"], ratio=best["cost"] / base["cost"])
            elif passing:
                best = min(passing, key=lambda r: r["cost"])
                entry.update(verdict="passed", value=best["value"], error=best["error"],
                             ratio=best["cost"] / base["cost"])
            elif failing:
                near = min(failing, key=lambda r: abs(r["cost"] - base["cost"]))  # the failure nearest the default
                entry.update(verdict="bound", value=near["value"], error=near["error"])
            else:
                entry["verdict"] = "none cheaper"
            out.setdefault(knob, {"knob": knob, "cases": []})["cases"].append(entry)
    for k in out.values():
        k["bound"] = any(e["verdict"] == "bound" for e in k["cases"])
        k["cheaper_passes"] = any("value" in e for e in k["cases"] if e["verdict"] in ("passed", "out"))
        k["why"] = "" if k["bound"] or not k["cheaper_passes"] else WHY_DEFAULT.get(k["knob"], "")
    return list(out.values())


def _across_lines(cases: list[Case], rows: list[dict]) -> list[str]:
    lines = ["## Defaults across the cases", "",
             "A default serves every case, so each knob is judged over all the cases that sweep it. Per case: "
             "**bound** (a cheaper value fails the case's tolerance), **passes** (a cheaper value is within it: "
             "the one measured cheapest, its cost over the default's, its error), **out** (the default itself "
             "fails; a cheaper value at least as accurate is named), **none cheaper** (no cheaper value was "
             "measured). A value is cheaper when it lies on the side of the knob that does less work (a longer "
             "step, coarser cells, a looser tolerance, softer grains) or was measured cheaper. "
             "The default is on the knee across the cases when a case binds it; otherwise the last column says "
             "what keeps it.", "",
             "| knob | per case | on the knee across the cases |", "|---|---|---|"]
    for k in defaults_across(cases, rows):
        parts = []
        for e in k["cases"]:
            head = f"{e['case']} ({_fmt(e['default'])})"
            if e["verdict"] == "bound":
                parts.append(f"{head}: bound, {_fmt(e['value'])} gives {e['error']:.2e} > {e['tolerance']:g}")
            elif e["verdict"] == "passed":
                parts.append(f"{head}: {_fmt(e['value'])} passes at {e['ratio']:.2f}x the cost ({e['error']:.2e})")
            elif e["verdict"] == "out":
                parts.append(f"{head}: out, {e['default_error']:.2e} > {e['tolerance']:g}" + (
                    f"; {_fmt(e['value'])} at least as accurate at {e['ratio']:.2f}x the cost" if "value" in e else ""))
            else:
                parts.append(f"{head}: none cheaper")
        if k["bound"]:
            verdict = "yes: " + ", ".join(e["case"] for e in k["cases"] if e["verdict"] == "bound") + " binds it"
        elif not k["cheaper_passes"]:
            verdict = "no cheaper value was measured"
        else:
            verdict = ("no; kept: " + k["why"]) if k["why"] else \
                "no, and nothing measured keeps it: a candidate to change"
        lines.append(f"| {k['knob']} | {'; '.join(parts)} | {verdict} |")
    return lines + [""]


def pareto_plot(case: Case, rows: list[dict], path: pathlib.Path) -> None:
    import matplotlib  # heavy, and only for the figure: imported when one is drawn

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4.2))
    base = next(r for r in rows if r["knob"] == "default")
    floor = 1e-7
    for i, knob in enumerate(case.knobs):
        pts = sorted([r for r in rows if r["knob"] == knob] + [dict(base, value=case.defaults[knob])],
                     key=lambda r: r["cost"])
        c = [r["cost"] for r in pts]
        e = [max(r["error"], floor) for r in pts]
        ax.loglog(c, e, "o-", color=f"C{i}", label=knob)
        for r, x, y in zip(pts, c, e):
            ax.annotate(f"{r['value']:g}" if isinstance(r["value"], float) else str(r["value"]), (x, y),
                        textcoords="offset points", xytext=(4, 3), fontsize=7, color=f"C{i}")
    ax.loglog([base["cost"]], [max(base["error"], floor)], "k*", ms=12, label="default", zorder=5)
    ax.axhline(case.tolerance, color="0.5", ls="--", lw=0.8, label=f"tolerance {case.tolerance:g}")
    ax.set(xlabel=case.cost_label + " (cost)", ylabel=case.error_label, title=case.name)
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _fmt(v) -> str:
    return f"{v:g}" if isinstance(v, float) else str(v)


def report(cases: list[Case], rows: list[dict], size: str, arch: str, device: str) -> str:
    commits = ", ".join(sorted({str(r["commit"]) for r in rows if r.get("commit")})) or _commit()
    lines = [f"# Accuracy against cost ({datetime.date.today().isoformat()}, commit {commits}, size '{size}', "
             f"{arch}: {device})", "",
             "Each case sweeps its cost knobs one at a time, the others at fbed's defaults. The recommended value",
             "is the cheapest within the case's tolerance; the default is on the knee when it is that value, or",
             "costs at most 1.5x it while within tolerance. Pareto plots: `pareto_<case>.png`; every row:",
             "`accuracy.csv`.", "",
             "## Recommended settings", "",
             "| case | knob | default | default's error | recommended | its error | cost ratio (default / rec.) | on the knee |",
             "|---|---|---|---|---|---|---|---|"]
    for case in cases:
        cr = [r for r in rows if r["case"] == case.name]
        if not cr:
            continue
        for knob in case.knobs:
            k = knee(case, cr, knob)
            ratio = k["default_cost"] / k["cost"] if k["cost"] else float("nan")
            lines.append(f"| {case.name} | {knob} | {_fmt(k['default'])} | {k['default_error']:.2e} | "
                         f"{_fmt(k['recommended'])} | {k['error']:.2e} | {ratio:.2f} | "
                         f"{'yes' if k['default_on_knee'] else 'no'} |")
    lines += [""] + _across_lines(cases, rows) + ["## Cases", ""]
    for case in cases:
        cr = [r for r in rows if r["case"] == case.name]
        if not cr:
            continue
        lines += [f"### {case.name}", "", f"{case.title}. Error: {case.error_label}; cost: {case.cost_label}; "
                  f"tolerance {case.tolerance:g}." + (f" {case.note}." if case.note else ""), "",
                  "| knob | value | error | cost | wall of the measure [s] |", "|---|---|---|---|---|"]
        lines += [f"| {r['knob']} | {_fmt(r['value'])} | {r['error']:.3e} | {r['cost']:.4g} | {r['wall_s']:.1f} |"
                  for r in cr]
        lines.append("")
    return "\n".join(lines) + "\n"


def accuracy(out: str | None = None, names: list[str] | None = None, size: str = "small", arch: str = "cpu",
             threads: int | None = 1, resume: bool = False) -> int:
    """Run the cases (all, or ``names``), write accuracy.csv, pareto_<case>.png and ACCURACY.md into
    ``out`` (default runs/accuracy); print the table. ``resume``: keep the rows already in out/accuracy.csv
    and measure the rest (the report then covers every case with rows). Returns 0, or 130 when a run was
    stopped by a signal (what was measured is written)."""
    cases = [c for c in all_cases() if not names or c.name in names]
    out_dir = out_folder(out, pathlib.Path("runs") / "accuracy")
    csv_path = out_dir / "accuracy.csv"
    rows: list[dict] = load_rows(csv_path, size, arch) if resume else []
    if resume:
        print(f"resuming: {len(rows)} rows kept from {csv_path}", flush=True)
    rc = 0

    def keep(row: dict) -> None:  # every new row on disk at once: a bench killed mid-case keeps it
        rows.append(row)
        _write_csv(rows, csv_path)

    with runtime.kept(), signals_interrupt():  # tests run in float64
        for case in cases:
            print(f"{case.name}: {case.title}", flush=True)
            done = {(r["knob"], str(r["value"])): r for r in rows if r["case"] == case.name}
            try:
                cr = sweep_case(case, size, arch, threads, done=done, on_row=keep)
            except Unavailable as why:
                print(f"  skipped: {why}", flush=True)
                continue
            except (Interrupted, KeyboardInterrupt) as why:
                print(f"  interrupted: {why or 'a signal'}; what was measured is in {csv_path}: go on with --resume",
                      flush=True)
                rc = 130
                break
            pareto_plot(case, cr, out_dir / f"pareto_{case.name}.png")
    if not rows:
        return rc
    device = platform.processor() or platform.machine()
    if arch == "cuda":
        device = gpu_name()
        device = "GPU" if device == "none" else device
    reported = [c for c in all_cases() if any(r["case"] == c.name for r in rows)]
    text = report(reported, rows, size, arch, device)
    (out_dir / "ACCURACY.md").write_text(text)
    print(text)
    return rc


def csv_value(text: str):
    """A CSV cell back as the value it was written from: int, float, or the text."""
    try:
        return int(text)
    except ValueError:
        pass
    try:
        return float(text)
    except ValueError:
        return text


@contextlib.contextmanager
def signals_interrupt():
    """SIGTERM (a time limit) raises KeyboardInterrupt while a bench runs, as Ctrl-C does, so the bench ends with
    its report instead of dying mid-write (fbed run installs its own handlers during a bed run: Interrupted)."""
    try:
        old = signal.signal(signal.SIGTERM, signal.default_int_handler)
    except ValueError:  # not the main thread: leave signals alone
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, old)


def same_bench(row: dict, path: pathlib.Path, size: str, arch: str) -> None:
    """Refuse to resume from a row of another size or arch (its errors or costs are not this bench's)."""
    if (row.get("size"), row.get("arch")) != (size, arch):
        raise ConfigError(f"it holds rows of size {row.get('size') or '?'!r} on {row.get('arch') or '?'!r}; this bench "
                          f"is size {size!r} on {arch!r}", str(path), "--resume",
                          hint="resume with the same --size and --arch, or write to another --out")


def load_rows(path: pathlib.Path, size: str, arch: str) -> list[dict]:
    """The rows of an accuracy.csv to resume from (none when it does not exist yet). Rows of points no case
    sweeps any more are dropped; a file of another size or arch is refused (its costs and errors are not
    this bench's)."""
    if not path.exists():
        return []
    with open(path, newline="") as fh:
        raw = list(csv.DictReader(fh))
    cases = {c.name: c for c in all_cases()}
    rows = []
    for r in raw:
        same_bench(r, path, size, arch)
        case = cases.get(r["case"])
        if case is None:
            continue
        if r["knob"] == "default":
            value = ""
        else:
            value = next((v for v in case.knobs.get(r["knob"], ()) if str(v) == r["value"]), None)
            if value is None:
                continue
        rows.append({**{k: csv_value(v) for k, v in r.items()}, "value": value, "case": r["case"], "knob": r["knob"],
                     "commit": r.get("commit", "")})
    return rows


def _write_csv(rows: list[dict], path: pathlib.Path) -> None:
    keys: list[str] = []
    for r in rows:
        keys += [k for k in r if k not in keys]
    with open(path, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=keys)
        w.writeheader()
        w.writerows(rows)

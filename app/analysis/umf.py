"""The fluidization curve at decreasing gas velocities and the minimum fluidization velocity read off it.

Owns: the experiment's procedure for U_mf (seed 002, Section 3.1: the pressure drop across the bed at
decreasing air velocities) on a run whose inlet schedule holds a sequence of velocities. Each hold is a
stretch of the schedule between two points of equal fraction; its pressure drop is the mean of the
series' ``pressure_drop`` over the hold's second half (the first half lets the bed rearrange). U_mf is
the classical graphical reading: the fixed-bed branch, dp = a U + b U^2 (Ergun's form, through the
origin) fitted to the holds whose pressure drop is below FIXED_BED of the bed's buoyant weight per area
(clearly off the plateau), meets the weight per area W. The branch is the contiguous run of such holds up
from the lowest velocity: a fluidized, slugging bed can also read below 0.8 W over a hold's short window (in
presets/mri_umf.toml and mri_umf_periodic.toml at 0.5 and 0.6 m/s), and those holds are not a fixed bed. Each
wall's share of the weight (its mean vertical force on the grains over the same window, from run.h5's
``wall_force_z_<wall>``) is written beside the pressure drop's: for a bed at rest the shares sum to 1.
Plain numpy/matplotlib, no Taichi.
"""
from __future__ import annotations

import csv
import json
import math
import pathlib

import numpy as np

FIXED_BED = 0.8   # holds with dp < 0.8 W are on the fixed-bed branch


def holds(schedule: list, speed: float) -> list[tuple[float, float, float]]:
    """(start, end, velocity [m/s]) of every stretch of an inlet schedule [[t, fraction], ...] that holds one
    fraction (> 0); ``speed`` the inlet's full velocity."""
    out = []
    for (t0, f0), (t1, f1) in zip(schedule, schedule[1:]):
        if t1 > t0 and f0 == f1 and f0 > 0:
            out.append((float(t0), float(t1), float(f0) * speed))
    return out


def curve(time: np.ndarray, dp: np.ndarray, stretches, walls: dict | None = None) -> list[dict]:
    """Mean and standard deviation of the pressure drop over each hold's second half; with ``walls`` (name ->
    series of a wall's vertical force on the grains [N]) each wall's mean over the same stretch too."""
    rows = []
    for t0, t1, u in stretches:
        sel = (time >= 0.5 * (t0 + t1)) & (time <= t1 + 1e-12)
        if sel.any():
            rows.append(dict(velocity=u, start=t0, end=t1, pressure_drop=float(np.mean(dp[sel])),
                             pressure_drop_std=float(np.std(dp[sel])), samples=int(sel.sum()),
                             walls={k: float(np.mean(v[sel])) for k, v in (walls or {}).items()}))
    return rows


def umf(rows: list[dict], weight: float) -> dict:
    """U_mf [m/s] where the fixed-bed fit a U + b U^2 reaches ``weight`` [Pa], and the fit's coefficients."""
    fixed = []
    for r in sorted(rows, key=lambda r: r["velocity"]):  # the contiguous run up from the lowest velocity
        if r["pressure_drop"] >= FIXED_BED * weight:
            break
        fixed.append(r)
    out = {"fixed_bed_points": len(fixed)}
    if len(fixed) < 2:
        return out
    u = np.array([r["velocity"] for r in fixed])
    p = np.array([r["pressure_drop"] for r in fixed])
    a, b = np.linalg.lstsq(np.column_stack([u, u * u]), p, rcond=None)[0]
    # b U^2 + a U - W = 0: the smallest positive root (U = W / a when the fit has no quadratic part)
    if abs(b) > 1e-12 * max(abs(a), 1e-30):
        disc = a * a + 4 * b * weight
        roots = [x for x in ((-a + s * math.sqrt(disc)) / (2 * b) for s in (1, -1)) if x > 0] if disc >= 0 else []
        if roots:
            out["umf"] = float(min(roots))
    elif a > 0:
        out["umf"] = float(weight / a)
    out.update(ergun_a=float(a), ergun_b=float(b))
    return out


def summarize(run_dir) -> dict:
    """The curve of a finished run (analysis/umf.csv, umf.json, umf.png); returns umf_simulated [m/s] and
    the weight per area for summary.json."""
    from .. import config as cfgmod
    from ..io import store

    run_dir = pathlib.Path(run_dir)
    cfg = cfgmod.load(run_dir / "config.toml")
    inlet = [b for _, b in cfg.boundary if b.kind == "velocity_inlet" and b.schedule]
    if not inlet:
        raise ValueError("the run has no velocity_inlet with a schedule of holds")
    speed = float(np.linalg.norm(inlet[0].velocity))
    series = store.read_series(run_dir / "run.h5")
    summary = json.loads((run_dir / "summary.json").read_text())
    weight = float(summary["bed_weight_per_area"])
    # each wall's vertical force on the grains, as a share of the bed's buoyant weight (weight per area x the
    # open cross-section): with the pressure drop's share it sums to 1 for a bed at rest (Model A and B alike)
    area = summary.get("bed_area")
    walls = {k[len("wall_force_z_"):]: v for k, v in series.items() if k.startswith("wall_force_z_")} if area else {}
    stretches = holds(inlet[0].schedule, speed)
    if not stretches:  # rcfd_small's ramp to a last point: an empty umf.csv and U_mf NaN, without a reason
        raise ValueError("the inlet's schedule holds no velocity (no two points [t, fraction] of equal fraction > 0); "
                         "the curve is read on holds at decreasing velocities, as presets/mri_umf.toml's schedule")
    rows = curve(series["time"], series["pressure_drop"], stretches, walls)
    if not rows:
        raise ValueError(f"the run ended at t = {float(series['time'][-1]):.4g} s, before the second half of the "
                         f"schedule's first hold ({stretches[0][0]:g} to {stretches[0][1]:g} s): run longer")
    fit = umf(rows, weight)
    out = run_dir / "analysis"
    out.mkdir(exist_ok=True)
    with open(out / "umf.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["velocity [m/s]", "pressure_drop [Pa]", "pressure_drop_std [Pa]", "dp_over_weight [-]",
                    "start [s]", "end [s]"] + [f"{k}_over_weight [-]" for k in walls])
        for r in rows:
            w.writerow([f"{r['velocity']:.6g}", f"{r['pressure_drop']:.6g}", f"{r['pressure_drop_std']:.6g}",
                        f"{r['pressure_drop'] / weight:.6g}", f"{r['start']:.6g}", f"{r['end']:.6g}"]
                       + [f"{r['walls'][k] / (weight * area):.6g}" for k in walls])
    figures = {"umf_simulated": fit.get("umf", math.nan), "umf_weight_per_area": weight,
               "umf_fixed_bed_points": fit["fixed_bed_points"]}
    if "umf" not in fit:  # why U_mf is NaN, in summary.json and umf.json (sweep.csv keeps numbers only)
        figures["umf_note"] = (f"no U_mf: {fit['fixed_bed_points']} hold(s) on the fixed-bed branch (pressure drop "
                               f"< {FIXED_BED:g} of the weight, up from the lowest velocity); the fit needs 2: hold "
                               "lower velocities" if fit["fixed_bed_points"] < 2 else
                               "no U_mf: the fixed-bed fit never reaches the bed's weight")
    (out / "umf.json").write_text(json.dumps({**figures, **fit, "drag": cfg.coupling.drag,
                                              "units": "m/s, Pa"}, indent=2) + "\n")
    plot([(cfg.coupling.drag, rows, fit)], weight, out / "umf.png")
    return figures


def plot(curves, weight: float, path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    for label, rows, fit in curves:
        u = np.array([r["velocity"] for r in rows])
        p = np.array([r["pressure_drop"] for r in rows]) / weight
        line, = ax.plot(u, p, "o-", label=f"{label}: U_mf {fit.get('umf', math.nan):.3f} m/s")
        if "ergun_a" in fit:
            uu = np.linspace(0, max(u.max(), fit.get("umf", 0)), 100)
            ax.plot(uu, (fit["ergun_a"] * uu + fit["ergun_b"] * uu * uu) / weight, ":", color=line.get_color())
    ax.axhline(1.0, color="0.5", ls="--", lw=0.8)
    ax.set(xlabel="superficial gas velocity [m/s] (decreasing in time)", ylabel="pressure drop / bed weight per area",
           ylim=(0, 1.4))
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def compare(sweep_dir) -> pathlib.Path:
    """The cases' curves on one figure and their U_mf in one table: SWEEP_DIR/umf_compare.{md,png}."""
    d = pathlib.Path(sweep_dir)
    with open(d / "sweep.csv", newline="") as f:
        cases = list(csv.DictReader(f))
    curves, lines, weight = [], ["| case | drag | U_mf [m/s] | fixed-bed points | weight per area [Pa] |",
                                 "|---|---|---|---|---|"], math.nan
    for c in cases:
        j = d / c["case"] / "analysis" / "umf.json"
        if not j.exists():  # a failed case kept its row (it vanished from the table without a word)
            lines.append(f"| {c['case']} | {c.get('coupling.drag') or '-'} | no analysis: "
                         f"{c.get('status') or 'see its log.txt'} | - | - |")
            continue
        fig = json.loads(j.read_text())
        with open(d / c["case"] / "analysis" / "umf.csv", newline="") as f:
            rd = csv.reader(f)
            next(rd)
            rows = [dict(velocity=float(r[0]), pressure_drop=float(r[1])) for r in rd]
        weight = fig["umf_weight_per_area"]
        curves.append((fig["drag"], rows, fig))
        lines.append(f"| {c['case']} | {fig['drag']} | {fig['umf_simulated']:.4g} | {fig['umf_fixed_bed_points']} "
                     f"| {weight:.4g} |")
    if curves:
        plot(curves, weight, d / "umf_compare.png")
    (d / "umf_compare.md").write_text("# U_mf of the sweep's cases\n\n" + "\n".join(lines) + "\n")
    return d / "umf_compare.md"

"""The MRI pipeline's report (``app.analysis.mri``): the tables (CSV and markdown) and figures of one analysed
series, and a sweep's cases side by side. Plain numpy; reachable from ``mri`` as before (``mri.write``,
``mri.compare``, ``mri.SOURCES``)."""
from __future__ import annotations

import csv
import json
import math
import pathlib

from . import mri_figures as mfig


def _write_csv(path, rows: list[dict], keys: list[str]) -> None:
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(keys)
        for r in rows:
            w.writerow([(f"{r[k]:.6g}" if isinstance(r.get(k), float) else r.get(k, "")) for k in keys])


def _md(rows: list[dict], keys: list[str]) -> str:
    out = ["| " + " | ".join(keys) + " |", "|" + "---|" * len(keys)]
    for r in rows:
        out.append("| " + " | ".join(f"{r[k]:.4g}" if isinstance(r.get(k), float) else str(r.get(k, ""))
                                     for k in keys) + " |")
    return "\n".join(out) + "\n"


def write(res: dict, out: pathlib.Path, title: str = "") -> dict:
    """Tables (CSV + markdown) and figures (PNG) of one analysed series into ``out``; returns key figures."""
    out.mkdir(parents=True, exist_ok=True)
    tkeys = ["metric", "threshold", "n", "mean", "median", "max", "std", "cv", "mean_lo", "mean_hi",
             "ci_width_pct", "ks_p", "gradient_quality", "fails", "chosen"]
    _write_csv(out / "thresholds.csv", res["table"], tkeys)
    summary = []
    for name, st in (("bed_height [m]", res["height_stats"]), ("bubble_diameter [m]", res["diameter_stats"]),
                     ("aspect_ratio [-]", res["aspect_stats"]), ("bubble_velocity [m/s]", res["velocity_stats"])):
        summary.append(dict(metric=name, threshold=res["chosen"][name.split(" ")[0]], **st))
    skeys = ["metric", "threshold", "n", "mean", "mean_lo", "mean_hi", "mean_lo_blocks", "mean_hi_blocks", "max",
             "std", "cv"]
    _write_csv(out / "metrics.csv", summary, skeys)
    radial = [dict(x=float(x), r=float(abs(x)), whole_bed=float(a), static_bed=float(b))
              for x, a, b in zip(res["x"], res["radial_whole"], res["radial_static"])]
    _write_csv(out / "radial.csv", radial, ["x", "r", "whole_bed", "static_bed"])
    _write_csv(out / "diameter_height.csv", res["diameter_height"], ["z_lo", "z_hi", "n", "mean", "max", "std"])
    vkeys = ["d_lo", "d_hi", "n", "mean", "mean_lo", "mean_hi", "mean_lo_blocks", "mean_hi_blocks", "std"]
    _write_csv(out / "velocity_classes.csv", res["velocity_classes"], vkeys)
    _write_csv(out / "spectrum.csv", [dict(f=float(a), power=float(b)) for a, b in zip(res["freq"], res["power"])],
               ["f", "power"])
    md = [f"# MRI-style analysis{': ' + title if title else ''}\n",
          f"Frames: {len(res['times'])} at {1e3 * res['frame_dt']:.3g} ms; max displacement for tracking "
          f"{1e3 * res['max_disp']:.3g} mm; static height {1e3 * res['static_height']:.0f} mm.\n",
          "## Metrics at their chosen thresholds (lengths in m, velocities in m/s, 95% bootstrap intervals)\n",
          "mean_lo, mean_hi: the study's interval, frames (bubbles, tracks) resampled one by one. mean_lo_blocks, "
          f"mean_hi_blocks: blocks of {res['block_frames']} consecutive frames resampled (two integral times of the "
          "bed height): the frames are correlated, so the study's interval is too narrow; compare runs with these.\n",
          _md(summary, skeys),
          _steady_line(res["height_halves"]), _sessions_lines(res.get("sessions")),
          f"Expansion ratio: mean {res['expansion_ratio']:.4g}, max {res['expansion_ratio_max']:.4g}. "
          f"Dominant frequency of the void fraction below the static height: {res['f_peak']:.4g} Hz (resolution "
          f"{res['f_resolution']:.3g} Hz: the record's length sets it).\n",
          "## Every threshold\n", _md(res["table"], tkeys),
          "## Velocity per bubble size class (m, m/s; intervals as above)\n", _md(res["velocity_classes"], vkeys),
          "## Diameter against height (m)\n", _md(res["diameter_height"], ["z_lo", "z_hi", "n", "mean", "max"])]
    (out / "tables.md").write_text("\n".join(md))
    mfig.plot(res, out, title)
    hs, ds, vs = res["height_stats"], res["diameter_stats"], res["velocity_stats"]
    return dict(bed_height_mean=hs["mean"], bed_height_mean_lo=hs["mean_lo"], bed_height_mean_hi=hs["mean_hi"],
                bed_height_mean_lo_blocks=hs["mean_lo_blocks"], bed_height_mean_hi_blocks=hs["mean_hi_blocks"],
                bubble_diameter_mean_lo_blocks=ds["mean_lo_blocks"],
                bubble_diameter_mean_hi_blocks=ds["mean_hi_blocks"],
                bed_height_max=hs["max"], bed_height_std=hs["std"], expansion_ratio=res["expansion_ratio"],
                bubble_diameter_mean=ds["mean"], bubble_diameter_mean_lo=ds["mean_lo"],
                bubble_diameter_mean_hi=ds["mean_hi"], bubble_diameter_max=ds["max"], bubble_count=ds["n"],
                bed_height_halves_z_mean=res["height_halves"]["z"]["mean"],
                bed_height_halves_z_std=res["height_halves"]["z"]["std"],
                bubble_velocity_mean=vs["mean"], bubble_tracks=vs["n"], aspect_ratio_mean=res["aspect_stats"]["mean"],
                void_frequency=res["f_peak"]) | _sessions_figures(res.get("sessions"))


def _steady_line(hv: dict) -> str:
    """The window's steadiness in words: the bed height's halves, mean and std with block errors, and z."""
    a, b, z = hv["first"], hv["second"], hv["z"]
    words = ("too short to tell: fewer than two blocks a half" if not all(map(math.isfinite, z.values())) else
             "more than 3 standard errors apart: the window is not yet the bed's steady state, so start it later "
             "(output.average_from) or run longer" if max(z.values()) > 3 else "within 3 standard errors")
    return (f"Steady? The bed height over the window's first and second halves: mean {1e3 * a['mean']:.2f} "
            f"({1e3 * a['mean_se']:.2f}) and {1e3 * b['mean']:.2f} ({1e3 * b['mean_se']:.2f}) mm, std "
            f"{1e3 * a['std']:.2f} ({1e3 * a['std_se']:.2f}) and {1e3 * b['std']:.2f} ({1e3 * b['std_se']:.2f}) mm "
            f"(block standard errors): z {z['mean']:.1f} (mean), {z['std']:.1f} (std), {words}.\n")


def _sessions_lines(ss: dict | None) -> str:
    """Pooled runs (``mri.summarize_pooled``): each run's bed height with its block error, and whether they agree."""
    if not ss:
        return ""
    rows = [dict(run=i, first_frame=r["first"], frames=r["frames"], blocks=r["blocks"], mean=r["mean"],
                 mean_se=r["mean_se"], std=r["std"]) for i, r in enumerate(ss["rows"])]
    p = ss["p"]
    words = ("too short to tell: a run holds fewer than two blocks" if not math.isfinite(p) else
             "they differ (p < 0.01): not one steady operating point; read each run's window (one may still be "
             "settling) before pooling them" if p < 0.01 else "consistent with one operating point")
    return ("## The pooled runs: bed height (m) each, errors over blocks of frames\n\n" + _md(rows, list(rows[0]))
            + f"\nchi^2 = {ss['chi2']:.3g} on {ss['dof']} degrees of freedom about their weighted mean "
            f"{ss['weighted_mean']:.4g} m: p = {p:.3g}, {words}.\n")


def _sessions_figures(ss: dict | None) -> dict:
    return {} if not ss else dict(runs=len(ss["rows"]), runs_height_chi2=ss["chi2"], runs_height_p=ss["p"])


SOURCES = (("mri", "synthetic MRI (grain volume on the MRI pixels)"),
           ("slab", "gas grid solid fraction on the slab"))


COMPARE_KEYS = ("bed_height_mean", "bed_height_mean_lo", "bed_height_mean_hi", "bed_height_mean_lo_blocks",
                "bed_height_mean_hi_blocks", "bed_height_max", "expansion_ratio", "bubble_diameter_mean",
                "bubble_diameter_mean_lo_blocks", "bubble_diameter_mean_hi_blocks", "bubble_diameter_max",
                "bubble_velocity_mean", "bubble_count", "void_frequency")  # _blocks: the intervals to compare by


def compare(sweep_dir) -> pathlib.Path:
    """Side-by-side table and figure of the MRI figures of a sweep's cases (from sweep.csv and each case's
    analysis/mri.json) into SWEEP_DIR/mri_compare.{csv,md,png}."""
    d = pathlib.Path(sweep_dir)
    with open(d / "sweep.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    cols = list(rows[0]) if rows else []
    swept = cols[1:cols.index("status")] if "status" in cols else []  # sweep.csv: case, the swept keys, status
    table = [compare_row(r["case"], {k: r[k] for k in swept}, r.get("status", ""), d / r["case"]) for r in rows]
    return write_compare(d, table, swept, "the sweep's cases")


def compare_row(case: str, keys: dict, status: str, folder: pathlib.Path) -> dict:
    """One case's row: its name, the keys it differs by, its status and the COMPARE_KEYS of its analysis/mri.json."""
    j = folder / "analysis" / "mri.json"
    fig = json.loads(j.read_text()) if j.exists() else {}
    return {"case": case, **keys, "status": status, **{f"{src}_{k}": fig[f"{src}_{k}"] for src, _ in SOURCES
                                                       for k in COMPARE_KEYS if f"{src}_{k}" in fig}}


def write_compare(d: pathlib.Path, table: list[dict], swept: list[str], what: str) -> pathlib.Path:
    """``table`` (``compare_row``s) into d/mri_compare.{csv,md,png}, ``swept`` the keys the cases differ by."""
    keys = list(dict.fromkeys(k for r in table for k in r))
    _write_csv(d / "mri_compare.csv", table, keys)
    (d / "mri_compare.md").write_text(f"# MRI figures of {what} (m, m/s, Hz)\n\nIntervals: 95%; _lo, _hi "
                                      "the study's (frames resampled one by one), _lo_blocks, _hi_blocks over blocks "
                                      "of correlated frames: cases differ where these do not overlap.\n\n"
                                      + _md(table, keys))
    mfig.compare(table, swept, [src for src, _ in SOURCES], d / "mri_compare.png")
    return d / "mri_compare.md"

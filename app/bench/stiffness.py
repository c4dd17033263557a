"""`fbed bench stiffness`: how soft may the grains be? The contact-stiffness study.

Owns: the sweep of Young's modulus over the bed of :mod:`.bed_cases` (the same run as its accuracy
cases: 3 mm glass ramped to 2 U_mf, statistics over [0.1, 0.3] s; each modulus starts from a bed settled
with its own contacts, and every modulus is blown at the same inlet velocity), the table (stiffness.csv), the
figure (stiffness.png) and the report (STIFFNESS.md) with the paragraph that judges the default from the
numbers.

Grains are made softer than glass (70 GPa) because the DEM step is a fraction of the contact time, which
grows as E^(-2/5): each decade of softness buys 2.5x fewer steps. Softness is not free: overlaps grow as
E^(-2/5) at impacts and E^(-2/3) under static load, and a bed of soft grains is a spring that stores the
slug's energy. The study shows where the bed's figures stop changing with E against what the stiffer
contacts cost.

Resuming: each modulus's row is written as soon as it is measured, with its size and arch; ``resume=True``
keeps the rows already in stiffness.csv and runs the missing moduli (a run stopped by a signal records none).
"""
from __future__ import annotations

import csv
import datetime
import math
import pathlib

from ..outputs import out_folder
from ..sim import runtime
from . import bed_cases
from .accuracy import csv_value, same_bench, signals_interrupt
from .cases import Interrupted

MODULI = (1.0e5, 1.0e6, 5.0e6, 1.0e7, 1.0e8)   # [Pa]; 5e6 is fbed's default (the schema's)
SETTLED = 0.05                                  # a step of E that changes no figure by more than 5% leaves it settled
COLUMNS = ("youngs_modulus", "status", "substeps", "dem_dt", "stepping_wall_s", "cost", "cost_wall", "cpu_share",
           "bed_height_mean", "bed_height_std", "bed_height_max", "dp_over_weight", "dp_over_weight_raw",
           "floor_over_weight", "momentum_over_weight", "bubble_diameter", "bubbles", "gas_pocket_height",
           "max_overlap_pct", "umf_simulated", "umf_predicted", "message", "size", "arch")
COMPARED = ("bed_height_mean", "bed_height_std", "bed_height_max", "dp_over_weight", "umf_simulated")


def measure(youngs_modulus: float, size: str) -> dict:
    """The bed run at this modulus, every other knob at fbed's default."""
    bed = bed_cases.SIZES[size]
    f = bed_cases.bed_run({**bed_cases.DEFAULTS, "youngs_modulus": youngs_modulus}, size)
    row = {"youngs_modulus": youngs_modulus, **f}
    if f.get("status") == "finished":
        row["stepping_wall_s"] = f["cost"] * (bed.duration - bed_cases.WARM_UP)
        row["dem_dt"] = bed_cases.DEFAULTS["fluid_step"] / f["substeps"]
        row["max_overlap_pct"] = 100.0 * f["max_overlap"]
    return row


def deviation(row: dict, other: dict) -> tuple[float, str]:
    """Largest relative difference of the compared figures between two runs, and which figure it is."""
    changes = {k: abs(row[k] / other[k] - 1.0) for k in COMPARED if other.get(k)}
    key = max(changes, key=changes.get)
    return changes[key], key


def verdict(rows: list[dict]) -> str:
    """The paragraph of STIFFNESS.md, from the numbers: how much the bed's figures change from one modulus to
    the next against what each step costs, where they stop changing (within SETTLED per step, if they do),
    and where the default stands."""
    ok = sorted((r for r in rows if r.get("status") == "finished"), key=lambda r: r["youngs_modulus"])
    if len(ok) < 2:
        return "Too few runs finished to judge the default."
    steps = [(a, b, *deviation(a, b)) for a, b in zip(ok[:-1], ok[1:])]
    lines = ["From one modulus to the next, the largest change of the bed's figures (mean, spread and peak of "
             "the bed height, dP/W, U_mf) and the stepping cost:"]
    lines.append("; ".join(f"{a['youngs_modulus']:g} -> {b['youngs_modulus']:g} Pa: {100 * d:.1f}% ({k}), cost "
                           f"x{b['cost'] / a['cost']:.2f}" for a, b, d, k in steps) + ".")
    plateau = next((i for i in range(len(steps)) if all(d <= SETTLED for _, _, d, _ in steps[i:])), None)
    if plateau is None:
        lines.append(f"The figures still change by more than {100 * SETTLED:g}% between the two stiffest moduli, "
                     "so within this range no softened modulus is shown to reproduce stiffer (glass-like) contacts.")
    else:
        lines.append(f"Above E = {ok[plateau]['youngs_modulus']:g} Pa every step changes them by less than "
                     f"{100 * SETTLED:g}%: there the physics stops changing with E.")
    stiff = ok[-1]
    close = [deviation(r, stiff)[0] <= SETTLED for r in ok]
    # the softest modulus from which every stiffer one is within SETTLED of the stiffest: the knee of the study
    knee = next(ok[i] for i in range(len(ok)) if all(close[i:]))
    lines.append(f"From E = {knee['youngs_modulus']:g} Pa up, every figure is within {100 * SETTLED:g}% of "
                 f"E = {stiff['youngs_modulus']:g} Pa's, at {knee['cost'] / stiff['cost']:.2f}x its cost.")
    default = next((r for r in ok if r["youngs_modulus"] == bed_cases.DEFAULTS["youngs_modulus"]), None)
    if default is not None:
        d, k = deviation(default, stiff)
        where = ("it is that modulus" if default is knee else
                 "it is softer than that" if default["youngs_modulus"] < knee["youngs_modulus"] else
                 "it is stiffer than that")
        lines.append(f"The default E = {default['youngs_modulus']:g} Pa differs from E = {stiff['youngs_modulus']:g} "
                     f"Pa by {100 * d:.1f}% ({k}) at {default['cost'] / stiff['cost']:.2f}x its cost ({where}), "
                     f"with overlaps up to {default['max_overlap_pct']:.1f}% of d (E = {ok[0]['youngs_modulus']:g} "
                     f"Pa: {ok[0]['max_overlap_pct']:.1f}%).")
    return " ".join(lines)


def write_csv(rows: list[dict], path: pathlib.Path) -> None:
    with open(path, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=COLUMNS, extrasaction="ignore")
        w.writeheader()
        w.writerows(rows)


def plot(rows: list[dict], path: pathlib.Path, size: str = "small") -> None:
    import matplotlib  # heavy, and only for the figure: imported when one is drawn

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ok = sorted((r for r in rows if r.get("status") == "finished"), key=lambda r: r["youngs_modulus"])
    e = [r["youngs_modulus"] for r in ok]
    fig, axes = plt.subplots(2, 3, figsize=(12, 6.5), sharex=True)
    panels = [
        ("bed height [mm]", [("bed_height_mean", "mean", 1e3), ("bed_height_max", "peak", 1e3),
                             ("bed_height_std", "std", 1e3)]),
        ("dP / W", [("dp_over_weight", "force balance (momentum change, floor)", 1.0),
                    ("dp_over_weight_raw", "pressure drop alone", 1.0)]),
        ("bubbles and slug [mm]", [("bubble_diameter", "bubble: mean equivalent diameter", 1e3),
                                   ("gas_pocket_height", "slug: gas pocket height", 1e3)]),
        ("largest overlap [% of d]", [("max_overlap_pct", "over the window", 1.0)]),
        ("U_mf [m/s]", [("umf_simulated", "simulated", 1.0), ("umf_predicted", "drag law", 1.0)]),
        ("stepping wall s per simulated s", [("cost", "wall", 1.0)]),
    ]
    for ax, (label, series) in zip(axes.flat, panels):
        for k, (key, name, scale) in enumerate(series):
            ax.semilogx(e, [scale * r.get(key, math.nan) for r in ok], "o-", color=f"C{k}", label=name)
        ax.axvline(bed_cases.DEFAULTS["youngs_modulus"], color="0.6", ls="--", lw=0.8)
        ax.set_ylabel(label)
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=7)
    ax2 = axes.flat[-1].twinx()
    ax2.semilogx(e, [r["substeps"] for r in ok], "s:", color="C3")
    ax2.set_ylabel("DEM steps per fluid step", color="C3")
    for ax in axes[-1]:
        ax.set_xlabel("Young's modulus E [Pa]")
    fig.suptitle(f"Contact stiffness: the {bed_cases.SIZES[size].count:,}-grain bed ('{size}') at 2 U_mf, "
                 "window 0.1-0.3 s (dashed: fbed's default)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _fmt(v, spec: str) -> str:
    return format(v, spec) if isinstance(v, (int, float)) and math.isfinite(v) else "-"


def report(rows: list[dict], size: str, arch: str) -> str:
    bed = bed_cases.SIZES[size]
    lines = [f"# Contact stiffness ({datetime.date.today().isoformat()}, size '{size}', {arch})", "",
             f"The bed of `fbed bench accuracy`'s bed cases ({bed.count:,} 3 mm glass beads in a "
             f"{2e3 * bed.radius:g} mm cylinder, Wen-Yu, inlet ramped to 2 U_mf over {bed_cases.INLET_RAMP:g} s: "
             f"the bed lifts as a slug), run to {bed.duration:g} s at each Young's modulus, every other setting at "
             f"fbed's default; figures over [{bed.window:g}, {bed.duration:g}] s. Stepping wall: after the first "
             f"{1e3 * bed_cases.WARM_UP:g} ms (compilation), on the CPU scaled by the share of a core the run got. "
             "dP/W: the force balance (pressure drop + floor - the grains' momentum change, over the weight). "
             "Bubbles: Verma's rule in the horizontal layers below the surface (n: how many); slug: the height of "
             "the gas pocket under the lifted bed. Figure: `stiffness.png`; every column: `stiffness.csv`.", "",
             "| E [Pa] | DEM steps / fluid step | stepping wall [s] | mean bed height [mm] | its std [mm] | peak "
             "[mm] | dP/W | bubble d [mm] (n) | slug [mm] | max overlap [% d] | U_mf [m/s] |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        if r.get("status") != "finished":
            lines.append(f"| {r['youngs_modulus']:g} | stopped: {r.get('message', '')[:120]} ||||||||||")
            continue
        lines.append(f"| {r['youngs_modulus']:g} | {r['substeps']} | {r['stepping_wall_s']:.1f} | "
                     f"{1e3 * r['bed_height_mean']:.2f} | {1e3 * r['bed_height_std']:.2f} | "
                     f"{1e3 * r['bed_height_max']:.1f} | {r['dp_over_weight']:.3f} | "
                     f"{_fmt(1e3 * r['bubble_diameter'], '.1f')} ({r['bubbles']}) | "
                     f"{1e3 * r['gas_pocket_height']:.1f} | {r['max_overlap_pct']:.2f} | {r['umf_simulated']:.3f} |")
    lines += ["", "## The default", "", verdict(rows), ""]
    return "\n".join(lines) + "\n"


def stiffness(out: str | None = None, size: str = "small", arch: str = "cpu", threads: int | None = 1,
              moduli: tuple = MODULI, resume: bool = False) -> int:
    """Run the bed at each modulus; write stiffness.csv, stiffness.png and STIFFNESS.md into ``out`` (default
    runs/stiffness) and print the table. ``resume``: keep the moduli already in out/stiffness.csv. Returns 0, or
    130 when a run was stopped by a signal (the moduli measured before it are written)."""
    out_dir = out_folder(out, pathlib.Path("runs") / "stiffness")
    csv_path = out_dir / "stiffness.csv"
    kept = {}
    if resume and csv_path.exists():
        with open(csv_path, newline="") as fh:
            for r in csv.DictReader(fh):
                same_bench(r, csv_path, size, arch)
                kept[float(r["youngs_modulus"])] = {k: (v if k in ("status", "message") else csv_value(v))
                                                    for k, v in r.items() if v != ""}
        print(f"resuming: {len(kept)} moduli kept from {csv_path}", flush=True)
    rows, rc = [], 0
    with runtime.kept(), signals_interrupt():
        runtime.init(arch, bed_cases.DEFAULTS["precision"], threads)
        for e in moduli:
            if e in kept:
                rows.append(kept[e])
                continue
            try:
                rows.append({**measure(e, size), "size": size, "arch": arch})
            except (Interrupted, KeyboardInterrupt) as why:
                print(f"  interrupted: {why or 'a signal'}; the moduli measured are in {csv_path}: go on with "
                      "--resume", flush=True)
                rc = 130
                break
            r = rows[-1]
            print(f"  E = {e:g} Pa: {r.get('status')}, {_fmt(r.get('cost', math.nan), '.1f')} wall s per "
                  "simulated s", flush=True)
            write_csv(rows, csv_path)
    if not rows:
        return rc
    plot(rows, out_dir / "stiffness.png", size)
    text = report(rows, size, arch)
    (out_dir / "STIFFNESS.md").write_text(text)
    print(text)
    return rc

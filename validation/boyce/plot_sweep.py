"""Peak bubble diameter against injection time: fbed beside Boyce et al.'s measured band and MFIX-Exa.

Reads sweep_before_fix.csv (`fbed sweep presets/boyce.toml --set boundary.bottom.jet_duration=...`)
and summary_101.7ms_before_fix.json (the `fbed run presets/boyce.toml` case), both at commit
4fcda58, from this folder, or the files given; marks the 101.7 ms rerun after the coupling fix
(summary_101.7ms.json); writes sweep.png and prints the table (markdown).

    python validation/boyce/plot_sweep.py [SWEEP_CSV] [SUMMARY_JSON]
"""
import csv
import json
import pathlib
import sys

HERE = pathlib.Path(__file__).resolve().parent
BAND = (40.0, 100.0)  # mm, Boyce et al. MRI, over 25-154 ms injections (shared/reference/boyce2019.json)
MFIX = {154.2: "larger and more elongated than measured", 101.7: "larger and more elongated than measured",
        66.7: "V-shaped down-flow captured", 51.4: "too small, collapses before erupting",
        25.0: "too small, collapses before erupting"}


def rows(sweep_csv, summary_json):
    out = []
    for r in csv.DictReader(open(sweep_csv)):
        out.append({k: r.get(k, "") for k in r} | {"jet_ms": 1e3 * float(r["boundary.bottom.jet_duration"])})
    s = json.loads(pathlib.Path(summary_json).read_text())
    out.append({**{k: str(v) for k, v in s.items()}, "jet_ms": 101.7})
    return sorted(out, key=lambda r: r["jet_ms"])


def num(r, k, scale=1.0):
    v = r.get(k, "")
    return float(v) * scale if v not in ("", "None", None) else None


def main(argv):
    sweep_csv = pathlib.Path(argv[0]) if argv else HERE / "sweep_before_fix.csv"
    summary = pathlib.Path(argv[1]) if len(argv) > 1 else HERE / "summary_101.7ms_before_fix.json"
    rs = rows(sweep_csv, summary)
    print("| injection [ms] | peak diameter [mm] | at [ms] | aspect at peak | detached [ms] | erupted [ms] | "
          "collapsed [ms] | rise [m/s] | wall [s] | MFIX-Exa (benchmark doc) |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in rs:
        def f(k, scale=1.0, fmt="{:.0f}"):
            v = num(r, k, scale)
            return fmt.format(v) if v is not None else "-"
        print(f"| {r['jet_ms']:.1f} | {f('bubble_peak_diameter', 1e3)} | {f('bubble_peak_time', 1e3)} | "
              f"{f('bubble_aspect_at_peak', 1, '{:.2f}')} | {f('bubble_detach_time', 1e3)} | "
              f"{f('bubble_eruption_time', 1e3)} | {f('bubble_collapse_time', 1e3)} | "
              f"{f('bubble_rise_velocity', 1, '{:.2f}')} | {f('wall_time', 1, '{:.1f}')} | {MFIX.get(round(r['jet_ms'], 1), '')} |")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    ax.axhspan(*BAND, color="tab:green", alpha=0.15, label="Boyce et al. 2019, MRI (40-100 mm)")
    x = [r["jet_ms"] for r in rs]
    y = [num(r, "bubble_peak_diameter", 1e3) for r in rs]
    erupted = [num(r, "bubble_eruption_time") is not None for r in rs]
    ax.plot(x, y, "k-", lw=1)
    ax.plot([a for a, e in zip(x, erupted) if e], [b for b, e in zip(y, erupted) if e], "ko", label="fbed: erupts")
    ax.plot([a for a, e in zip(x, erupted) if not e], [b for b, e in zip(y, erupted) if not e], "ko", mfc="w",
            label="fbed: collapses in the bed")
    after = HERE / "summary_101.7ms.json"  # the rerun after the coupling fix (commit 57c9ee1)
    if after.exists() and not argv:
        d = json.loads(after.read_text())
        ax.plot([101.7], [1e3 * d["bubble_peak_diameter"]], "r*", ms=12, label="fbed after the coupling fix (57c9ee1)")
    ax.set(xlabel="injection time [ms]", ylabel="peak bubble diameter, central slab [mm]", ylim=(0, 120),
           title="Single-bubble injection, 260k grains (H100)")
    ax.legend(fontsize=8, loc="lower right")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(HERE / "sweep.png", dpi=120)


if __name__ == "__main__":
    main(sys.argv[1:])

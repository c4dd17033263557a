"""The rCFD gas tracer against the run's own gas, fluid step by fluid step (issue 20; validation/rcfd/README.md).

`fbed rcfd run --gas` carries a gas tracer on the frame-mean face fluxes of the database (finite volumes, upwind or
flux-corrected: app.rcfd.transport.step_response). fbed's gas solver carries no tracer, so there was nothing to
check it against. A recording whose frames are one fluid step long holds the very fluxes the gas solver used at
each step: the tracer on it is the gas's own, up to the transport scheme, which both sides share. Coarsening that
recording to frames of k steps (fluxes averaged over the k steps, the void fraction at every k-th boundary: exactly
what a recording at k steps holds) leaves one error, the frame averaging, measured here from the same start times:

    python3 -m app run presets/rcfd_bubbling.toml --out runs/gas_rtd --set probes.rcfd_interval=1e-3 \
        --set probes.rcfd_grain_cells=false --set run.duration=3.5
    python3 validation/rcfd/gas_rtd.py runs/gas_rtd --from 1.0 --factors 1 2 5 10 --out validation/rcfd/gas_rtd

For each start (every --spacing s from --from) and each factor k: a step input at the inlet, the outlet's
mixing-cup concentration F over each frame, and from it the mean residence time tau = int (1 - F) dt, the spread
sigma (int 2 t (1 - F) dt = tau^2 + sigma^2) and t50. Differences are paired (the same start, k against 1). The
ensemble's tau is also checked against the gas volume over the flow (a filled region's balance).
"""
from __future__ import annotations

import argparse
import json
import pathlib
import sys

import h5py
import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from app.rcfd.database import load  # noqa: E402
from app.rcfd.transport import GasTracer, recorded_frames, rtd_moments, step_response  # noqa: E402


#: frame_averaging: every transport on the common substep (--substep), so that only the fluxes differ;
#: as_run: the substeps `fbed rcfd run --gas` takes (Courant number 0.9 on each frame's fluxes)
MODES = ("frame_averaging", "as_run")


def compare(fine: np.ndarray, got: np.ndarray, k: int, dt1: float) -> dict:
    """Step responses on frames of k steps (``got``, starts x frames) against the step-resolved ones on the common
    substep (``fine``), on the same frames: the reference is averaged over each k steps (the outflow is the inflow
    where the region holds every grain, so the flow-weighted mean is the plain one) and its moments taken the same
    way, so that what differs is the transport alone. Paired over the starts."""
    ref_k = np.concatenate([np.zeros((fine.shape[0], 1)), fine.reshape(fine.shape[0], -1, k).mean(2)], axis=1)
    got = np.concatenate([np.zeros((got.shape[0], 1)), got], axis=1)
    mr, mg = [rtd_moments(f, k * dt1) for f in ref_k], [rtd_moments(f, k * dt1) for f in got]
    entry = {"frame_interval": k * dt1, "F_end_min": float(min(m["F_end"] for m in mg))}
    for x in ("tau", "sigma", "t50"):
        ref, val = np.array([m[x] for m in mr]), np.array([m[x] for m in mg])
        d = val - ref
        entry[x] = {"reference_mean": float(np.nanmean(ref)), "mean": float(np.nanmean(val)),
                    "std_over_starts": float(np.nanstd(val, ddof=1)), "paired_difference": float(np.nanmean(d)),
                    "paired_difference_se": float(np.nanstd(d, ddof=1) / np.sqrt(len(d))),
                    "paired_relative_rms": float(np.sqrt(np.nanmean((d / ref) ** 2)))}
    per_start = np.abs(got - ref_k).max(1)
    entry["F_max_difference_median"] = float(np.median(per_start))
    entry["F_max_difference_max"] = float(per_start.max())
    entry["F_mean_max_difference"] = float(np.abs(got.mean(0) - ref_k.mean(0)).max())
    return entry


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("run", help="run folder whose rcfd.h5 has frames of one fluid step")
    ap.add_argument("--from", dest="t_from", type=float, default=1.0, help="first start [s]")
    ap.add_argument("--spacing", type=float, default=0.05, help="between starts [s]")
    ap.add_argument("--horizon", type=float, default=0.2, help="each step response's length [s]")
    ap.add_argument("--factors", type=int, nargs="+", default=[1, 2, 5, 10])
    ap.add_argument("--substep", type=float, default=1e-4,
                    help="the common transport substep [s] (upwind's diffusion depends on it: see the docstring)")
    ap.add_argument("--scheme", choices=GasTracer.SCHEMES, default="upwind", help="the gas tracer's scheme")
    ap.add_argument("--out", default=None)
    a = ap.parse_args(argv)
    a.factors = sorted(set(a.factors) | {1})  # 1: the reference
    db = load(pathlib.Path(a.run))
    dt1 = db.frame_interval
    if abs(dt1 - float(db.attrs["step"])) > 1e-12 * dt1:
        raise SystemExit(f"{a.run}: frames of {dt1:g} s, not one fluid step ({db.attrs['step']:g} s)")
    with h5py.File(db.path, "r") as f:
        fluxes = [f[f"frame/flux_{x}"][: db.n_frames] for x in "xyz"]
    t_start = db.time[db.b0]
    kmax = max(a.factors)
    n1 = int(round(a.horizon / dt1))
    n1 -= n1 % kmax  # a whole number of the coarsest frames
    starts = [int(i) for i in np.nonzero(np.isclose((t_start - a.t_from) / a.spacing,
                                                    np.round((t_start - a.t_from) / a.spacing), atol=1e-6)
                                         & (t_start >= a.t_from - 1e-9))[0] if i + n1 <= db.n_frames]
    if not starts:
        raise SystemExit(f"no start from {a.t_from:g} s leaves {a.horizon:g} s of frames")
    fine, coarse = [], {(k, mode): [] for k in a.factors for mode in MODES}
    worst = {"balance_error": 0.0, "c_min": 1.0, "c_max": 0.0}
    for s in starts:
        for k in a.factors:
            for mode in MODES:
                r = step_response(db.open_volume, db.h, recorded_frames(db, fluxes, s, n1 // k, k),
                                  k * dt1, max_substep=a.substep if mode == "frame_averaging" else None,
                                  scheme=a.scheme)
                coarse[k, mode].append(r["F"][1:])
                worst = {"balance_error": max(worst["balance_error"], r["balance_error"]),
                         "c_min": min(worst["c_min"], r["c_min"]), "c_max": max(worst["c_max"], r["c_max"])}
        fine.append(coarse[1, "frame_averaging"][-1])
    fine = np.asarray(fine)
    # the filled region's balance: tau = gas volume / flow, over the window the starts span
    b = slice(int(db.b0[starts[0]]), int(db.b1[starts[-1] + n1 - 1]) + 1)
    gas_volume = float(np.mean(np.sum(db.eps[b] * db.open_volume, axis=(1, 2, 3)))) * db.h ** 3
    inflow = float(np.mean(np.sum(np.maximum(fluxes[2][starts[0]:starts[-1] + n1, :, :, 0], 0), axis=(1, 2))))
    out = {"run": str(a.run), "scheme": a.scheme, "substep": a.substep, "frame_interval_recorded": dt1,
           "starts": len(starts), "first_start": float(t_start[starts[0]]), "last_start": float(t_start[starts[-1]]),
           "horizon": n1 * dt1, "gas_volume_over_flow": gas_volume / inflow, "tracer": worst, "factors": {}}
    for k in a.factors:
        out["factors"][str(k)] = {mode: compare(fine, np.asarray(coarse[k, mode]), k, dt1) for mode in MODES}
    text = json.dumps(out, indent=1)
    print(text)
    if a.out:
        od = pathlib.Path(a.out)
        od.mkdir(parents=True, exist_ok=True)
        (od / "gas_rtd.json").write_text(text + "\n")
        plot(od / "gas_rtd.png", fine, {k: np.asarray(coarse[k, "as_run"]) for k in a.factors}, dt1, a.factors)
    return 0


def plot(path: pathlib.Path, fine: np.ndarray, coarse: dict, dt1: float, factors) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    t = (np.arange(fine.shape[1]) + 1) * dt1
    ax.fill_between(t * 1e3, np.percentile(fine, 10, 0), np.percentile(fine, 90, 0), alpha=0.2, color="k",
                    label="10-90% of the starts, step-resolved")
    ax.plot(t * 1e3, fine.mean(0), "k", label="step-resolved fluxes (1 ms), common substep")
    for k in factors:
        if k == 1:
            continue
        c = coarse[k]
        tk = (np.arange(c.shape[1]) + 0.5) * k * dt1
        ax.plot(tk * 1e3, c.mean(0), "o-", ms=3, label=f"frames of {k * dt1 * 1e3:g} ms, as `fbed rcfd run`")
    ax.set_xlim(0, 100)
    ax.set_xlabel("time after the step [ms]")
    ax.set_ylabel("outlet concentration F (mean over the starts)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


if __name__ == "__main__":
    sys.exit(main())

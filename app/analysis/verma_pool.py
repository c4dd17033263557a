"""Several runs of the Verma bed pooled (`fbed analyze RUN RUN ... --out DIR` on verma runs): the whole preset's
window (1-6.5 s) does not fit one GPU session, so its sessions go on from each other's packed states
(benchmarks/device_run.sh ``verma_pack``, ``VERMA_FROM``) and their analysed windows are pooled as realisations of
one operating point (``pooling.check_same_case``).

Each run's records from its own window start (output.average_from) are laid end to end in time (each run's times
shifted by one constant, so intervals and velocities are its own). The frame-by-frame figures (bubble diameters,
porosity PDFs, the diameter profile, the pressure drop over the weight) pool as the frames do; the plane pairs'
correlation is each run's own summed (``rise.rise_velocity``'s ``segments``), noses and tails pair within a run,
and no bubble is followed from one run into the next. Whether the runs are one operating point: their pressure drops
over the weight against each other, with errors over blocks of correlated steps (``mri_stats.sessions_agree``).
Plain numpy, no Taichi.
"""
from __future__ import annotations

import json
import pathlib

import numpy as np

from . import verma
from .mri_stats import block_frames, sessions_agree


def _shifted(run: dict, shift: float) -> dict:
    """A run's records from its window start on, every time plus ``shift`` [s]."""
    planes = {k: dict(p, time=p["time"] + shift) for k, p in run["planes"].items()}
    vol = None if run["vol"] is None else dict(run["vol"], time=run["vol"]["time"] + shift)
    t, dp = run["series_t"], run["dp"]
    keep = t >= run["t_cut"] if t is not None else None
    return dict(run, planes=planes, vol=vol, series_t=None if t is None else t[keep] + shift,
                dp=None if dp is None else dp[keep])


def _window(run: dict) -> tuple[float, float]:
    ts = [p["time"] for p in run["planes"].values()] + ([run["vol"]["time"]] if run["vol"] is not None else [])
    ends = [float(t[-1]) for t in ts if len(t)]
    return run["t_cut"], max(ends) if ends else run["t_cut"]


def merge(runs: list[dict]) -> dict:
    """One record of several runs' windows (``verma._read_run``'s dicts, in order) with their first frames under
    ``segments``; planes and 3-D grids must match (else ValueError naming the record; the vessel's mask is the
    first run's, one case's: ``pooling.check_same_case`` compared the vessels)."""
    names = set(runs[0]["planes"])
    if any(set(r["planes"]) != names for r in runs) or any((r["vol"] is None) != (runs[0]["vol"] is None)
                                                          for r in runs):
        raise ValueError("the runs recorded different planes or 3-D frames: pool runs of one case")
    steps = ([float(np.median(np.diff(p["time"]))) for r in runs for p in r["planes"].values() if len(p["time"]) > 1]
             + [float(np.median(np.diff(r["vol"]["time"]))) for r in runs if r["vol"] is not None
                and len(r["vol"]["time"]) > 1])
    step = min(steps) if steps else 1e-3  # [s] between one run's last record and the next one's first
    shifted, offset = [], runs[0]["t_cut"]
    for r in runs:
        t0, t1 = _window(r)
        shifted.append(_shifted(r, offset - t0))
        offset += (t1 - t0) + step
    first = shifted[0]

    def cat(key, recs):
        return np.concatenate([x[key] for x in recs])

    planes = {}
    for name in sorted(names):
        recs = [s["planes"][name] for s in shifted]
        if len({(x["porosity"].shape[1:], x["z"], x["h"]) for x in recs}) > 1:
            raise ValueError(f"plane {name} differs between the runs (height, cell or shape): pool runs of one case")
        planes[name] = dict(recs[0], time=cat("time", recs), porosity=cat("porosity", recs))
    vol = None
    if first["vol"] is not None:
        recs = [s["vol"] for s in shifted]
        if len({(x["porosity"].shape[1:], x["h"]) for x in recs}) > 1:
            raise ValueError("the 3-D frames differ between the runs (cell or shape): pool runs of one case")
        vol = dict(recs[-1], time=cat("time", recs), porosity=cat("porosity", recs))
    n_planes = [len(next(iter(s["planes"].values()))["time"]) if names else 0 for s in shifted]
    n_vol = [len(s["vol"]["time"]) for s in shifted] if vol is not None else []
    series = [s for s in shifted if s["series_t"] is not None]
    n_series = [len(s["series_t"]) for s in series]
    return dict(first, planes=planes, vol=vol, t_cut=runs[0]["t_cut"],
                series_t=cat("series_t", series) if len(series) == len(shifted) else None,
                dp=cat("dp", series) if len(series) == len(shifted) and all(s["dp"] is not None for s in series)
                else None,
                segments={"planes": np.cumsum([0] + n_planes[:-1]), "vol": np.cumsum([0] + n_vol[:-1]),
                          "series": np.cumsum([0] + n_series[:-1])},
                frames={"planes": n_planes, "porosity3d": n_vol})


def summarize_pooled(run_dirs, out_dir) -> dict:
    """The Verma analysis of several runs of one case pooled into OUT/analysis (table, figures) and OUT/pooled.json
    (the runs, their frames, the session keys that differ, the figures)."""
    from .. import config as cfgmod
    from .pooling import check_same_case

    run_dirs, out_dir = [pathlib.Path(d) for d in run_dirs], pathlib.Path(out_dir)
    cfgs = [cfgmod.load(d / "config.toml") for d in run_dirs]
    runs = [verma._read_run(d / verma.RUN_FILE, 1.0, c.output.average_from) for d, c in zip(run_dirs, cfgs)]
    for d, r in zip(run_dirs, runs):
        if not r["planes"] and r["vol"] is None:
            raise ValueError(f"{d}/run.h5 holds neither /planes nor /porosity3d")
    notes = check_same_case(run_dirs, [_window(r) for r in runs], cfgs)
    weights = [float(json.loads((d / verma.SUMMARY_FILE).read_text())[verma.BED_WEIGHT_KEY]) for d in run_dirs]
    if max(weights) - min(weights) > 1e-6 * max(weights):  # the grains lost through the outlet differ
        notes.append(f"bed weight per area {min(weights):.6g}-{max(weights):.6g} Pa over the runs: their mean is used")
    merged = merge(runs)
    res = verma.analyze_records(merged, float(np.mean(weights)), out_dir / verma.ANALYSIS_DIR)
    figs = {"verma_runs": len(run_dirs)} | verma.summary_figures(res)
    agree = None
    if merged["dp"] is not None:  # do the runs' pressure drops agree within their errors (blocks of correlated steps)?
        x, seg = merged["dp"] / float(np.mean(weights)), merged["segments"]["series"]
        agree = sessions_agree(x, seg, block_frames(x, seg))
        figs |= {"verma_runs_dp_chi2": agree["chi2"], "verma_runs_dp_p": agree["p"]}
    record = dict(runs=[str(d) for d in run_dirs], frames=merged["frames"], windows=[_window(r) for r in runs],
                  bubbles_per_plane={n: p["count"] for n, p in res["planes"].items()}, session_differences=notes,
                  runs_dp_over_weight=agree, figures=figs)
    (out_dir / "pooled.json").write_text(json.dumps(record, indent=2) + "\n")
    return figs

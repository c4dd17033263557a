"""`fbed rcfd analyze RUN` and `fbed rcfd run RUN`: recurrence statistics and rCFD paths of a recorded run.

analyze -> RUN/rcfd/: recurrence.png, spectrum.png, rcfd.json (period from the mid-bed void fraction and
           from the bed height, the first recurrence of D(tau), the database-length check, the frame check).
run     -> RUN/rcfd/<name>/: mixing.csv, mixing.png, path.csv, recurrence_path.png, summary.json (per path and
           ensemble: mixing index, t50, t90, the volume stitched at jumps, conservation; bed height and radial
           void profile along the paths against the database; marginal and total speed-up).
"""
from __future__ import annotations

import json
import math
import pathlib
import time as wallclock

import h5py
import numpy as np

from ..io import store
from ..outputs import out_folder
from . import paths as pathmod
from . import recurrence as rec
from .database import Database, load, tag_mask
from .engine import Engine, bed_mask, statistics
from .transport import mixing_index_real, rtd_moments

def write_json(path: pathlib.Path, data: dict) -> None:
    """``data`` as JSON (numpy scalars as their values, anything else as its text), written as every fbed file is
    (:func:`app.io.store.write_text`: whole or not at all, a full disk a clean error)."""
    store.write_text(path, json.dumps(data, indent=2, default=lambda o: o.item() if hasattr(o, "item") else str(o))
                     + "\n")


def analyze(run_dir: str, out: str | None = None) -> dict:
    db = load(run_dir)
    st = statistics(db)
    od = out_folder(out, pathlib.Path(run_dir) / "rcfd")
    dt = db.frame_interval / int(db.attrs.get("lag", 1))
    lv = rec.levelled_off(st["best"])
    sp_eps, sp_h = st["sp_eps"], st["sp_h"]
    res = {
        "frames": db.n_frames, "states": db.n_states, "frame_interval": dt,
        "t0": float(db.time[0]), "t1": float(db.time[-1]), "bed_cells": int(st["mask"].sum()),
        "cells": db.n_cells, "recurrence_norm": st["norm"], "recurrence_seconds": st["R_seconds"],
        "mid_bed_height": float(db.origin[2] + (st["k_mid"] + 0.5) * db.h),
        "period_mid_bed_eps": sp_eps["period"], "frequency_mid_bed_eps": sp_eps["peak_frequency"],
        "period_bed_height": sp_h["period"], "frequency_bed_height": sp_h["peak_frequency"],
        "spectral_bin": sp_eps["df"], "first_recurrence_lag": st["lag"] * dt,
        "similarity_window": st["window"], "similarity_final": float(st["S"][-1]),
        "database_levelled_off": lv["levelled_off"], "similarity_last_quarter_rise": lv["last_quarter_rise"],
        "halves": st["halves"], "mean_bed_height": float(np.mean(db.bed_height)),
        "std_bed_height": float(np.std(db.bed_height)),
        "taylor_time": float(db.attrs.get("taylor_time", float("nan"))),
        "taylor_time_at_frame_interval": float(db.attrs.get("taylor_time_frame", float("nan"))),
        "frame_check": str(db.attrs.get("frame_check", "not recorded")),
        "grains": int(db.attrs.get("grains", 0)),
        "mixing_index_real_last": mixing_index_real(db.tagged[-1], db.solid[-1]),
    }
    if db.has_flux:
        res["continuity_residual"] = continuity_residual(db)
    units = {"frame_interval": "s", "t0": "s", "t1": "s", "period_mid_bed_eps": "s", "period_bed_height": "s",
             "frequency_mid_bed_eps": "Hz", "frequency_bed_height": "Hz", "spectral_bin": "Hz",
             "first_recurrence_lag": "s", "mean_bed_height": "m", "std_bed_height": "m", "taylor_time": "s",
             "taylor_time_at_frame_interval": "s", "recurrence_seconds": "s", "mid_bed_height": "m"}
    res["units"] = units
    write_json(od / "rcfd.json", res)
    _plot_recurrence(od / "recurrence.png", st["R"], db.time)
    _plot_spectrum(od / "spectrum.png", st, db, res)
    np.save(od / "recurrence.npy", st["R"].astype(np.float32))
    return res


def continuity_residual(db: Database) -> float:
    """Median over frames of max over bed cells |sum of outflows + theta V d(eps)/dt| / (sum of |face fluxes|)
    of the frame-mean fluxes (how well the recorded fluxes would carry a gas tracer)."""
    out = []
    vol = db.open_volume * db.cell_volume
    mask = bed_mask(db)
    for k in range(0, db.n_frames, max(1, db.n_frames // 50)):
        fx, fy, fz = db.flux(k)
        div = (fx[1:] - fx[:-1]) + (fy[:, 1:] - fy[:, :-1]) + (fz[:, :, 1:] - fz[:, :, :-1])
        deps = (db.eps[db.b1[k]].astype(np.float64) - db.eps[db.b0[k]]) / db.frame_interval * vol
        gross = (np.abs(fx[1:]) + np.abs(fx[:-1]) + np.abs(fy[:, 1:]) + np.abs(fy[:, :-1]) + np.abs(fz[:, :, 1:])
                 + np.abs(fz[:, :, :-1]))
        r = np.abs(div + deps)[mask] / np.maximum(gross[mask].max(), 1e-300)
        out.append(float(r.max()))
    return float(np.median(out))


def pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _plot_recurrence(path, R, time, paths=None):
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6.4, 5.6))
    ext = (time[0], time[-1], time[-1], time[0])
    im = ax.imshow(R, extent=ext, cmap="viridis", vmin=0, vmax=1, interpolation="nearest")
    fig.colorbar(im, ax=ax, label="R (normalised squared difference of eps)")
    if paths:
        for p, colour in zip(paths, ("w", "r", "orange")):
            for pos, s_from, s_to, r in p["jumps"]:
                ax.plot([time[s_from]], [time[s_to]], "o", ms=4, mfc="none", mec=colour)
            for start, length, state0 in p["sequences"]:
                t_a, t_b = time[state0], time[min(state0 + length, len(time) - 1)]
                ax.plot([t_a, t_b], [t_a, t_b], "-", color=colour, lw=2, alpha=0.8)
        ax.set_title("recurrence plot; path 0: sequences on the diagonal, jumps (from, to) as circles")
    else:
        ax.set_title("recurrence plot of the bed's void fraction")
    ax.set_xlabel("t_i [s]")
    ax.set_ylabel("t_j [s]")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _plot_spectrum(path, st, db, res):
    plt = pyplot()
    fig, axs = plt.subplots(2, 2, figsize=(10, 7))
    for ax, sp, name in ((axs[0, 0], st["sp_eps"], f"mid-bed void fraction (z = {res['mid_bed_height']:.3g} m)"),
                         (axs[0, 1], st["sp_h"], "bed height")):
        ax.semilogy(sp["freq"][1:], sp["power"][1:] + 1e-300, "k.-", lw=0.8)
        ax.axvline(sp["peak_frequency"], color="r", label=f"peak {sp['peak_frequency']:.3g} Hz "
                   f"(period {sp['period']:.3g} s)")
        ax.axvspan(sp["peak_frequency"] - 0.5 * sp["df"], sp["peak_frequency"] + 0.5 * sp["df"], color="r", alpha=0.15,
                   label=f"one bin: {sp['df']:.3g} Hz")
        ax.set_xlabel("frequency [Hz]")
        ax.set_ylabel("power (Hann)")
        ax.set_title(name)
        ax.legend(fontsize=8)
    dt = db.frame_interval / int(db.attrs.get("lag", 1))
    lags = np.arange(st["Dtau"].size) * dt
    axs[1, 0].plot(lags, st["Dtau"], "k-")
    if st["lag"]:
        axs[1, 0].axvline(st["lag"] * dt, color="r", label=f"first recurrence {st['lag'] * dt:.3g} s")
        axs[1, 0].legend(fontsize=8)
    axs[1, 0].set_xlabel("lag [s]")
    axs[1, 0].set_ylabel("mean R at lag")
    axs[1, 0].set_title("mean distance against lag")
    axs[1, 1].plot(db.time, st["best"], "k.", ms=2, label="best earlier recurrence of each state")
    axs[1, 1].plot(db.time, st["S"], "b-", label="its running mean S(n)")
    axs[1, 1].legend(fontsize=8)
    axs[1, 1].set_xlabel("t [s]")
    axs[1, 1].set_ylabel("1 - R")
    axs[1, 1].set_title(f"similarity to the best earlier state (window {st['window']} frames): "
                        f"{'levelled off' if res['database_levelled_off'] else 'still rising'}", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


# ------------------------------------------------------------------------------------------------ run
def crossing_time(t: np.ndarray, M: np.ndarray, level: float) -> float:
    """First time M reaches ``level`` (linear between samples; NaN if never)."""
    above = np.nonzero(M >= level)[0]
    if not above.size:
        return float("nan")
    i = int(above[0])
    if i == 0:
        return float(t[0])
    return float(t[i - 1] + (level - M[i - 1]) / (M[i] - M[i - 1]) * (t[i] - t[i - 1]))


def radial_profiles(db: Database) -> tuple[np.ndarray, np.ndarray]:
    """(bin centres [m], (B, bins) mean eps per radial ring of width h over the cells below the mean bed height)."""
    cc = db.cell_centres()
    r = np.hypot(cc[..., 0] - db.axis[0], cc[..., 1] - db.axis[1])
    below = cc[..., 2] < np.mean(db.bed_height)
    ok = (db.open_volume > 0) & below
    bins = np.floor(r / db.h).astype(int)
    nb = int(bins[ok].max()) + 1
    w = db.open_volume * ok
    num = np.stack([np.bincount(bins.ravel(), weights=(e * w).ravel(), minlength=nb) for e in db.eps])
    den = np.bincount(bins.ravel(), weights=w.ravel(), minlength=nb)
    return (np.arange(nb) + 0.5) * db.h, num / np.maximum(den, 1e-300)


def full_cost_per_second(run_dir: pathlib.Path, t0: float, t1: float) -> float:
    """The full CFD-DEM run's wall time per simulated second over t0..t1 [s/s] (stepping and callbacks, recording
    included), from run.h5's wall_time series."""
    try:
        with h5py.File(run_dir / "run.h5", "r") as f:
            t, w = f["series/time"][...], f["series/wall_time"][...]
    except (OSError, KeyError):
        return float("nan")
    ok = np.isfinite(w)
    t, w = t[ok], w[ok]
    if t.size < 2:
        return float("nan")
    a, b = np.interp([t0, t1], t, w)
    return float((b - a) / (t1 - t0)) if t1 > t0 and b >= a else float("nan")


def initial_concentration(db: Database, state: int, tag: str | None) -> np.ndarray:
    """c per cell at ``state``: the real grains' tag_now (the recorded tag) or the tag on cell centres."""
    if tag is None or tag.replace(" ", "") == db.tag.replace(" ", ""):
        sol = db.solid[state].astype(np.float64)
        return np.divide(db.tag_now[state].astype(np.float64), sol, out=np.zeros(db.n_cells), where=sol > 0).clip(0, 1)
    return tag_mask(tag, db.cell_centres().reshape(-1, 3)).astype(np.float64)


def _check_tagged(db: Database, state: int, c: np.ndarray, tag: str) -> None:
    """Some grains and not all must be tagged: 'z>100' (none) or 'x<=1e9' (all) gave mixing and Lacey indices of
    NaN on every path, without a word."""
    sol = db.solid[state].astype(np.float64)
    tagged, total = float(np.sum(c * sol)), float(np.sum(sol))
    if 0.0 < tagged < total * (1.0 - 1e-9):
        return
    occupied = db.cell_centres().reshape(-1, 3)[sol > 0]
    span = ", ".join(f"{a} {lo:.4g}..{hi:.4g}" for a, lo, hi in zip("xyz", occupied.min(0), occupied.max(0)))
    raise ValueError(f"--tag {tag!r} tags {'none' if tagged <= 0 else 'all'} of the grains at t = "
                     f"{float(db.time[state]):.4g} s (their cells' centres span {span} m): the mixing index needs "
                     "grains tagged and grains not")


def _write_curves(path: pathlib.Path, time: np.ndarray, Ms: np.ndarray) -> None:
    """A csv of each path's index against time, with the ensemble mean and std."""
    mean, std = Ms.mean(0), Ms.std(0, ddof=1) if len(Ms) > 1 else np.zeros(Ms.shape[1])
    with open(path, "w") as f:
        f.write("time," + ",".join(f"path{i}" for i in range(len(Ms))) + ",mean,std\n")
        for j in range(Ms.shape[1]):
            f.write(f"{time[j]:.6g}," + ",".join(f"{v:.6f}" for v in Ms[:, j]) + f",{mean[j]:.6f},{std[j]:.6f}\n")


def _write_paths(od: pathlib.Path, db: Database, time: np.ndarray, Ms: np.ndarray, Ls: np.ndarray, ps: list) -> None:
    """mixing.csv (the cell index), lacey.csv (Lacey's index) and path.csv (the frames of every path)."""
    _write_curves(od / "mixing.csv", time, Ms)
    _write_curves(od / "lacey.csv", time, Ls)
    with open(od / "path.csv", "w") as f:
        f.write("path,position,frame,state_start,time_in_database,jump\n")
        for i, p in enumerate(ps):
            jpos = {j[0] for j in p.jumps}
            for pos, k in enumerate(p.frames):
                f.write(f"{i},{pos},{k},{db.b0[k]},{db.time[db.b0[k]]:.6g},{int(pos in jpos)}\n")


def path_bed_statistics(db: Database, ps: list) -> dict:
    """Bed height and radial void profile at every recorded boundary the paths pass (a lagged frame spans
    several: no aliasing on the bed's period), against the database's."""
    lag = int(db.attrs.get("lag", 1))
    visited = [np.concatenate([np.arange(db.b0[k] + 1, db.b1[k] + 1) for k in p.frames]) for p in ps]
    heights = np.stack([db.bed_height[v] for v in visited])
    rbins, prof = radial_profiles(db)
    path_prof = np.stack([prof[v].mean(0) for v in visited])
    sp = [rec.spectrum(hh, db.frame_interval / lag) for hh in heights]
    return {"bed_height_mean": float(heights.mean()), "bed_height_std": float(heights.std(1).mean()),
            "bed_height_frequency": float(np.mean([s["peak_frequency"] for s in sp])),
            "database_bed_height_mean": float(db.bed_height.mean()), "database_bed_height_std": float(db.bed_height.std()),
            "radial_bins": rbins.tolist(), "radial_eps_paths": path_prof.mean(0).tolist(),
            "radial_eps_database": prof.mean(0).tolist()}


def _gas_paths(eng: Engine, ps: list, od: pathlib.Path, time: np.ndarray, horizon: float, scheme: str) -> dict:
    """The gas tracer's step response along every path from its start (rtd.csv), and the residence time
    distribution averaged over injection times (``injected_rtd``), with their summaries (``scheme``: GasTracer's)."""
    gr = [eng.gas_transport(p, scheme=scheme) for p in ps]
    Fs = np.stack([g["F"] for g in gr])
    Fm = np.nanmean(Fs, 0)
    with open(od / "rtd.csv", "w") as f:
        f.write("time," + ",".join(f"path{i}" for i in range(len(ps))) + ",mean\n")
        for j in range(time.size):
            f.write(f"{time[j]:.6g}," + ",".join(f"{v:.6f}" for v in Fs[:, j]) + f",{Fm[j]:.6f}\n")
    injected, balance = injected_rtd(eng, ps, od, scheme)
    return {"scheme": scheme, **rtd_summary(np.nan_to_num(Fm), eng.db.frame_interval), "injected": injected,
            "balance_error_max": max([g["balance_error"] for g in gr] + [balance]),
            "jump_mass_share_max": max(g["jump_share"] for g in gr),
            "c_min": min(g["c_min"] for g in gr), "c_max": max(g["c_max"] for g in gr),
            "wall_per_simulated_second_per_path": sum(g["wall"] for g in gr) / (len(ps) * horizon),
            "note": "step input c = 1 at the inlet from the path's start; F(t) = the outlet's mixing-cup c "
                    "(region top); finite volumes on the frame-mean fluxes, substeps at Courant number 0.9. "
                    "Against the step-resolved fluxes (validation/rcfd/gas_rtd.py): frames of 5 ms change F by "
                    "under 0.002; the scheme's own diffusion, set by the substep, moves the spread by 3-5% (fct) "
                    "or 8-13% (upwind). 'injected': the step responses of injections along the paths, averaged "
                    "(the distribution over injection times, as a tracer fed at any moment sees it)"}


def rtd_summary(F: np.ndarray, dt: float) -> dict:
    """A step response's last value and its residence times (transport.rtd_moments; the mean and spread only of a
    response that has come through, F > 0.99: else they are not its distribution's)."""
    m = rtd_moments(F, dt)
    done = m["F_end"] > 0.99
    return {"step_response_final": m["F_end"], "mean_residence_time": m["tau"] if done else float("nan"),
            "residence_time_spread": m["sigma"] if done else float("nan"), "median_residence_time": m["t50"]}


def injected_rtd(eng: Engine, ps: list, od: pathlib.Path, scheme: str) -> tuple[dict, float]:
    """The residence time distribution averaged over injection times: a step input at every ``every``-th frame of
    each path that leaves a window of half the path, its response over that window (jumps inside it included),
    averaged over injections and paths (rtd_injected.csv: the mean and the spread over injections); its summary,
    and the largest tracer balance error of the injections."""
    n = len(ps[0].frames)
    window = max(1, n // 2)
    every = max(1, window // 4)
    curves, balance = [], 0.0
    for p in ps:
        for first in range(0, n - window + 1, every):
            g = eng.gas_transport(p, scheme=scheme, first=first, count=window)
            curves.append(g["F"])
            balance = max(balance, g["balance_error"])
    F = np.nan_to_num(np.stack(curves))
    mean, spread = F.mean(0), F.std(0)
    dt = eng.db.frame_interval
    with open(od / "rtd_injected.csv", "w") as f:
        f.write("time,mean,std\n")
        for j in range(mean.size):
            f.write(f"{j * dt:.6g},{mean[j]:.6f},{spread[j]:.6f}\n")
    return {"injections": len(curves), "window": window * dt, "every": every * dt, **rtd_summary(mean, dt)}, balance


def lacey_summary(time: np.ndarray, Ls: np.ndarray) -> dict:
    """Lacey's index along the paths: its time mean, final value and t50, t90 (ensemble means)."""
    t50 = [crossing_time(time, L, 0.5) for L in Ls]
    t90 = [crossing_time(time, L, 0.9) for L in Ls]
    nan_mean = (lambda v: float(np.nanmean(v)) if np.isfinite(v).any() else float("nan"))
    return {"time_mean": float(np.nanmean(Ls)), "final_mean": float(np.nanmean(Ls[:, -1])), "t50": t50, "t90": t90,
            "t50_mean": nan_mean(t50), "t90_mean": nan_mean(t90),
            "note": "Lacey 1954 (app.rcfd.transport.lacey_index): 0 segregated, 1 random whatever the grains per cell"}


def jump_summary(results: list) -> dict:
    """What the jumps did to the tracer: the change of the cell index across each jump and the share of the tagged
    volume that changed cell there (grain tracer only)."""
    dM = [x for r in results for x in r.get("jump_dM", [])]
    tm = [x for r in results for x in r.get("tag_moved", [])]
    return {"jump_dM_mean": float(np.mean(dM)) if dM else float("nan"),
            "jump_tag_moved_share_mean": float(np.mean(tm)) if tm else float("nan")}


def _path_warnings(balance: float, R_jumps: list, moved: list) -> list:
    out = []
    if balance > 2.0:
        out.append(f"a frame is visited {balance:.2g}x as often as the mean frame (more than 2x)")
    if R_jumps and float(np.median(R_jumps)) > 0.2:
        out.append(f"the median R at jumps is {np.median(R_jumps):.3g} (> 0.2): the database has few good recurrences")
    if moved and max(moved) > 0.01:
        out.append(f"a jump moved {100 * max(moved):.2g}% of the grain volume to other (jump grid) cells (> 1%)")
    return out


def cost_summary(eng: Engine, rd: pathlib.Path, results: list, horizon: float, t_path: float) -> dict:
    """The speed-up account: c_full from the database run, c_r from the median path (robust on a shared CPU)."""
    db = eng.db
    c_r = float(np.median([r["wall"] for r in results])) / horizon
    c_full = full_cost_per_second(rd, float(db.time[0]), float(db.time[-1]))
    t_db = float(db.time[-1] - db.time[0])
    prep = eng.prep_seconds + eng.stitch_seconds + t_path
    n = len(results)
    return {"full_wall_per_simulated_second": c_full, "rcfd_wall_per_simulated_second_per_path": c_r,
            "prep_seconds": prep, "recurrence_seconds": eng.st["R_seconds"], "stitch_seconds": eng.stitch_seconds,
            "path_seconds": t_path, "database_seconds_simulated": t_db,
            "marginal_speedup": c_full / c_r if c_r > 0 else float("inf"),
            "total_speedup_with_database": c_full * horizon / (c_full * t_db + prep + n * c_r * horizon),
            "total_speedup_without_database": c_full * horizon / (prep + n * c_r * horizon),
            "note": "marginal: full wall per simulated second / rCFD transport wall per simulated second of the "
                    "median path (mixing index after every frame included); total (horizon T, n paths): c_full T / "
                    "(c_full t_db + prep + n c_r T), with the database run counted, and without it (when it was "
                    "run anyway)"}


def run_paths(run_dir: str, horizon: float, n_paths: int, seed: int, tag: str | None, name: str | None = None,
              out: str | None = None, start: str = "end", engine: Engine | None = None, log=print,
              gas: bool | str = False, lag: int = 1, jump: str | None = None, workers: int | None = None) -> dict:
    """`fbed rcfd run`: n_paths seeded Markov paths over ``horizon`` seconds from the database's last state
    (start='end') or its first (start='begin'). ``jump``: 'match', 'flow' or 'stitch' (Engine's ``jump``); None:
    Engine's 'auto'. ``gas``: also a gas tracer, by this scheme ('fct' or
    'upwind'; True: 'fct'). ``workers``: processes the jumps and the paths are spread over (default: one per
    core)."""
    rd = pathlib.Path(run_dir)
    db = engine.db if engine else load(rd, lag)
    if engine is None and jump in ("match", "flow") and db.cells is None:
        raise ValueError(f"jump {jump!r} pairs grains and needs each grain's cell per boundary (record with "
                         "probes.rcfd_grain_cells = true); use --jump stitch")
    eng = engine or Engine(db, jump=jump or "auto")
    dt = db.frame_interval
    n_frames = int(math.ceil(horizon / dt - 1e-9))
    need, have = n_frames * (32.0 * n_paths + 8.0), store.available_memory()  # each path's frames, mixing and
    if have is not None and need > have:                                    # Lacey indices, and the times
        raise ValueError(f"--horizon {horizon:g} s is {n_frames:,} frames of {dt:g} s a path: {n_paths} path(s) "
                         f"need about {need / 1e9:.3g} GB of memory, and {have / 1e9:.3g} GB is available")
    start_state = db.n_states - 1 if start == "end" else 0
    c0 = initial_concentration(db, start_state, tag)
    _check_tagged(db, start_state, c0, tag or db.tag)
    od = out_folder(out, rd / "rcfd" / (name or f"run_T{horizon:g}_N{n_paths}_s{seed}"))
    t_path = wallclock.perf_counter()
    ps = [eng.path(n_frames, start_state, (seed, i)) for i in range(n_paths)]
    t_path = wallclock.perf_counter() - t_path
    eng.prefetch_jumps(ps, workers, progress=lambda done, total: log(
        f"fbed: rcfd run: {done}/{total} jumps built and stored in {eng.matchings_path}"))
    results = eng.transport_paths(ps, c0, start_state, workers)
    stored = eng.save_matchings()
    time = np.arange(n_frames + 1) * dt
    Ms = np.stack([r["M"] for r in results])
    Ls = np.stack([r["lacey"] for r in results])
    mean, std = Ms.mean(0), Ms.std(0, ddof=1) if n_paths > 1 else np.zeros(n_frames + 1)
    _write_paths(od, db, time, Ms, Ls, ps)
    t50 = [crossing_time(time, r["M"], 0.5) for r in results]
    t90 = [crossing_time(time, r["M"], 0.9) for r in results]
    moved = [m for r in results for m in r["moved"]]
    R_jumps = [j[3] for p in ps for j in p.jumps]
    balance = pathmod.visit_balance(np.concatenate([p.frames for p in ps]), db.n_frames)
    warnings = _path_warnings(balance, R_jumps, moved)
    same_tag = tag is None or tag.replace(" ", "") == db.tag.replace(" ", "")
    nan_mean = (lambda v: float(np.nanmean(v)) if np.isfinite(v).any() else float("nan"))
    summary = {
        "run": str(rd), "horizon": horizon, "paths": n_paths, "seed": seed, "seeds": [list(p.seed) for p in ps],
        "start_state": start_state, "start_time": float(db.time[start_state]), "tag": tag or db.tag,
        "tag_source": "real grains (recorded tag_now)" if same_tag else "cell centres", "solids": eng.solids,
        "jump_cells": "half cells" if getattr(eng, "half", False) else "cells",
        "frames_per_path": n_frames, "frame_interval": dt, "lag": int(db.attrs.get("lag", 1)),
        "l_min": eng.params.l_min, "l_mean": eng.params.l_mean, "window": eng.params.window,
        "jumps_per_path": float(np.mean([len(p.jumps) for p in ps])),
        "median_R_at_jumps": float(np.median(R_jumps)) if R_jumps else float("nan"), "visit_balance": balance,
        "stitched_share_mean": float(np.mean(moved)) if moved else 0.0,
        "stitched_share_max": float(np.max(moved)) if moved else 0.0,
        "tracer_drift_max": max(r["drift"] for r in results),
        "concentration_min": min(r["c_min"] for r in results), "concentration_max": max(r["c_max"] for r in results),
        "mixing_final_mean": float(mean[-1]), "mixing_final_std": float(std[-1]),
        "mixing_time_mean": float(mean.mean()),
        "mixing_time_mean_std": float(Ms.mean(1).std(ddof=1)) if n_paths > 1 else 0.0,
        "t50": t50, "t90": t90, "t50_mean": nan_mean(t50), "t90_mean": nan_mean(t90),
        "lacey": lacey_summary(time, Ls), "jump": getattr(eng, "jump", "stitch"), **jump_summary(results),
        **path_bed_statistics(db, ps), "cost": cost_summary(eng, rd, results, horizon, t_path), "warnings": warnings}
    if eng.jump != "stitch":
        summary["matchings"] = {"store": str(eng.matchings_path), "loaded": eng.matchings_loaded, "stored": stored,
                                "used": len({(j[1], j[2]) for p in ps for j in p.jumps if j[0] > 0}),
                                "seconds": eng.stitch_seconds}
    else:
        summary["stitch_flow"] = eng.jump_stitcher.flow
    if gas:
        summary["gas_tracer"] = _gas_paths(eng, ps, od, time, horizon, "fct" if gas is True else gas)
    write_json(od / "summary.json", summary)
    _plot_mixing(od / "mixing.png", time, Ms, mean, std)
    seqs = [(s, L, int(db.b0[s])) for s, L in ps[0].sequences]
    _plot_recurrence(od / "recurrence_path.png", eng.st["R"], db.time, [{"jumps": ps[0].jumps, "sequences": seqs}])
    for w in warnings:
        log(f"fbed: rcfd: warning: {w}")
    return summary


def _plot_mixing(path, time, Ms, mean, std, full=None):
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for M in Ms:
        ax.plot(time, M, color="0.7", lw=0.6)
    ax.plot(time, mean, "b-", lw=2, label=f"rCFD mean of {len(Ms)} paths")
    ax.fill_between(time, mean - 2 * std, mean + 2 * std, color="b", alpha=0.2, label="±2σ")
    if full:
        for i, (tf, Mf) in enumerate(full):
            ax.plot(tf, Mf, "k--", lw=1.2, label="full CFD-DEM" if i == 0 else None)
    ax.set_xlabel("time from the tag [s]")
    ax.set_ylabel("mixing index M")
    ax.set_ylim(-0.02, 1.02)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)

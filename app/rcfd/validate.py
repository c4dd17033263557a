"""`fbed rcfd validate PRESET --t0 --t1 --t2`: rCFD against fbed's own full runs (the design note's protocol).

1. Run A: the preset to t1, recording the database from t0 (probes.rcfd_from = t0), grains tagged at t0.
2. Replay: the database's frames in recorded order move the t0 tag; the real grains' tracer over the same
   interval is the reference. Same flow, same frames: only the transport operator differs, so this tests
   rCFD's transport (the well-mixed-cell shift), nothing else.
3. Continuations: from A's checkpoint at t1, ``continuations`` full runs to t2, each with the grain positions
   perturbed by 1e-6 d (seeded normal noise), each recording its own frames and its real tracer (tagged at t1).
   The bed is chaotic: their spread is the floor below which no comparison can go.
4. rCFD: ``paths`` Markov paths over t2 - t1 from the database's last state, the same tag.
5. Compared: the mixing curve (mean index over the horizon, t50, t90) -- the real test of rCFD's extrapolation;
   the bed statistics (mean and std of the bed height, its dominant frequency, the radial void profile) -- these
   only test that the database is representative, since rCFD replays recorded frames.
Finished stages are reused when the command is run again (a run cut off by a time limit goes on).
Exit 0 when every check passes, 1 when one fails (the report says which), 2 on bad input.
"""
from __future__ import annotations

import json
import pathlib
import shutil

import h5py
import numpy as np

from . import commands, paths as pathmod, recurrence as rec
from .database import load
from .transport import mixing_index_real

PERTURBATION = 1e-6  # of the grain diameter


def _finished(d: pathlib.Path, t_end: float) -> bool:
    s = d / "summary.json"
    if not s.exists():
        return False
    js = json.loads(s.read_text())
    return js.get("status") == "finished" and abs(js.get("time", -1) - t_end) < 1e-9


def perturb_checkpoint(src: pathlib.Path, dst: pathlib.Path, seed: int, amplitude: float) -> None:
    """Copy a checkpoint with every grain position moved by ``amplitude`` [m] x a seeded standard normal."""
    from ..io import store

    grains, gas, meta = store.read_checkpoint(src)
    rng = np.random.default_rng(seed)
    x = grains["position"]
    grains["position"] = (x + amplitude * rng.standard_normal(x.shape)).astype(x.dtype)
    store.write_checkpoint(dst, grains, gas, float(meta["time"]), int(meta["step"]), str(meta["config"]))


def full_curves(d: pathlib.Path, t1: float) -> dict:
    db = load(d)
    M = np.array([mixing_index_real(db.tagged[b], db.solid[b]) for b in range(db.n_states)])
    t = db.time - t1
    rb, prof = commands.radial_profiles(db)
    sp = rec.spectrum(db.bed_height, db.frame_interval)
    wall = commands.full_cost_per_second(d, float(db.time[0]), float(db.time[-1]))
    return {"t": t, "M": M, "bed_mean": float(db.bed_height.mean()), "bed_std": float(db.bed_height.std()),
            "bed_freq": sp["peak_frequency"], "df": sp["df"], "radial": prof.mean(0), "wall_per_s": wall,
            "heights": db.bed_height}


def _within(value, ref, tol) -> bool:
    return bool(np.isfinite(value) and np.isfinite(ref) and abs(value - ref) <= tol)


def validate(preset: str, t0: float, t1: float, t2: float, out: str | None, n_paths: int, seed: int,
             n_cont: int, overrides: list, arch: str, log=print, lag: int = 1) -> int:
    from ..run import EXIT_OK, run

    od = pathlib.Path(out) if out else pathlib.Path("runs") / f"rcfd-validate-{pathlib.Path(preset).stem}"
    od.mkdir(parents=True, exist_ok=True)
    A = od / "A"
    if not _finished(A, t1):
        log(f"fbed: rcfd validate: database run A to t1 = {t1:g} s, frames from t0 = {t0:g} s")
        rc = run(preset, list(overrides) + [f"run.duration={t1!r}", f"probes.rcfd_from={t0!r}"], out=str(A),
                 arch=arch, overwrite=True)
        if rc != EXIT_OK:
            log(f"fbed: rcfd validate: run A ended with exit {rc}; see {A}")
            return rc
    d = json.loads((A / "summary.json").read_text())
    diameter = float(d.get("grain_diameter", 0.0)) or _diameter(A)
    conts = []
    for k in range(n_cont):
        C = od / f"C{k + 1}"
        if not _finished(C, t2):
            log(f"fbed: rcfd validate: continuation C{k + 1} to t2 = {t2:g} s, positions perturbed by "
                f"{PERTURBATION:g} d")
            if C.exists():
                shutil.rmtree(C)
            C.mkdir(parents=True)
            shutil.copy(A / "config.toml", C / "config.toml")
            perturb_checkpoint(A / "checkpoint.h5", C / "checkpoint.h5", 1000 + k, PERTURBATION * diameter)
            rc = run(None, list(overrides) + [f"run.duration={t2!r}", f"probes.rcfd_from={t1!r}"], resume=str(C),
                     arch=arch)
            if rc != EXIT_OK:
                log(f"fbed: rcfd validate: continuation C{k + 1} ended with exit {rc}; see {C}")
                return rc
        conts.append(full_curves(C, t1))
    log("fbed: rcfd validate: analysis, replay and rCFD paths")
    ana = commands.analyze(str(A), str(od / "analysis"))
    db = load(A, lag)
    eng = commands.Engine(db)
    # -- replay: the recorded order from t0, the t0 tag, against the real grains' tracer
    rp = pathmod.replay(db.n_frames, eng.successor)
    c0 = commands.initial_concentration(db, int(db.b0[rp.frames[0]]), None)
    rres = eng.transport(rp, c0, int(db.b0[rp.frames[0]]))
    states = np.concatenate([[db.b0[rp.frames[0]]], db.b1[rp.frames]])
    M_real = np.array([mixing_index_real(db.tagged[b], db.solid[b]) for b in states])
    t_rep = db.time[states] - db.time[states[0]]
    rep_err = float(np.max(np.abs(rres["M"] - M_real)))
    rep_t90 = (commands.crossing_time(t_rep, rres["M"], 0.9), commands.crossing_time(t_rep, M_real, 0.9))
    # -- rCFD ensemble over the continuations' horizon
    horizon = t2 - t1
    summ = commands.run_paths(str(A), horizon, n_paths, seed, None, out=str(od / "rcfd_paths"), engine=eng, log=log)
    Ms = np.loadtxt(od / "rcfd_paths" / "mixing.csv", delimiter=",", skiprows=1)
    t_r, M_paths = Ms[:, 0], Ms[:, 1:1 + n_paths].T
    n = int(np.sum(t_r <= min(c["t"][-1] for c in conts) + 1e-9))  # the full curves on rCFD's time grid
    Mf = np.stack([np.interp(t_r[:n], c["t"], c["M"]) for c in conts])
    tf = t_r[:n]
    # the full runs' time mean from every boundary within the horizon (rCFD's own grid may be coarser)
    full_mean_idx = np.array([c["M"][c["t"] <= t_r[n - 1] + 1e-9].mean() for c in conts])
    rc_mean_idx = M_paths[:, :n].mean(1)
    sig_full = float(full_mean_idx.std(ddof=1)) if n_cont > 1 else 0.0
    t50f = [commands.crossing_time(tf, m, 0.5) for m in Mf]
    t90f = [commands.crossing_time(tf, m, 0.9) for m in Mf]
    t50r = [commands.crossing_time(t_r[:n], m[:n], 0.5) for m in M_paths]
    t90r = [commands.crossing_time(t_r[:n], m[:n], 0.9) for m in M_paths]

    def rel_check(r, f):
        r_m, f_m = np.nanmean(r) if np.isfinite(r).any() else np.nan, np.nanmean(f) if np.isfinite(f).any() else np.nan
        s = np.nanstd(f, ddof=1) if np.isfinite(f).sum() > 1 else 0.0
        tol = max(2 * s, 0.15 * f_m) if np.isfinite(f_m) else np.nan
        return {"rcfd": float(r_m), "full": float(f_m), "full_std": float(s), "tolerance": float(tol),
                "pass": _within(r_m, f_m, tol)}

    tau = float(np.mean([_integral_time(c["heights"], db.frame_interval / lag) for c in conts]))
    n_eff = max(1.0, horizon / (2 * tau))  # independent samples of the bed height in the horizon
    se = float(np.mean([c["bed_std"] for c in conts]) / np.sqrt(n_eff))
    full_bed_mean = float(np.mean([c["bed_mean"] for c in conts]))
    full_bed_std = float(np.mean([c["bed_std"] for c in conts]))
    full_freq = float(np.mean([c["bed_freq"] for c in conts]))
    full_rad = np.mean([c["radial"] for c in conts], 0)
    rc_rad = np.asarray(summ["radial_eps_paths"])
    m = min(full_rad.size, rc_rad.size)
    c_full = float(np.nanmean([c["wall_per_s"] for c in conts]))
    c_r = summ["cost"]["rcfd_wall_per_simulated_second_per_path"]
    checks = {
        "replay_mixing_index": {"tests": "rCFD transport (same frames, same order: only the operator differs)",
                                "max_abs_difference": rep_err, "tolerance": 0.03, "pass": rep_err <= 0.03,
                                "rcfd_final": float(rres["M"][-1]), "full": float(M_real[-1]),
                                "t90_rcfd": rep_t90[0], "t90_real": rep_t90[1]},
        "mean_mixing_index": {"tests": "rCFD extrapolation (paths and transport against full runs)",
                              "rcfd": float(rc_mean_idx.mean()), "rcfd_std": float(rc_mean_idx.std(ddof=1))
                              if n_paths > 1 else 0.0, "full": float(full_mean_idx.mean()), "full_std": sig_full,
                              "tolerance": max(2 * sig_full, 0.05),
                              "pass": _within(rc_mean_idx.mean(), full_mean_idx.mean(), max(2 * sig_full, 0.05))},
        "t50": {"tests": "rCFD extrapolation", **rel_check(t50r, t50f)},
        "t90": {"tests": "rCFD extrapolation", **rel_check(t90r, t90f)},
        "bed_height_mean": {"tests": "representativeness of the database only", "rcfd": summ["bed_height_mean"],
                            "integral_time": tau, "n_eff": n_eff,
                            "full": full_bed_mean, "tolerance": max(2 * se, 0.02 * full_bed_mean),
                            "pass": _within(summ["bed_height_mean"], full_bed_mean, max(2 * se, 0.02 * full_bed_mean))},
        "bed_height_std": {"tests": "representativeness of the database only", "rcfd": summ["bed_height_std"],
                           "full": full_bed_std, "tolerance": 0.15 * full_bed_std,
                           "pass": _within(summ["bed_height_std"], full_bed_std, 0.15 * full_bed_std)},
        "bed_height_frequency": {"tests": "representativeness of the database only",
                                 "rcfd": summ["bed_height_frequency"], "full": full_freq, "tolerance": conts[0]["df"],
                                 "pass": _within(summ["bed_height_frequency"], full_freq, conts[0]["df"])},
        "radial_void_profile_rms": {"tests": "representativeness of the database only",
                                    "rms_difference": float(np.sqrt(np.mean((rc_rad[:m] - full_rad[:m]) ** 2))),
                                    "tolerance": 0.02},
        "marginal_speedup": {"tests": "cost", "value": c_full / c_r if c_r > 0 else float("inf"),
                             "full_wall_per_simulated_second": c_full, "rcfd_wall_per_simulated_second": c_r,
                             "tolerance": ">= 1e4"},
        "conservation": {"tests": "rCFD transport", "drift": summ["tracer_drift_max"], "tolerance": 1e-10,
                         "pass": summ["tracer_drift_max"] <= 1e-10, "c_min": summ["concentration_min"],
                         "c_max": summ["concentration_max"], "stitched_share_max": summ["stitched_share_max"]},
    }
    checks["radial_void_profile_rms"]["pass"] = checks["radial_void_profile_rms"]["rms_difference"] <= 0.02
    checks["marginal_speedup"]["pass"] = checks["marginal_speedup"]["value"] >= 1e4
    total = c_full * horizon / (c_full * (t1 - t0) + summ["cost"]["prep_seconds"] + n_paths * c_r * horizon)
    result = {"preset": preset, "lag": lag, "t0": t0, "t1": t1, "t2": t2, "paths": n_paths, "seed": seed,
              "continuations": n_cont, "perturbation_of_d": PERTURBATION, "analysis": ana, "checks": checks,
              "total_speedup_with_database": total, "replay_curve": {"t": t_rep.tolist(), "rcfd": rres["M"].tolist(),
                                                                      "real": M_real.tolist()}}
    commands._json(od / "validation.json", result)
    _plot(od, t_rep, rres["M"], M_real, t_r, M_paths, tf, Mf)
    _report(od / "REPORT.md", result)
    ok = all(c.get("pass", True) for c in checks.values())
    for name, c in checks.items():
        log(f"  {name}: {'pass' if c['pass'] else 'FAIL'} ({c['tests']})")
    log(f"fbed: rcfd validate: report in {od / 'REPORT.md'}")
    return 0 if ok else 1


def _diameter(A: pathlib.Path) -> float:
    with h5py.File(A / "checkpoint.h5", "r") as f:
        return float(2.0 * np.mean(f["grains/radius"][...]))


def _integral_time(x: np.ndarray, dt: float) -> float:
    """Integral time scale [s] of a series: the autocorrelation summed up to its first zero."""
    y = x - x.mean()
    if not np.any(y):
        return dt
    ac = np.correlate(y, y, "full")[y.size - 1:] / (y.var() * y.size)
    zero = np.nonzero(ac <= 0)[0]
    end = int(zero[0]) if zero.size else ac.size
    return float(ac[:end].sum() * dt)


def _plot(od, t_rep, M_rep, M_real, t_r, M_paths, tf, Mf):
    plt = commands._plt()
    fig, axs = plt.subplots(1, 2, figsize=(12, 4.5))
    axs[0].plot(t_rep, M_real, "k-", label="real grains")
    axs[0].plot(t_rep, M_rep, "b--", label="replay (shift operators)")
    axs[0].set_title("replay of the database in recorded order")
    axs[0].set_xlabel("time from t0 [s]")
    axs[0].set_ylabel("mixing index")
    axs[0].legend()
    mean, std = M_paths.mean(0), M_paths.std(0, ddof=1) if len(M_paths) > 1 else 0 * M_paths[0]
    for M in M_paths:
        axs[1].plot(t_r, M, color="0.75", lw=0.5)
    axs[1].plot(t_r, mean, "b-", lw=2, label=f"rCFD, {len(M_paths)} paths")
    axs[1].fill_between(t_r, mean - 2 * std, mean + 2 * std, color="b", alpha=0.2, label="±2σ")
    for i, M in enumerate(Mf):
        axs[1].plot(tf, M, "k--", lw=1.2, label="full CFD-DEM (perturbed continuations)" if i == 0 else None)
    axs[1].set_title("extrapolation from t1")
    axs[1].set_xlabel("time from t1 [s]")
    axs[1].legend()
    fig.tight_layout()
    fig.savefig(od / "mixing_validation.png", dpi=110)
    plt.close(fig)


def _report(path: pathlib.Path, res: dict) -> None:
    lines = [f"# rCFD validation: {res['preset']}", "",
             f"Database {res['t0']:g}-{res['t1']:g} s; {res['continuations']} full continuations to {res['t2']:g} s "
             f"(positions perturbed by {res['perturbation_of_d']:g} d); {res['paths']} rCFD paths (seed "
             f"{res['seed']}).", "",
             "| check | what it tests | rCFD | full / reference | tolerance | result |", "|---|---|---|---|---|---|"]
    for name, c in res["checks"].items():
        r = c.get("rcfd", c.get("max_abs_difference", c.get("rms_difference", c.get("value", c.get("drift")))))
        f = c.get("full", c.get("full_wall_per_simulated_second", ""))
        fmt = (lambda v: f"{v:.4g}" if isinstance(v, (float, int)) else str(v))
        lines.append(f"| {name} | {c['tests']} | {fmt(r)} | {fmt(f)} | {fmt(c['tolerance'])} | "
                     f"{'pass' if c['pass'] else '**fail**'} |")
    lines += ["", "The mixing curve is the real test of rCFD. The bed statistics only test that the database is "
              "representative: rCFD replays recorded frames, so matching them is nearly automatic.", ""]
    path.write_text("\n".join(lines))

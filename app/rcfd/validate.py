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

import dataclasses
import json
import pathlib
import shutil

import h5py
import numpy as np

from ..analysis.mri_stats import block_stats, halves, integral_time, z_between
from ..outputs import out_folder
from . import commands, paths as pathmod, recurrence as rec
from .database import load
from .transport import lacey_index, lacey_random_std, mixing_index_real

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


def grain_volume(db) -> float:
    """The mean grain volume [m^3] (Lacey's grains per cell = solid volume / it: exact for one size)."""
    if db.grain_volume is not None:
        return float(np.mean(db.grain_volume))
    return float(db.solid[0].astype(np.float64).sum()) / max(1, int(db.attrs.get("grains", 0)))


def real_lacey(db, states) -> np.ndarray:
    """Lacey's index of the real grains' tag (recorded tagged and solid volume per cell) at ``states``."""
    b = db.solid[states].astype(np.float64)
    return lacey_index(db.tagged[states].astype(np.float64), b, b / grain_volume(db))


def full_curves(d: pathlib.Path, t1: float) -> dict:
    db = load(d)
    M = np.array([mixing_index_real(db.tagged[b], db.solid[b]) for b in range(db.n_states)])
    L = real_lacey(db, np.arange(db.n_states))
    t = db.time - t1
    rb, prof = commands.radial_profiles(db)
    sp = rec.spectrum(db.bed_height, db.frame_interval)
    wall = commands.full_cost_per_second(d, float(db.time[0]), float(db.time[-1]))
    return {"t": t, "M": M, "L": L, "bed_mean": float(db.bed_height.mean()), "bed_std": float(db.bed_height.std()),
            "bed_freq": sp["peak_frequency"], "df": sp["df"], "radial": prof.mean(0), "wall_per_s": wall,
            "heights": db.bed_height}


def _within(value, ref, tol) -> bool:
    return bool(np.isfinite(value) and np.isfinite(ref) and abs(value - ref) <= tol)


def _run_stage(d: pathlib.Path, t_end: float, what: str, log, start) -> int:
    """Run a stage unless it finished before (``start()`` runs it); its exit code."""
    from ..run import EXIT_OK

    if _finished(d, t_end):
        return EXIT_OK
    log(f"fbed: rcfd validate: {what}")
    rc = start()
    if rc != EXIT_OK:
        log(f"fbed: rcfd validate: {d.name} ended with exit {rc}; see {d}")
    return rc


def full_runs(od: pathlib.Path, preset: str, overrides: list, t0: float, t1: float, t2: float, n_cont: int,
              arch: str, log) -> tuple[int, list]:
    """Run A (the database) and the perturbed continuations; (exit code, the continuations' curves)."""
    from ..run import run

    A = od / "A"
    rc = _run_stage(A, t1, f"database run A to t1 = {t1:g} s, frames from t0 = {t0:g} s", log, lambda: run(
        preset, list(overrides) + [f"run.duration={t1!r}", f"probes.rcfd_from={t0!r}"], out=str(A), arch=arch,
        overwrite=True))
    if rc:
        return rc, []
    d = json.loads((A / "summary.json").read_text())
    diameter = float(d.get("grain_diameter", 0.0)) or _diameter(A)
    conts = []
    for k in range(n_cont):
        C = od / f"C{k + 1}"

        def start(C=C, k=k):
            if C.exists():
                shutil.rmtree(C)
            C.mkdir(parents=True)
            shutil.copy(A / "config.toml", C / "config.toml")
            perturb_checkpoint(A / "checkpoint.h5", C / "checkpoint.h5", 1000 + k, PERTURBATION * diameter)
            return run(None, list(overrides) + [f"run.duration={t2!r}", f"probes.rcfd_from={t1!r}"], resume=str(C),
                       arch=arch)

        rc = _run_stage(C, t2, f"continuation C{k + 1} to t2 = {t2:g} s, positions perturbed by {PERTURBATION:g} d",
                        log, start)
        if rc:
            return rc, []
        conts.append(full_curves(C, t1))
    return 0, conts


def replay_checks(db, eng) -> tuple[dict, dict]:
    """The replays of the database in recorded order from t0 against the real grains' tracer: (checks, curves).
    - grains: the grain tracer with the real t0 tag per grain. It uses no operator along the recorded order, so it
      must equal the real tracer to the float32 of the stored per-cell volumes: a check of the recording's books.
    - jumps: the same with a jump from a state to itself every mean sequence length (the stitch averages the tag
      over each jump cell there, the match re-pairs the grains within each jump cell at random: the grains'
      places are known only to a jump cell): the transport error the paths make, without the error of their
      frame order. The design note's 0.03 applies here.
    - cells: the cell shifts (SolidsTracer) frame by frame, for comparison (no pass/fail: its error is the
      well-mixed cell's, measured in validation/rcfd/README.md)."""
    rp = pathmod.replay(db.n_frames, eng.successor)
    s0 = int(db.b0[rp.frames[0]])
    states = np.concatenate([[s0], db.b1[rp.frames]])
    real = np.array([mixing_index_real(db.tagged[b], db.solid[b]) for b in states])
    real_L = real_lacey(db, states)
    t = db.time[states] - db.time[states[0]]
    curves, checks = {"t": t, "real": real, "real_lacey": real_L}, {}
    cells = commands.Engine(db, eng.st, eng.params, solids="cells") if eng.solids == "grains" else eng
    cases = [("cells", cells, rp, None)]
    if eng.solids == "grains":
        tau0 = db.tagged_grains.astype(np.float64) if s0 == 0 else None
        cases += [("grains", eng, rp, tau0), ("jumps", eng, pathmod.with_resets(rp, eng.params.l_mean, db.b0), tau0)]
    for name, e, path, tau0 in cases:
        r = e.transport(path, commands.initial_concentration(db, s0, None), s0, tau0=tau0)
        err = float(np.max(np.abs(r["M"] - real)))
        curves[name], curves[f"{name}_lacey"] = r["M"], r["lacey"]
        t90 = (commands.crossing_time(t, r["M"], 0.9), commands.crossing_time(t, real, 0.9))
        checks[f"replay_{name}"] = {"max_abs_difference": err, "rcfd_final": float(r["M"][-1]),
                                    "full": float(real[-1]), "t90_rcfd": t90[0], "t90_real": t90[1],
                                    "lacey_max_abs_difference": float(np.nanmax(np.abs(r["lacey"] - real_L))),
                                    "lacey_rcfd_final": float(r["lacey"][-1]), "lacey_full": float(real_L[-1])}
    checks["replay_cells"].update(tests="the cell shifts every frame (for comparison; not a pass/fail check)",
                                  tolerance="reported")
    if "replay_grains" in checks:
        checks["replay_grains"].update(tests="the recording's books (grain tracer, recorded order: no operator)",
                                       tolerance=1e-6, every_frames=0)
        checks["replay_grains"]["pass"] = checks["replay_grains"]["max_abs_difference"] <= 1e-6
        checks["replay_jumps"].update(tests="rCFD transport (recorded order, a jump to the same state every mean "
                                      "sequence length)", tolerance=0.03, every_frames=eng.params.l_mean)
        checks["replay_jumps"]["pass"] = checks["replay_jumps"]["max_abs_difference"] <= 0.03
    return checks, curves


def mixing_checks(conts: list, t_r: np.ndarray, M_paths: np.ndarray, key: str = "M",
                  name: str = "mixing_index") -> tuple[dict, tuple]:
    """The rCFD ensemble's mixing curve against the continuations' (mean index over the horizon, t50, t90), on
    the cell index (key 'M') or Lacey's (key 'L', checks named *_lacey)."""
    n = int(np.sum(t_r <= min(c["t"][-1] for c in conts) + 1e-9))  # the full curves on rCFD's time grid
    tf = t_r[:n]
    Mf = np.stack([np.interp(tf, c["t"], c[key]) for c in conts])
    # the full runs' time mean from every boundary within the horizon (rCFD's own grid may be coarser)
    full_mean = np.array([c[key][c["t"] <= t_r[n - 1] + 1e-9].mean() for c in conts])
    rc_mean = M_paths[:, :n].mean(1)
    sig = float(full_mean.std(ddof=1)) if len(conts) > 1 else 0.0
    tol = max(2 * sig, 0.05)

    def rel_check(level):
        r = [commands.crossing_time(tf, m[:n], level) for m in M_paths]
        f = [commands.crossing_time(tf, m, level) for m in Mf]
        r_m = np.nanmean(r) if np.isfinite(r).any() else np.nan
        f_m = np.nanmean(f) if np.isfinite(f).any() else np.nan
        s = np.nanstd(f, ddof=1) if np.isfinite(f).sum() > 1 else 0.0
        t = max(2 * s, 0.15 * f_m) if np.isfinite(f_m) else np.nan
        return {"tests": "rCFD extrapolation", "rcfd": float(r_m), "full": float(f_m), "full_std": float(s),
                "rcfd_reached": int(np.isfinite(r).sum()), "tolerance": float(t), "pass": _within(r_m, f_m, t)}

    sfx = "" if key == "M" else "_lacey"
    checks = {f"mean_{name}": {"tests": "rCFD extrapolation (paths and transport against full runs)",
                                    "rcfd": float(rc_mean.mean()),
                                    "rcfd_std": float(rc_mean.std(ddof=1)) if len(rc_mean) > 1 else 0.0,
                                    "full": float(full_mean.mean()), "full_std": sig, "tolerance": tol,
                                    "pass": _within(rc_mean.mean(), full_mean.mean(), tol)},
              f"t50{sfx}": rel_check(0.5), f"t90{sfx}": rel_check(0.9)}
    return checks, (tf, Mf)


def bed_checks(conts: list, summ: dict, horizon: float, dt: float) -> dict:
    """Bed height mean, std, frequency and the radial void profile along the paths against the continuations:
    these test only that the database is representative."""
    tau = float(np.mean([integral_time(c["heights"], dt) for c in conts]))
    n_eff = max(1.0, horizon / (2 * tau))  # independent samples of the bed height in the horizon
    std = float(np.mean([c["bed_std"] for c in conts]))
    mean = float(np.mean([c["bed_mean"] for c in conts]))
    freq = float(np.mean([c["bed_freq"] for c in conts]))
    tol_mean = max(2 * std / np.sqrt(n_eff), 0.02 * mean)
    rad_f = np.mean([c["radial"] for c in conts], 0)
    rad_r = np.asarray(summ["radial_eps_paths"])
    m = min(rad_f.size, rad_r.size)
    rms = float(np.sqrt(np.mean((rad_r[:m] - rad_f[:m]) ** 2)))
    rep = "representativeness of the database only"
    return {"bed_height_mean": {"tests": rep, "rcfd": summ["bed_height_mean"], "integral_time": tau, "n_eff": n_eff,
                                "full": mean, "tolerance": tol_mean,
                                "pass": _within(summ["bed_height_mean"], mean, tol_mean)},
            "bed_height_std": {"tests": rep, "rcfd": summ["bed_height_std"], "full": std, "tolerance": 0.15 * std,
                               "pass": _within(summ["bed_height_std"], std, 0.15 * std)},
            "bed_height_frequency": {"tests": rep, "rcfd": summ["bed_height_frequency"], "full": freq,
                                     "tolerance": conts[0]["df"],
                                     "pass": _within(summ["bed_height_frequency"], freq, conts[0]["df"])},
            "radial_void_profile_rms": {"tests": rep, "rms_difference": rms, "tolerance": 0.02, "pass": rms <= 0.02}}


def steadiness(database: np.ndarray, conts: list, block: int, z_max: float = 3.0) -> dict:
    """Is the bed steady from t0 to t2? The bed height's mean and spread over the database's halves and over the
    continuations (their errors pooled as independent runs); ``drift`` names those of the continuations that lie more
    than ``z_max`` standard errors from the database's. Reported beside the bed checks, whose failure it can explain:
    a database recorded before the bed settled does not represent what follows it (validation/rcfd/README.md, 000).
    A diagnostic, not a check: the errors come from the blocks, themselves uncertain, and a steady AR(1) bed of 3,000
    + 3 x 2,000 frames was flagged in 3-4 of 20-40 seeds (tests/test_rcfd.py); a spread falling from 8 to 5 mm was
    flagged in every one. rcfd_bubbling's 5 s database: z = 1.7 (mean), 2.9 (std), not flagged."""
    hv = halves(database, block)
    rows = {"database, first half": hv["first"], "database, second half": hv["second"],
            "database": block_stats(database, block)}
    each = [block_stats(c, block) for c in conts]
    n = len(each)
    rows["continuations"] = {k: float(np.mean([e[k] for e in each])) for k in ("mean", "std")}
    rows["continuations"].update({f"{k}_se": float(np.sqrt(np.sum([e[f"{k}_se"] ** 2 for e in each])) / n)
                                  for k in ("mean", "std")})
    d, c = rows["database"], rows["continuations"]
    z = z_between(c, d)
    return {"tests": "is the bed steady from t0 to t2 (bed height: the database against the continuations)",
            "rows": rows, "z": z, "block_samples": block,
            "drift": [k for k, v in z.items() if v > z_max]}


def sensitivity_checks(A: pathlib.Path, od: pathlib.Path, conts: list, horizon: float, n_paths: int, seed: int,
                       lag: int, eng, jump_grid: str, jump: str, log=print) -> dict:
    """The design note's sensitivity check: the extrapolation again with the frame interval doubled (each frame
    spans twice the recorded frames; the mean sequence kept in seconds, so half as many frames) and with the mean
    sequence halved; each must stay within the extrapolation tolerance of the full runs (the mean index, t50 and
    t90, on the cell index and on Lacey's). The other settings are the main run's; each variant's paths go to
    ``od / rcfd_paths_<variant>``."""
    variants = {"frames_doubled": (2 * lag, eng.params.l_mean // 2), "sequences_halved": (lag, eng.params.l_mean // 2)}
    out = {}
    for name, (v_lag, v_mean) in variants.items():
        db = load(A, v_lag)
        e = commands.Engine(db, jump_grid=jump_grid, jump=jump)
        e = commands.Engine(db, e.st, dataclasses.replace(e.params, l_mean=max(e.params.l_min + 1, v_mean)),
                            jump_grid=jump_grid, jump=jump)
        log(f"fbed: rcfd validate: sensitivity, {name} (lag {v_lag}, mean sequence {e.params.l_mean} frames)")
        pd = od / f"rcfd_paths_{name}"
        commands.run_paths(str(A), horizon, n_paths, seed, None, out=str(pd), engine=e, log=log)
        for key, fname, label in (("M", "mixing.csv", "mixing_index"), ("L", "lacey.csv", "lacey_index")):
            data = np.loadtxt(pd / fname, delimiter=",", skiprows=1)
            t_r, paths = data[:, 0], data[:, 1:1 + n_paths].T
            checks, _ = mixing_checks(conts, t_r, paths, key, label)
            for k, c in checks.items():
                c["tests"] = f"sensitivity: {name} (lag {v_lag}, mean sequence {e.params.l_mean} frames)"
                out[f"sensitivity_{name}_{k}"] = c
    return out


def cost_checks(conts: list, summ: dict) -> dict:
    c_full = float(np.nanmean([c["wall_per_s"] for c in conts]))
    c_r = summ["cost"]["rcfd_wall_per_simulated_second_per_path"]
    marginal = c_full / c_r if c_r > 0 else float("inf")
    return {"marginal_speedup": {"tests": "cost", "value": marginal, "full_wall_per_simulated_second": c_full,
                                 "rcfd_wall_per_simulated_second": c_r, "tolerance": ">= 1e4", "pass": marginal >= 1e4},
            "conservation": {"tests": "rCFD transport", "drift": summ["tracer_drift_max"], "tolerance": 1e-10,
                             "pass": summ["tracer_drift_max"] <= 1e-10, "c_min": summ["concentration_min"],
                             "c_max": summ["concentration_max"], "stitched_share_max": summ["stitched_share_max"]}}


def validate(preset: str, t0: float, t1: float, t2: float, out: str | None, n_paths: int, seed: int,
             n_cont: int, overrides: list, arch: str, log=print, lag: int = 1, l_mean: int | None = None,
             jump_grid: str = "auto", jump: str = "auto", sensitivity: bool = False) -> int:
    """The protocol above; ``l_mean`` [frames] overrides the paths' mean sequence length (default N/10);
    ``jump_grid`` 'cells' locates the grain tracer's jumps on the cells instead of half cells; ``jump`` 'stitch'
    stitches cell volumes at the jumps instead of matching grains (Engine); ``sensitivity``: the design note's
    last check too (:func:`sensitivity_checks`)."""
    od = out_folder(out, pathlib.Path("runs") / f"rcfd-validate-{pathlib.Path(preset).stem}")
    rc, conts = full_runs(od, preset, overrides, t0, t1, t2, n_cont, arch, log)
    if rc:
        return rc
    A = od / "A"
    log("fbed: rcfd validate: analysis, replay and rCFD paths")
    ana = commands.analyze(str(A), str(od / "analysis"))
    db = load(A, lag)
    eng = commands.Engine(db, jump_grid=jump_grid, jump=jump)
    if l_mean:
        eng = commands.Engine(db, eng.st, dataclasses.replace(eng.params, l_mean=max(int(l_mean), eng.params.l_min + 1)),
                              jump_grid=jump_grid, jump=jump)
    checks, rep = replay_checks(db, eng)
    horizon = t2 - t1
    summ = commands.run_paths(str(A), horizon, n_paths, seed, None, out=str(od / "rcfd_paths"), engine=eng, log=log)
    Ms = np.loadtxt(od / "rcfd_paths" / "mixing.csv", delimiter=",", skiprows=1)
    t_r, M_paths = Ms[:, 0], Ms[:, 1:1 + n_paths].T
    mix, (tf, Mf) = mixing_checks(conts, t_r, M_paths)
    checks.update(mix)
    L_paths = np.loadtxt(od / "rcfd_paths" / "lacey.csv", delimiter=",", skiprows=1)[:, 1:1 + n_paths].T
    mix_L, (_, Lf) = mixing_checks(conts, t_r, L_paths, "L", "lacey_index")
    checks.update(mix_L)
    checks.update(bed_checks(conts, summ, horizon, db.frame_interval / lag))
    tau = checks["bed_height_mean"]["integral_time"]
    block = max(2, int(round(2 * tau * lag / db.frame_interval)))  # recorded frames in two integral times
    steady = steadiness(db.bed_height, [c["heights"] for c in conts], block)
    checks.update(cost_checks(conts, summ))
    if sensitivity:
        checks.update(sensitivity_checks(A, od, conts, horizon, n_paths, seed, lag, eng, jump_grid, jump, log))
    c_full = checks["marginal_speedup"]["full_wall_per_simulated_second"]
    c_r = checks["marginal_speedup"]["rcfd_wall_per_simulated_second"]
    total = c_full * horizon / (c_full * (t1 - t0) + summ["cost"]["prep_seconds"] + n_paths * c_r * horizon)
    result = {"preset": preset, "lag": lag, "solids": eng.solids, "jump_cells": "half cells" if eng.half else "cells", "l_min": eng.params.l_min, "l_mean": eng.params.l_mean, "t0": t0, "t1": t1, "t2": t2, "paths": n_paths,
              "seed": seed, "continuations": n_cont, "perturbation_of_d": PERTURBATION, "analysis": ana,
              "checks": checks, "steadiness": steady, "total_speedup_with_database": total,
              "total_speedup_without_database": summ["cost"]["total_speedup_without_database"],
              "replay_curve": {k: np.asarray(v).tolist() for k, v in rep.items()},
              "full_curves": {"t": tf.tolist(), "M": Mf.tolist(), "L": Lf.tolist()},
              "rcfd_mean_curve": M_paths.mean(0).tolist(), "rcfd_mean_lacey": L_paths.mean(0).tolist(),
              "jump": eng.jump, "jump_dM_mean": summ.get("jump_dM_mean"),
              "jump_tag_moved_share_mean": summ.get("jump_tag_moved_share_mean"),
              "lacey_random_scatter": lacey_random_std(db.solid[-1].astype(np.float64) / grain_volume(db),
                                                       float(db.tag_now[-1].sum() / db.solid[-1].sum()))}
    commands.write_json(od / "validation.json", result)
    _plot(od, rep, t_r, (M_paths, L_paths), tf, (Mf, Lf))
    _report(od / "REPORT.md", result)
    for name, c in checks.items():
        verdict = "reported" if "pass" not in c else "pass" if c["pass"] else "FAIL"
        log(f"  {name}: {verdict} ({c['tests']})")
    log(f"fbed: rcfd validate: report in {od / 'REPORT.md'}")
    return 0 if all(c.get("pass", True) for c in checks.values()) else 1


def _diameter(A: pathlib.Path) -> float:
    with h5py.File(A / "checkpoint.h5", "r") as f:
        return float(2.0 * np.mean(f["grains/radius"][...]))


def _plot(od, rep, t_r, paths, tf, full):
    """The replay (cell index), and the extrapolation on the cell index and on Lacey's."""
    plt = commands.pyplot()
    fig, axs = plt.subplots(1, 3, figsize=(17, 4.5))
    axs[0].plot(rep["t"], rep["real"], "k-", lw=2, label="real grains")
    style = {"cells": ("r:", "cell shifts every frame"), "grains": ("g--", "grain tracer (no jumps)"),
             "jumps": ("b-", "grain tracer, a jump to the same state every mean sequence")}
    for k, (ls, label) in style.items():
        if k in rep:
            axs[0].plot(rep["t"], rep[k], ls, label=label)
    axs[0].set_title("replay of the database in recorded order (cell index)")
    axs[0].set_xlabel("time from t0 [s]")
    axs[0].set_ylabel("mixing index")
    axs[0].legend(fontsize=8)
    for ax, M_paths, Mf, what in ((axs[1], paths[0], full[0], "cell index"), (axs[2], paths[1], full[1], "Lacey")):
        mean, std = M_paths.mean(0), M_paths.std(0, ddof=1) if len(M_paths) > 1 else 0 * M_paths[0]
        for M in M_paths:
            ax.plot(t_r, M, color="0.75", lw=0.5)
        ax.plot(t_r, mean, "b-", lw=2, label=f"rCFD, {len(M_paths)} paths")
        ax.fill_between(t_r, mean - 2 * std, mean + 2 * std, color="b", alpha=0.2, label="±2σ")
        for i, M in enumerate(Mf):
            ax.plot(tf, M, "k--", lw=1.2, label="full CFD-DEM (perturbed continuations)" if i == 0 else None)
        ax.set_title(f"extrapolation from t1: {what}")
        ax.set_xlabel("time from t1 [s]")
        ax.legend(fontsize=8)
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
        verdict = "reported" if "pass" not in c else "pass" if c["pass"] else "**fail**"
        lines.append(f"| {name} | {c['tests']} | {fmt(r)} | {fmt(f)} | {fmt(c['tolerance'])} | {verdict} |")
    lines += ["", "The mixing curve is the real test of rCFD. The bed statistics only test that the database is "
              "representative: rCFD replays recorded frames, so matching them is nearly automatic.", ""]
    st = res.get("steadiness")
    if st:
        lines += [f"Is the bed steady? The bed height [mm] (standard errors from blocks of {st['block_samples']} "
                  "frames, about two integral times):", "", "| | mean | std |", "|---|---|---|"]
        lines += [f"| {name} | {1e3 * r['mean']:.2f} ({1e3 * r['mean_se']:.2f}) | {1e3 * r['std']:.2f} "
                  f"({1e3 * r['std_se']:.2f}) |" for name, r in st["rows"].items()]
        z = st["z"]
        lines += ["", (f"The continuations' {' and '.join(st['drift'])} lie{'s' * (len(st['drift']) == 1)} more than "
                       "3 standard errors from the database's (z: mean {:.1f}, std {:.1f}): the bed was likely not "
                       "steady from t0 to t2, so the database does not represent what followed it; record it later "
                       "(a steady bed of a few thousand frames is flagged about one time in ten: read the table)."
                       if st["drift"] else "The continuations' mean and spread lie within 3 standard errors of the "
                       "database's (z: mean {:.1f}, std {:.1f}).").format(z["mean"], z["std"]), ""]
    path.write_text("\n".join(lines))

"""`fbed rcfd analyze|run|validate`: the commands' argument checks and printed results (no physics here)."""
from __future__ import annotations

import math
import pathlib
import sys

from ..config import ConfigError
from ..config.derived import RCFD_MIN_FRAMES, rcfd_frames
from ..outputs import refuse_live_folder


def _db_dir(target: str) -> pathlib.Path:
    d = pathlib.Path(target)
    if not (d / "rcfd.h5").exists():
        raise ConfigError("no rcfd.h5 in this folder", str(d), "RUN_DIR",
                          hint="give the output folder of a run that recorded rCFD frames (probes.rcfd_from >= 0)")
    refuse_live_folder(d, "RUN_DIR")
    return d


#: the actions each flag of `fbed rcfd` is read by (its dest -> actions); given to another, it did nothing (app.cli
#: refuses it)
FLAG_ACTIONS = {"horizon": ("run",), "paths": ("run", "validate"), "seed": ("run", "validate"), "tag": ("run",),
                "name": ("run",), "start": ("run",), "gas": ("run",), "gas_scheme": ("run",),
                "jump": ("run", "validate"), "workers": ("run",),
                "lag": ("run", "validate"),
                "t0": ("validate",), "t1": ("validate",), "t2": ("validate",), "continuations": ("validate",),
                "sensitivity": ("validate",), "overrides": ("validate",), "arch": ("validate",)}


def _check_counts(args) -> None:
    """--paths, --seed and --lag, read by run and validate (validate's --paths 0 ran every run, then a traceback)."""
    if args.paths < 1:
        raise ConfigError(f"--paths must be at least 1, got {args.paths}", "", "--paths")
    if args.seed < 0:  # numpy's seeds are non-negative: it said so as an error of the run's rcfd.h5
        raise ConfigError(f"--seed must be 0 or more, got {args.seed}", "", "--seed")
    if args.lag < 1:  # a frame of LAG recorded frames: -3 ran, as if 1
        raise ConfigError(f"--lag must be at least 1 (recorded frames a frame spans), got {args.lag}", "", "--lag")


def main(args) -> int:
    from . import commands

    def log(msg):
        print(msg, file=sys.stderr, flush=True)

    if args.action == "analyze":
        d = _db_dir(args.target)
        try:
            res = commands.analyze(str(d), args.out)
        except ValueError as err:
            raise ConfigError(str(err), str(d / "rcfd.h5"), "probes.rcfd_from") from None
        for k in ("frames", "frame_interval", "period_mid_bed_eps", "period_bed_height", "spectral_bin",
                  "first_recurrence_lag", "database_levelled_off", "taylor_time", "frame_check"):
            v = res[k]
            print(f"{k} = {v:.6g}" if isinstance(v, float) else f"{k} = {v}")
        return 0
    if args.action == "run":
        if args.workers is not None and args.workers < 1:
            raise ConfigError(f"--workers must be at least 1, got {args.workers}", "", "--workers",
                              hint="leave it out for one per core")
        d = _db_dir(args.target)
        if not (args.horizon > 0 and math.isfinite(args.horizon)):
            raise ConfigError(f"--horizon must be a positive time in s, got {args.horizon:g}", "", "--horizon")
        _check_counts(args)
        if args.name is not None and (args.name in ("", ".", "..") or any(c in args.name for c in "/\\")):
            raise ConfigError(f"--name must be one folder name (made under RUN_DIR/rcfd), got {args.name!r}", "",
                              "--name", hint="to write elsewhere give --out FOLDER")  # '../../x' wrote outside the run
        if args.gas_scheme is not None and not args.gas:  # it would have chosen the scheme of no tracer
            raise ConfigError("--gas-scheme chooses the gas tracer's scheme, and --gas is not given", "",
                              "--gas-scheme", hint="add --gas, or drop --gas-scheme")
        if args.tag is not None:
            from .database import parse_tag

            try:
                parse_tag(args.tag)
            except ValueError as err:
                raise ConfigError(str(err), "", "--tag") from None
        try:
            s = commands.run_paths(str(d), args.horizon, args.paths, args.seed, args.tag, args.name, args.out,
                                   args.start, log=log, gas=args.gas and (args.gas_scheme or "fct"), lag=args.lag,
                                   jump=args.jump, workers=args.workers)
        except ValueError as err:
            key = next((k for k in ("--lag", "--horizon", "--tag") if k in str(err)),
                       "--jump" if str(err).startswith("jump") else "RUN_DIR")
            msg = str(err).removeprefix(f"{d / 'rcfd.h5'}: ")  # the error names the file already
            raise ConfigError(msg, str(d / "rcfd.h5"), key) from None
        c = s["cost"]
        print(f"mixing index at {args.horizon:g} s: {s['mixing_final_mean']:.4f} ± {s['mixing_final_std']:.4f} "
              f"({args.paths} paths); t50 {s['t50_mean']:.4g} s, t90 {s['t90_mean']:.4g} s")
        print(f"moved at jumps ({s['jump']}): mean {100 * s['stitched_share_mean']:.3g}%, max "
              f"{100 * s['stitched_share_max']:.3g}% of the grain volume; tracer drift {s['tracer_drift_max']:.2g}")
        L = s["lacey"]
        print(f"Lacey index at {args.horizon:g} s: {L['final_mean']:.4f}; t50 {L['t50_mean']:.4g} s, t90 {L['t90_mean']:.4g} s")
        print(f"speed-up: marginal {c['marginal_speedup']:.3g}x, total {c['total_speedup_with_database']:.3g}x "
              f"(database counted), {c['total_speedup_without_database']:.3g}x (not counted)")
        if "gas_tracer" in s:
            g = s["gas_tracer"]
            print(f"gas tracer (step input, {g['scheme']}): outlet F at {args.horizon:g} s "
                  f"{g['step_response_final']:.4f}, mean residence time {g['mean_residence_time']:.4g} s (spread "
                  f"{g['residence_time_spread']:.3g} s), balance error {g['balance_error_max']:.2g}")
            i = g["injected"]
            print(f"gas residence times over {i['injections']} injections along the paths: mean "
                  f"{i['mean_residence_time']:.4g} s, spread {i['residence_time_spread']:.3g} s, median "
                  f"{i['median_residence_time']:.4g} s")
        return 0
    _check_validate(args)
    from .validate import validate

    return validate(args.target, args.t0, args.t1, args.t2, args.out, args.paths, args.seed, args.continuations,
                    args.overrides, args.arch, log=log, lag=args.lag, sensitivity=args.sensitivity,
                    jump=args.jump or "auto")


def _check_validate(args) -> None:
    """`fbed rcfd validate`'s arguments, the preset and the database's length, before any run is made."""
    for k in ("t0", "t1", "t2"):
        if getattr(args, k) is None:
            raise ConfigError(f"validate needs --{k}", "", f"--{k}", hint="e.g. --t0 0.5 --t1 1.5 --t2 2.5")
    if not (0 <= args.t0 < args.t1 < args.t2):
        bad = "--t0" if not args.t0 >= 0 else "--t2" if not args.t1 < args.t2 else "--t1"
        raise ConfigError(f"need 0 <= t0 < t1 < t2 (got {args.t0:g}, {args.t1:g}, {args.t2:g})", "", bad)
    _check_counts(args)
    if args.continuations < 1:  # 0 ran the database and its continuations, then stopped in a traceback
        raise ConfigError(f"--continuations must be at least 1 (full runs the paths are checked against), got "
                          f"{args.continuations}", "", "--continuations")
    from ..config import load

    interval = load(args.target, args.overrides).probes.rcfd_interval
    frames = rcfd_frames(args.t1 - args.t0, interval)
    if frames < RCFD_MIN_FRAMES:
        raise ConfigError(f"t1 - t0 = {args.t1 - args.t0:g} s holds {frames} frame{'' if frames == 1 else 's'} of "
                          f"probes.rcfd_interval = {interval:g} s; rCFD needs at least {RCFD_MIN_FRAMES}", "", "--t1",
                          hint="record longer (a later --t1, an earlier --t0)")
    if frames - args.lag + 1 < RCFD_MIN_FRAMES:  # a frame spans LAG recorded ones, one starting at each boundary
        raise ConfigError(f"--lag {args.lag} leaves {max(0, frames - args.lag + 1)} frames of the {frames} that "
                          f"t1 - t0 = {args.t1 - args.t0:g} s records; rCFD needs at least {RCFD_MIN_FRAMES}", "",
                          "--lag", hint=f"give --lag {frames - RCFD_MIN_FRAMES + 1} or less, or record longer")

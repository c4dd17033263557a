"""The `fbed` command line: argument parsing and error reporting only (no physics here).

    fbed run PRESET [--set section.key=value]... [--out DIR] [--arch auto|cpu|cuda] [--resume DIR]
    fbed run PRESET --video [FILE]    (also write an mp4 of the run; [video] in the preset sets its look)
    fbed view PRESET [--set ...]      (the run in a window with live controls)
    fbed analyze RUN_DIR              (the preset's bubble analysis on a finished run; on a sweep folder
                                      of mri or umf runs, the cases side by side)
    fbed analyze RUN_DIR RUN_DIR... --out DIR   (mri, verma: several runs of one case pooled, e.g. GPU sessions)
    fbed analyze DIR DIR... --compare --out DIR (mri: cases side by side, labelled by the keys they differ by)
    fbed bench stress [--out DIR]     (hostile scenes: finish clean or stop with a clear message)
    fbed bench accuracy|stiffness [--size small|full] [--arch cpu|cuda] [--out DIR] [--resume]
                                      (error against cost; --resume goes on from the rows in --out)
    fbed sweep PRESET --set key=v1,v2,... [--set ...] [--jobs N] [--out DIR] [--overwrite] [--plot FIGURE]
               [--scheduler ADDRESS|local]   (each case a task on a Dask cluster)
    fbed --version
    fbed rcfd analyze RUN_DIR         (recurrence plot, spectra, period of a run that recorded rcfd.h5)
    fbed rcfd run RUN_DIR --horizon T --paths N --seed S [--tag "x<0"]   (rCFD mixing along Markov paths)
    fbed rcfd validate PRESET --t0 A --t1 B --t2 C [--out DIR]   (rCFD against full continuations)
    fbed pack BED OUT [--resolution R] [--speed-resolution Q]   (a bed in a few bytes a grain, for carrying)

Bad input (preset, key, unit, range, file) prints one clear message and exits with 2.
"""
from __future__ import annotations

import argparse
import math
import sys

from .config import ConfigError
from .config.rules import mp4_name
from .io.bedpack import RESOLUTION
from .io.store import VERSION, DiskFull, disk_full_text


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="fbed", description="GPU CFD-DEM simulator of gas-solid fluidized beds")
    p.add_argument("--version", action="version", version=f"fbed {VERSION}")
    sub = p.add_subparsers(dest="command", metavar="COMMAND")
    _add_run(sub)
    _add_view(sub)
    _add_analyze(sub)
    _add_bench(sub)
    _add_sweep(sub)
    _add_rcfd(sub)
    _add_pack(sub)
    return p


def _add_run(sub) -> None:
    r = sub.add_parser("run", help="run a preset", description="Run a TOML preset and write its outputs.")
    r.add_argument("preset", nargs="?", help="preset file (.toml); optional with --resume")
    r.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.KEY=VALUE",
                   help="override a preset key (repeatable), e.g. --set run.duration=0.05")
    r.add_argument("--out", help="output folder (default: runs/<preset name>, numbered if taken)")
    r.add_argument("--arch", choices=("auto", "cpu", "cuda"), default="auto",
                   help="where the kernels run (auto: CUDA when a GPU is present)")
    r.add_argument("--resume", metavar="DIR", help="continue the run in DIR from its checkpoint")
    r.add_argument("--overwrite", action="store_true", help="replace an existing run in --out")
    r.add_argument("--video", nargs="?", const="", default=None, metavar="FILE",
                   help="write a video (default FILE: video.mp4 in the output folder); same as "
                        "--set video.enabled=true")


def _add_view(sub) -> None:
    v = sub.add_parser("view", help="run a preset in a window with live controls",
                       description="Run PRESET in a window: space pause, n step, up/down gas velocity, j jet, "
                                   "c colour, v view, arrows orbit, =/- zoom, p screenshot, esc quit.")
    v.add_argument("preset", help="preset file (.toml)")
    v.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.KEY=VALUE")
    v.add_argument("--out", help="output folder (default: runs/<preset name>)")
    v.add_argument("--arch", choices=("auto", "cpu", "cuda"), default="auto")


def _add_analyze(sub) -> None:
    a = sub.add_parser("analyze", help="post-process a finished run (the preset's probes.analysis)",
                       description="Run the analysis named by the run's probes.analysis (boyce: the bubble on "
                                   "the central slab; verma: bubble statistics on the planes; mri: the MRI study's "
                                   "statistics on /mri and /slab; umf: the fluidization curve) on RUN_DIR's files; "
                                   "writes RUN_DIR/analysis and updates summary.json. On a sweep folder of mri or "
                                   "umf runs: the cases side by side (mri_compare.*, umf_compare.*). On several "
                                   "run folders of one case (mri, verma): their analysed windows pooled as "
                                   "realisations of one operating point, e.g. the GPU sessions of one drag law, "
                                   "into --out.")
    a.add_argument("run_dir", nargs="+", help="output folder of a run, or of a sweep (mri, umf: its cases side by "
                   "side); several run folders of one case (mri, verma) are pooled into --out")
    a.add_argument("--out", help="with several run folders: the folder for the pooled analysis (analysis/, "
                   "pooled.json), or with --compare for the table")
    a.add_argument("--compare", action="store_true", help="mri: several cases (run folders, or pooled folders of "
                   "--out) side by side in --out (mri_compare.*), labelled by the keys they differ by, as a sweep's")
    a.add_argument("--kind", choices=("boyce", "verma", "mri", "umf"), help="override the run's probes.analysis")
    a.add_argument("--plot", metavar="FIGURE", help="on a sweep folder: plot this summary figure against the swept "
                   "keys from sweep.csv (DIR/FIGURE.png), the cases not run again")


def _add_bench(sub) -> None:
    b = sub.add_parser("bench", help="stress scenes, accuracy against cost, contact stiffness "
                                     "(fbed bench stress|accuracy|stiffness)",
                       description="fbed bench stress: hostile scenes that must finish clean or stop with a clear "
                                   "message; writes STRESS.md and stress.json into --out. fbed bench accuracy: "
                                   "error against cost for every verification case, one knob at a time (accuracy.csv, "
                                   "pareto_<case>.png, ACCURACY.md with the recommended settings). fbed bench "
                                   "stiffness: the small bed against Young's modulus (stiffness.csv, stiffness.png, "
                                   "STIFFNESS.md).")
    b.add_argument("kind", choices=("stress", "accuracy", "stiffness"))
    b.add_argument("--out", help="output folder (default: runs/stress, runs/accuracy or runs/stiffness)")
    b.add_argument("--scenes", nargs="+", help="stress: only these scenes")
    b.add_argument("--cases", nargs="+", help="accuracy: only these cases")
    b.add_argument("--size", choices=("small", "full"), default="small",
                   help="accuracy, stiffness: 'small' (CPU minutes) or 'full' (the sizes meant for the GPU)")
    b.add_argument("--arch", choices=("cpu", "cuda"), default="cpu")
    b.add_argument("--resume", action="store_true",
                   help="accuracy, stiffness: keep the rows already in --out's CSV (same --size and --arch) and "
                        "measure only the rest (a bench cut off by a time limit goes on where it stopped)")
    b.add_argument("--limit", type=float, default=600.0, help="stress: wall-clock limit per scene [s] (a hang fails)")
    _flags_read_by(b, "kind", BENCH_FLAGS)


def _add_sweep(sub) -> None:
    w = sub.add_parser("sweep", help="run a preset over lists of values",
                       description="Run PRESET for every combination of the --set lists; write sweep.csv.")
    w.add_argument("preset", help="preset file (.toml)")
    w.add_argument("--set", dest="sets", action="append", default=[], metavar="SECTION.KEY=V1,V2,...",
                   help="a key and its list of values (repeatable: the cases are the Cartesian product)")
    w.add_argument("--jobs", type=int, default=1, help="cases run at once (each on one CPU thread when > 1)")
    w.add_argument("--out", help="output folder (default: a new runs/<preset>-sweep, -2, ...)")
    w.add_argument("--overwrite", action="store_true", help="replace an earlier sweep in --out")
    w.add_argument("--resume", action="store_true", help="go on with the sweep in --out (the same --set lists): "
                   "its finished and unstable cases are kept, interrupted ones go on from their checkpoints")
    w.add_argument("--plot", dest="plot_figure", metavar="FIGURE",
                   help="plot this summary figure against the first swept key (another, later: fbed analyze "
                   "OUT --plot FIGURE)")
    w.add_argument("--arch", choices=("auto", "cpu", "cuda"), default="auto")
    w.add_argument("--scheduler", metavar="ADDRESS",
                   help="submit each case to this Dask distributed scheduler (tcp://host:8786), or 'local' for a "
                        "LocalCluster of --jobs workers here; needs the cluster extra (pip install -e '.[cluster]')")


def _add_rcfd(sub) -> None:
    rc = sub.add_parser("rcfd", help="recurrence CFD on a recorded run (fbed rcfd analyze|run|validate)",
                        description="fbed rcfd analyze RUN_DIR: recurrence plot, spectra and period of the frames a "
                                    "run recorded (probes.rcfd_from); fbed rcfd run RUN_DIR: a solids tracer moved "
                                    "along seeded Markov paths through the frames; fbed rcfd validate PRESET: a "
                                    "database run, its replay, three perturbed full continuations and the rCFD "
                                    "ensemble against them.")
    rc.add_argument("action", choices=("analyze", "run", "validate"))
    rc.add_argument("target", help="analyze, run: a run folder with rcfd.h5; validate: a preset")
    rc.add_argument("--out", help="output folder (default: RUN_DIR/rcfd/...; validate: runs/rcfd-validate-<preset>)")
    rc.add_argument("--horizon", type=float, default=10.0, help="run: simulated time of each path [s]")
    rc.add_argument("--paths", type=int, default=20, help="run, validate: number of paths")
    rc.add_argument("--seed", type=int, default=1, help="run, validate: seed of the paths (path i uses (seed, i))")
    rc.add_argument("--tag", help="run: tagged grains, e.g. 'x<0' (default: the recorded probes.rcfd_tag, from the "
                                  "real grains)")
    rc.add_argument("--name", help="run: name of the output folder under RUN_DIR/rcfd")
    rc.add_argument("--start", choices=("end", "begin"), default="end",
                    help="run: tag at the database's last state (end) or first (begin)")
    rc.add_argument("--gas", action="store_true", help="run: also a gas tracer (step input at the inlet) on the "
                                                        "recorded fluxes: rtd.csv, the outlet's step response")
    rc.add_argument("--gas-scheme", choices=("fct", "upwind"), default=None,
                    help="run, with --gas: the gas tracer's scheme: fct (flux-corrected, second order where smooth, "
                         "bounded; the default) or upwind (first order, as CFDEM's rCFD; 4x cheaper, its RTD spread "
                         "1.5x FCT's on the rcfd_bubbling bed: validation/rcfd/README.md, 0000)")
    rc.add_argument("--jump", choices=("match", "flow", "stitch"), default=None,
                    help="run, validate: how the grain tracer crosses a jump: match (each grain takes the tag of one "
                         "grain of the state left, paired by position by a dense assignment; the default up to "
                         "10,000 grains), flow (paired one to one too, the grains routed cell to cell along a flow: "
                         "scales to a million grains; the default above), both stored in RUN_DIR/rcfd/matchings.h5 "
                         "for later runs, or stitch (cell volumes stitched, each grain takes its cell's mean tag: "
                         "mixes faster); a database without grain cells always stitches")
    rc.add_argument("--lag", type=int, default=1, help="run, validate: a frame spans LAG recorded frames, its shift "
                                                       "built from each grain's cell at its ends (motion that "
                                                       "reverses within it is no dispersion)")
    rc.add_argument("--workers", type=int, default=None, help="run: processes the jumps and the paths are spread "
                    "over (default: one per core)")
    rc.add_argument("--t0", type=float, help="validate: start of the database [s]")
    rc.add_argument("--t1", type=float, help="validate: end of the database, start of the continuations [s]")
    rc.add_argument("--t2", type=float, help="validate: end of the continuations [s]")
    rc.add_argument("--continuations", type=int, default=3, help="validate: perturbed full continuations")
    rc.add_argument("--sensitivity", action="store_true", help="validate: the extrapolation again with the frame "
                    "interval doubled and with the mean sequence halved, each against the full runs' tolerance")
    rc.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.KEY=VALUE",
                    help="validate: override a preset key of the runs")
    rc.add_argument("--arch", choices=("auto", "cpu", "cuda"), default="auto")
    from .rcfd.cli import FLAG_ACTIONS  # (no Taichi)

    _flags_read_by(rc, "action", FLAG_ACTIONS)


def _add_pack(sub) -> None:
    k = sub.add_parser("pack", help="pack a bed's positions and sizes (and, moving, its speeds) into a small file",
                       description="Write BED's live grains (a bed.h5 or checkpoint.h5) as a packed bed: positions "
                                   "rounded to --resolution, sizes exact, velocities and spins kept to "
                                   "--speed-resolution (else left out: a bed at rest), contact history left out; "
                                   "about 5.5 B a grain at 0.1 um, against 12 for float32 positions. OUT serves as "
                                   "particles.initial_state.")
    k.add_argument("bed", help="a bed.h5 or checkpoint.h5 of an earlier run")
    k.add_argument("out", help="the packed bed to write (.h5)")
    k.add_argument("--resolution", type=float, default=RESOLUTION, help="position resolution [m] (a coordinate is off "
                   "by at most half of it; raised where the bed spans more than 2^21 of it)")
    k.add_argument("--speed-resolution", type=float, default=0.0, help="keep each grain's velocity and its spin's "
                   "surface speed (omega x radius) to this [m/s] a component, to go on with a moving bed (default 0: "
                   "left out, the bed restarts at rest)")


#: the kinds of `fbed bench` each flag is read by (its dest -> kinds)
BENCH_FLAGS = {"scenes": ("stress",), "limit": ("stress",), "cases": ("accuracy",), "size": ("accuracy", "stiffness"),
               "resume": ("accuracy", "stiffness")}


def _flags_read_by(parser, choice: str, table: dict) -> None:
    """Record on ``parser`` which values of its positional ``choice`` read each flag of ``table``, and the flags'
    defaults, for :func:`refuse_unread_flags`."""
    parser.set_defaults(flag_choice=choice, flag_table=table,
                        flag_defaults={d: parser.get_default(d) for d in table})


def refuse_unread_flags(args) -> None:
    """A flag the chosen action does not read is refused, naming the actions that read it: `fbed rcfd validate
    --horizon 5` ran over t2 - t1, `fbed bench stress --cases x` ran every scene, each without a word."""
    table = getattr(args, "flag_table", None)
    if not table:
        return
    chosen = getattr(args, args.flag_choice)
    for dest, readers in table.items():
        if chosen not in readers and getattr(args, dest) != args.flag_defaults[dest]:
            flag = "--set" if dest == "overrides" else f"--{dest.replace('_', '-')}"
            hint = ("validate runs its paths over t2 - t1" if dest == "horizon" and chosen == "validate"
                    else f"drop {flag} here")
            raise ConfigError(f"{flag} is for fbed {args.command} {' and '.join(readers)}, not {chosen}", "", flag,
                              hint=hint)


def run_overrides(args) -> list[str]:
    """`fbed run`'s --set list, with --video's; the flags that cannot go together refused, naming the flag."""
    if args.resume and (args.out or args.overwrite):  # both were ignored: the run went on in --resume's folder
        flag = "--out" if args.out else "--overwrite"
        raise ConfigError(f"a resumed run goes on in its own folder ({args.resume}): {flag} does not apply", flag, "",
                          hint=f"to branch it, copy the folder and resume the copy: cp -r {args.resume} NEW && fbed "
                          "run --resume NEW" if args.out else "leave out --overwrite to resume; to start the run "
                          "again, leave out --resume (PRESET --out DIR --overwrite)")
    overrides = list(args.overrides)
    if args.video is not None:
        if args.video and not mp4_name(args.video):
            raise ConfigError(f"'{args.video}' is not an .mp4 file's name (the video is H.264 in an MP4 file)",
                              "--video", "", hint="e.g. --video bubble.mp4, or --video alone for video.mp4 in the "
                              "output folder")
        overrides.append("video.enabled=true")
        if args.video:
            overrides.append(f"video.file={args.video!r}".replace("'", '"'))
    return overrides


def main(argv: list[str] | None = None) -> int:
    # each command imports its module when chosen: `fbed --version`, `fbed analyze` and `fbed rcfd` never load
    # Taichi, and a bad argument is reported before any solver is imported
    args = build_parser().parse_args(argv)
    if args.command is None:
        build_parser().print_help()
        return 2
    try:
        refuse_unread_flags(args)
        if args.command == "run":
            from .run import run

            return run(args.preset, run_overrides(args), args.out, args.arch, args.resume, args.overwrite)
        if args.command == "view":  # the runner and the window composed here: the GUI never drives the runner
            from .gui.viewer import ViewerController, display_available
            from .run import run

            if not display_available():
                raise ConfigError("no display: the interactive window needs a screen", args.preset, "view",
                                  hint=f"render headless instead: fbed run {args.preset} --video")
            return run(args.preset, args.overrides, out=args.out, arch=args.arch, viewer=ViewerController)
        if args.command == "pack":
            from .pack import pack_command  # (numpy and h5py: no Taichi)
            return pack_command(args.bed, args.out, args.resolution, args.speed_resolution)
        if args.command == "bench":
            if args.kind == "accuracy":
                from .bench.accuracy import accuracy, all_cases

                names = [c.name for c in all_cases()]
                unknown = sorted(set(args.cases or []) - set(names))
                if unknown:
                    raise ConfigError(f"unknown case {unknown[0]!r}", "--cases", unknown[0],
                                      hint="cases: " + ", ".join(names))
                return accuracy(args.out, args.cases, args.size, args.arch, 1 if args.arch == "cpu" else None,
                                resume=args.resume)
            if args.kind == "stiffness":
                from .bench.stiffness import stiffness

                return stiffness(args.out, args.size, args.arch, 1 if args.arch == "cpu" else None,
                                 resume=args.resume)
            from .bench.stress import SCENES, stress

            if not (args.limit > 0 and math.isfinite(args.limit)):  # -1: every scene reported "hung (killed at the
                raise ConfigError(f"--limit must be a positive time in s, got {args.limit:g}", "", "--limit")  # limit)"

            unknown = sorted(set(args.scenes or []) - {sc.name for sc in SCENES})
            if unknown:
                raise ConfigError(f"unknown scene {unknown[0]!r}", "--scenes", unknown[0],
                                  hint="scenes: " + ", ".join(sc.name for sc in SCENES))
            return stress(args.out, args.scenes, args.arch, args.limit)
        if args.command == "analyze":
            from .postprocess import analyze_command

            return analyze_command(args.run_dir, args.out, args.kind, args.plot, args.compare)
        if args.command == "rcfd":
            from .rcfd.cli import main as rcfd_main

            return rcfd_main(args)
        if args.command == "sweep":
            from .sweep import sweep

            if not args.sets:
                raise ConfigError("nothing to sweep", "--set", "", hint="e.g. --set boundary.bottom.velocity=[0,0,0.3],[0,0,0.6]")
            if args.jobs < 1:
                raise ConfigError(f"--jobs must be at least 1, got {args.jobs}", "", "--jobs")
            return sweep(args.preset, args.sets, args.jobs, args.out, args.plot_figure, args.arch, args.scheduler,
                         args.overwrite, args.resume)
    except ConfigError as err:
        print(f"fbed: error: {err}", file=sys.stderr)
        return 2
    except (DiskFull, OSError) as err:  # an analysis's, a sweep's or rCFD's outputs (a run says its own, with its
        what = disk_full_text(err)  # checkpoint kept); any other OS error as before
        if what is None:
            raise
        print(f"fbed: error: {what}; free some space and run it again", file=sys.stderr)
        return 3
    except KeyboardInterrupt:  # before a run's own handler is installed (or outside a run): nothing half-written
        print("fbed: interrupted", file=sys.stderr)
        return 130
    return 2


def entry() -> None:
    sys.exit(main())


if __name__ == "__main__":
    entry()

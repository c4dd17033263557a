"""`fbed analyze`: a finished run's analysis (probes.analysis), a sweep's cases side by side, several runs of one
case pooled; the analysis a run does at its end. The analyses themselves live in app/analysis/."""
from __future__ import annotations

import csv
import importlib
import json
import pathlib

from . import config as cfgmod
from .callbacks.progress import log
from .config import ConfigError
from .io import store
from .outputs import refuse_live_folder

EXIT_OK, EXIT_INPUT = 0, 2


def post_process(analysis: str, out_dir: pathlib.Path, at_run_end: bool = True) -> dict:
    """Run the preset's analysis on the finished run's files; its key figures go into summary.json.
    ``at_run_end``: a failure says how to rerun it (at the end of `fbed run`; `fbed analyze` is that rerun)."""
    try:
        ended_early(analysis, out_dir)
        mod = importlib.import_module(f".analysis.{analysis}", "app")
        figures = mod.summarize(out_dir)
        log(f"fbed: {analysis} analysis written to {out_dir / 'analysis'}")
        return figures
    except Exception as err:  # noqa: BLE001 - an analysis failure must not lose the run's outputs
        again = f"; rerun it with `fbed analyze {out_dir}`" if at_run_end else ""
        log(f"fbed: the {analysis} analysis failed ({type(err).__name__}: {err}){again}")
        return {"analysis_error": f"{type(err).__name__}: {err}"}


#: the run.h5 groups each analysis reads (any one), and the probes' intervals that record them
RECORDS = {"boyce": {"slab": "slab_interval"}, "mri": {"mri": "mri_interval", "slab": "slab_interval"},
           "verma": {"planes": "planes_interval", "porosity3d": "volume_interval"}}


def ended_early(analysis: str, out_dir: pathlib.Path) -> None:
    """ValueError where the records an analysis reads are all missing although the preset asks for them: the run
    ended before their first (a 0.1 ms run of mri_poppy was told "set probes.mri_interval", which it had)."""
    import h5py

    groups = RECORDS.get(analysis, {})
    if not groups:  # (umf reads the series, which every run has)
        return
    with h5py.File(out_dir / "run.h5", "r") as f:
        if any(g in f for g in groups):
            return
        t = f["series/time"][-1] if "series/time" in f and f["series/time"].shape[0] else 0.0
    probes = cfgmod.load(out_dir / "config.toml").probes
    asked = {k: getattr(probes, k) for k in groups.values() if getattr(probes, k) > 0}
    if asked:
        first = min(asked.values())
        raise ValueError(f"the run ended at t = {t:.6g} s, before the first record of "
                         f"{' or '.join(f'probes.{k} = {v:g} s' for k, v in asked.items())}: run longer than {first:g} s")


def analyze(run_dir: str, kind: str | None = None, plot: str | None = None) -> int:
    """`fbed analyze RUN_DIR`: the run's analysis (probes.analysis, or ``kind``) into RUN_DIR/analysis; with
    ``plot`` on a sweep folder, that summary figure against the swept keys (SWEEP_DIR/FIGURE.png) alone."""
    d = pathlib.Path(run_dir)
    sweep_dir = (d / "sweep.csv").exists() and not (d / "run.h5").exists()
    if plot is not None:
        if not sweep_dir:
            raise ConfigError("--plot draws a sweep's figure: this folder holds no sweep.csv", str(d), "--plot",
                              hint="give the folder `fbed sweep` wrote")
        from .sweep import replot

        print(replot(d, plot))
        return EXIT_OK
    if sweep_dir:
        return analyze_sweep(d, kind)
    if not (d / "run.h5").exists() or not (d / "config.toml").exists():
        raise ConfigError("not a run folder (no run.h5 / config.toml)", str(d), "RUN_DIR",
                          hint="give the output folder of an fbed run")
    refuse_live_folder(d, "RUN_DIR")
    cfg = cfgmod.load(d / "config.toml")
    kind = kind or cfg.probes.analysis
    if kind == "none":
        raise ConfigError("the run names no analysis", str(d / "config.toml"), "probes.analysis",
                          hint="pass --kind boyce, verma, mri or umf")
    figures = post_process(kind, d, at_run_end=False)
    if "analysis_error" in figures:  # the run's summary.json keeps what it had (a wrong --kind spoils nothing)
        return EXIT_INPUT
    summary_path = d / "summary.json"
    summary = json.loads(summary_path.read_text()) if summary_path.exists() else {}
    summary.update(figures)
    store.write_json(summary_path, summary)
    for k, v in figures.items():
        print(f"{k} = {v:.6g}" if isinstance(v, float) else f"{k} = {v}")
    return EXIT_OK


def analyze_sweep(d: pathlib.Path, kind: str | None = None) -> int:
    """`fbed analyze SWEEP_DIR`: each case's analysis where it is missing, then the cases side by side
    (SWEEP_DIR/mri_compare.{csv,md,png} or umf_compare.{md,png})."""
    with open(d / "sweep.csv", newline="") as f:
        cases = [r["case"] for r in csv.DictReader(f)]
    kinds = set()
    for c in cases:
        cd = d / c
        if (cd / "config.toml").exists():
            kinds.add(kind or cfgmod.load(cd / "config.toml").probes.analysis)
    if len(kinds) != 1 or next(iter(kinds)) not in ("mri", "umf"):
        raise ConfigError(f"side-by-side comparison is written for the mri and umf analyses, not {sorted(kinds)}",
                          str(d), "probes.analysis", hint="analyze each case folder on its own: fbed analyze DIR/case-000")
    which = next(iter(kinds))
    for c in cases:
        cd = d / c
        if (cd / "run.h5").exists() and not (cd / "analysis" / f"{which}.json").exists():
            analyze(str(cd), which)
    print(importlib.import_module(f".analysis.{which}", "app").compare(d).read_text())
    return EXIT_OK


def analyze_command(run_dirs: list[str], out: str | None, kind: str | None, plot: str | None,
                    compare: bool = False) -> int:
    """`fbed analyze`: one run or sweep folder (:func:`analyze`), several runs of one case pooled
    (:func:`analyze_pooled`), or several cases side by side (:func:`analyze_compare`)."""
    if len(run_dirs) == 1 and out is None and not compare:
        return analyze(run_dirs[0], kind, plot)
    if plot is not None:
        raise ConfigError("--plot draws a sweep's figure, not pooled or compared runs'", "", "--plot",
                          hint="drop --plot, or give the sweep folder alone")
    return analyze_compare(run_dirs, out, kind) if compare else analyze_pooled(run_dirs, out, kind)


def analyze_compare(dirs_given: list[str], out: str | None, kind: str | None = None) -> int:
    """`fbed analyze DIR DIR ... --compare --out OUT`: the mri figures of several cases side by side, as of a sweep's
    (OUT/mri_compare.{csv,md,png}): run folders (analysed first where they are not yet) or pooled folders (their
    case.toml, their first run's preset, names the case), labelled by the case keys they differ by (e.g.
    coupling.drag): four drag laws run in separate GPU sessions make the sweep's table."""
    from .analysis import mri_report, pooling

    dirs = [pathlib.Path(d) for d in dirs_given]
    if len(dirs) < 2 or out is None:
        raise ConfigError("puts several cases side by side into a folder of their own: give two folders or more and "
                          "--out", "", "--compare", hint="e.g. fbed analyze runs/a runs/b --compare --out runs/cmp")
    cfgs, status = [], []
    for d in dirs:
        if (d / "pooled.json").exists() and (d / CASE_FILE).exists():
            case, what = d / CASE_FILE, f"{len(json.loads((d / 'pooled.json').read_text())['runs'])} runs pooled"
        elif (d / "run.h5").exists() and (d / "config.toml").exists():
            case, what = d / "config.toml", "run"
            named = cfgmod.load(case).probes.analysis
            if (kind or named) != "mri":  # before analysing it: nothing is rewritten
                raise ConfigError(f"--compare is written for the mri analysis; this run names {named!r}", str(case),
                                  "probes.analysis", hint="compare mri runs, or pooled folders of them")
            if not (d / "analysis" / "mri.json").exists() and analyze(str(d), kind) != EXIT_OK:
                return EXIT_INPUT
        else:
            raise ConfigError(f"neither a run folder (run.h5, config.toml) nor a pooled one (pooled.json, {CASE_FILE})",
                              str(d), "RUN_DIR", hint="give fbed runs' folders or `fbed analyze ... --out` folders")
        if not (d / "analysis" / "mri.json").exists():
            raise ConfigError("no mri analysis here (analysis/mri.json)", str(d), "RUN_DIR",
                              hint="--compare is written for the mri analysis")
        cfgs.append(cfgmod.load(case))
        status.append(what)
    keys = pooling.keys_that_differ(cfgs)
    flats = [pooling.flat(c) for c in cfgs]
    table = [mri_report.compare_row(d.name, {k: f.get(k) for k in keys}, st, d)
             for d, f, st in zip(dirs, flats, status)]
    o = pathlib.Path(out)
    o.mkdir(parents=True, exist_ok=True)
    print(mri_report.write_compare(o, table, keys, f"{len(dirs)} cases").read_text())
    return EXIT_OK


#: the analyses that pool several runs of one case, and their modules
POOLED = {"mri": ".analysis.mri", "verma": ".analysis.verma_pool"}
#: a pooled folder's copy of its first run's resolved preset: the case it holds (read by --compare)
CASE_FILE = "case.toml"


def analyze_pooled(run_dirs: list[str], out: str | None, kind: str | None = None) -> int:
    """`fbed analyze RUN RUN ... --out DIR`: the mri or verma analysis of several runs of one case pooled as
    realisations of one operating point (``summarize_pooled`` of ``analysis.mri``, ``analysis.verma_pool``) into
    DIR/analysis and DIR/pooled.json."""
    dirs = [pathlib.Path(d) for d in run_dirs]
    if len(dirs) < 2:
        raise ConfigError("--out is for pooling several runs of one case: give two run folders or more", "", "--out",
                          hint=f"analyze one run in its own folder: fbed analyze {run_dirs[0]}")
    if out is None:
        raise ConfigError("several run folders are pooled into a folder of their own: name it", "", "--out",
                          hint=f"e.g. fbed analyze {' '.join(run_dirs)} --out runs/pooled")
    for d in dirs:
        if not (d / "run.h5").exists() or not (d / "config.toml").exists():
            raise ConfigError("not a run folder (no run.h5 / config.toml)", str(d), "RUN_DIR",
                              hint="give the output folders of fbed runs of one case")
        refuse_live_folder(d, "RUN_DIR")
    o = pathlib.Path(out)
    if len({d.resolve() for d in dirs}) < len(dirs):
        raise ConfigError("a run folder is given twice: its frames would count twice", out, "RUN_DIR")
    if any(o.resolve() == d.resolve() for d in dirs) or (o / "run.h5").exists():
        raise ConfigError("--out is a run folder: the pooled analysis would replace its own", out, "--out",
                          hint="name a new folder, e.g. runs/pooled")
    kinds = {kind or cfgmod.load(d / "config.toml").probes.analysis for d in dirs}
    if len(kinds) > 1:
        raise ConfigError(f"the runs name different analyses ({', '.join(sorted(kinds))}): they are not one case",
                          str(dirs[0]), "probes.analysis", hint="pool the sessions of one case")
    if next(iter(kinds)) not in POOLED:
        raise ConfigError(f"pooling runs is written for the {' and '.join(POOLED)} analyses, not {sorted(kinds)}",
                          str(dirs[0]), "probes.analysis", hint="analyze each run folder on its own: fbed analyze DIR")
    which = next(iter(kinds))
    o.mkdir(parents=True, exist_ok=True)
    try:
        figures = importlib.import_module(POOLED[which], "app").summarize_pooled(dirs, o)
    except ValueError as err:
        raise ConfigError(str(err), out, "RUN_DIR") from None
    (o / CASE_FILE).write_text((dirs[0] / "config.toml").read_text())
    log(f"fbed: {len(dirs)} runs pooled: the {which} analysis written to {o / 'analysis'}")
    for k, v in figures.items():
        print(f"{k} = {v:.6g}" if isinstance(v, float) else f"{k} = {v}")
    return EXIT_OK

"""`fbed sweep`: run a preset over the Cartesian product of lists of values.

    fbed sweep PRESET --set key=v1,v2,... [--set key2=...] [--jobs N] [--out DIR] [--plot FIGURE]
               [--overwrite | --resume] [--scheduler ADDRESS|local]

Each case is an ordinary `fbed run` in its own folder (DIR/case-000, ...), in its own
process, so a failed case is recorded in sweep.csv and does not stop the others.
With --scheduler, the cases are submitted to a Dask distributed scheduler (ADDRESS, e.g.
tcp://head:8786, or `local`: a LocalCluster of --jobs workers on this machine); each runs as
`python -m app run` on a worker, with PRESET and DIR as absolute paths (a folder every worker
sees); a worker that dies is recorded as that case's failure and the others go on.
sweep.csv has one row per case: its swept values, its status and exit code, and every
number of its summary.json. With --plot, FIGURE (a summary key, e.g. mean_pressure_drop)
is plotted against the first swept key into DIR/FIGURE.png (`fbed analyze DIR --plot FIGURE`: later, from
sweep.csv). Ctrl-C or SIGTERM stops the running cases with their checkpoints and starts no other; --resume
goes on with the sweep in DIR (the same lists): finished and unstable cases kept, interrupted ones resumed.
"""
from __future__ import annotations

import concurrent.futures
import csv
import itertools
import math
import os
import pathlib
import signal
import sys

from .config import ConfigError, load
from .outputs import fresh_folder, names, out_folder, remove_paths, run_outputs
from .stopping import EXIT_INTERRUPTED as EXIT_STOPPED, signals_handled
from .sweep_case import NOT_FINISHED, LiveCases, failed_row, failure, not_started, run_case  # noqa: F401 (failure: tests)


def split_values(raw: str) -> list[str]:
    """Split 'a,b,[1,2],"x,y"' on the commas that are not inside brackets, braces or quotes."""
    out, depth, quote, cur = [], 0, None, ""
    for ch in raw:
        if quote:
            cur += ch
            if ch == quote:
                quote = None
            continue
        if ch in "\"'":
            quote = ch
        elif ch in "[{":
            depth += 1
        elif ch in "]}":
            depth -= 1
        elif ch == "," and depth == 0:
            out.append(cur.strip())
            cur = ""
            continue
        cur += ch
    if cur.strip():
        out.append(cur.strip())
    return out


def cases(sets: list[str]) -> tuple[list[str], list[tuple[str, ...]]]:
    keys, lists = [], []
    for item in sets:
        if "=" not in item:
            raise ConfigError(f"{item!r} is not of the form key=v1,v2,...", "--set", item)
        key, raw = item.split("=", 1)
        key, values = key.strip(), split_values(raw)
        if not values:
            raise ConfigError("no values given", "--set", key)
        if key in keys:
            k = keys.index(key)
            if len(values) == len(lists[k]) == 1:  # one fixed value given again: the later wins, as in `fbed run`
                lists[k] = values
                continue
            # a list beside another --set of its key: each case would apply both, the later winning in every case
            raise ConfigError("the key is given twice, with a list of values", "--set", key,
                              hint=f"give all its values in one --set {key}=v1,v2,...")
        twice = sorted({v for v in values if values.count(v) > 1})
        if twice:
            raise ConfigError(f"{', '.join(twice)} given twice: the cases would be the same run", "--set", key,
                              hint="give each value once (to repeat a case with another random fill, sweep run.seed)")
        keys.append(key)
        lists.append(values)
    return keys, list(itertools.product(*lists))


def number(v) -> float:
    """A swept value or summary figure as a number: the magnitude of a vector value such as [0,0,0.6]; NaN for
    what is no number (a drag law's name, a failed case's missing figure)."""
    try:
        return float(v)
    except (TypeError, ValueError):
        pass
    try:
        import tomllib

        return float(sum(float(x) ** 2 for x in tomllib.loads(f"v = {v}")["v"]) ** 0.5)
    except Exception:
        return float("nan")


def plotted(rows: list[dict], key: str, figure: str, group: str | None = None):
    """What --plot draws: ({group value: (x, y)}, categories). x is ``key``'s value where every case's is a number
    (the points sorted by it); else ``categories`` lists the values in the order the cases were given (a swept
    drag law: its names) and x is each case's index in it. Cases without the figure as a finite number (failed
    ones) are left out; none with it is a ConfigError naming the figures the cases have."""
    have = [r for r in rows if math.isfinite(number(r.get(figure)))]
    if not have:
        skip = {key, group, "case", "exit_code"}
        figures = sorted({k for r in rows for k, v in r.items() if k not in skip and math.isfinite(number(v))})
        raise ConfigError(f"no case's summary.json has the figure {figure!r} (sweep.csv holds each case's figures)",
                          "--plot", figure, hint="figures of these cases: " + (", ".join(figures[:15]) or "none") +
                          (", ..." if len(figures) > 15 else ""))
    categories = None
    if any(not math.isfinite(number(r.get(key))) for r in rows):
        categories = list(dict.fromkeys(str(r.get(key)) for r in rows))
    series = {}
    for gval in (dict.fromkeys(r.get(group) for r in rows) if group else [None]):
        sel = [r for r in have if group is None or r.get(group) == gval]
        x = [categories.index(str(r.get(key))) if categories else number(r[key]) for r in sel]
        pts = sorted(zip(x, (number(r[figure]) for r in sel)))
        series[gval] = ([a for a, _ in pts], [b for _, b in pts])
    return series, categories


def plot(rows: list[dict], key: str, figure: str, path: pathlib.Path, group: str | None = None) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    series, categories = plotted(rows, key, figure, group)
    fig, ax = plt.subplots(figsize=(6, 4))
    for gval, (x, y) in series.items():
        ax.plot(x, y, "o" if categories else "o-", label=f"{group} = {gval}" if group else None)
    if categories:
        ax.set_xticks(range(len(categories)), categories, rotation=20 if len(categories) > 3 else 0)
    else:  # (matplotlib's default put nine labels like 0.00425 on a 6-inch axis, running into each other)
        from matplotlib.ticker import MaxNLocator

        ax.xaxis.set_major_locator(MaxNLocator(nbins=5))
    ax.set_xlabel(key)
    ax.set_ylabel(figure)
    if group:
        ax.legend()
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def check_figure_name(figure: str) -> None:
    if not figure.replace("_", "").isalnum():
        raise ConfigError("not a summary figure's name (the plot is written as DIR/FIGURE.png)", "--plot", figure,
                          hint="a key of the cases' summary.json, e.g. --plot mean_pressure_drop")


def plot_sweep(rows: list[dict], keys: list[str], figure: str, out_dir: pathlib.Path) -> pathlib.Path:
    """DIR/FIGURE.png: ``figure`` against the first swept key, one line per value of the second. A figure no case
    has is a ConfigError that names the figures there are, and how to plot one from the table."""
    path = out_dir / f"{figure}.png"
    try:
        plot(rows, keys[0], figure, path, group=keys[1] if len(keys) > 1 else None)
    except ConfigError as err:
        raise ConfigError(err.message, err.file, err.key, hint=f"{err.hint}; plot one from sweep.csv, without "
                          f"running the cases again: fbed analyze {out_dir} --plot FIGURE") from None
    return path


def replot(d: pathlib.Path, figure: str) -> pathlib.Path:
    """`fbed analyze SWEEP_DIR --plot FIGURE`: a sweep's figure drawn from its sweep.csv (its swept keys are the
    columns between 'case' and 'status'). A misspelt `fbed sweep --plot` was found out only after every case had
    run, and redrawing needed the cases run again (or matplotlib by hand)."""
    check_figure_name(figure)
    with open(d / "sweep.csv", newline="") as f:
        table = csv.DictReader(f)
        rows, columns = list(table), list(table.fieldnames or [])
    if "case" not in columns or "status" not in columns or columns.index("status") < 2:
        raise ConfigError("sweep.csv names no swept key (its columns: case, the keys, status, ...)",
                          str(d / "sweep.csv"), "--plot", hint="give the folder `fbed sweep` wrote")
    return plot_sweep(rows, columns[1:columns.index("status")], figure, d)


def on_dask(scheduler: str, jobs: int, preset: str, keys, combos, out_dir: pathlib.Path, arch: str, done,
            todo: dict) -> bool:
    """Each case of ``todo`` ({index: resume it}) as one Dask task (an `fbed run` subprocess on a worker);
    ``done(i, row)`` as each ends; whether Ctrl-C or SIGTERM stopped them (the cases not done are cancelled).

    A local cluster's own log is silenced (its workers inherit the setting): fbed says how each case ended, and a
    worker that a killed case's nanny restarts while the cluster closes logged a traceback on the sweep's terminal
    ("Failed to communicate with scheduler during heartbeat", seen once in four runs of the dead-worker test)."""
    if scheduler == "local":
        os.environ.setdefault("DASK_LOGGING__DISTRIBUTED", "critical")  # read when distributed is first imported
    try:
        from distributed import Client, Event, LocalCluster, as_completed
    except ImportError:
        raise ConfigError("--scheduler needs Dask's distributed scheduler", "--scheduler", scheduler,
                          hint="python3 -m pip install -e '.[cluster]' (or pip install 'dask[distributed]')") from None
    import uuid

    cluster, stopped = None, []
    if scheduler == "local":
        cluster = LocalCluster(n_workers=max(1, jobs), threads_per_worker=1, processes=True, dashboard_address=None)
    try:
        try:
            client = Client(cluster if cluster is not None else scheduler, timeout="30s")
        except (OSError, TimeoutError, ValueError) as err:
            raise ConfigError(f"cannot reach the Dask scheduler ({err})", "--scheduler", scheduler,
                              hint="start one with `dask scheduler` (and workers with `dask worker ADDRESS`), "
                                   "or pass --scheduler local") from None
        with client:
            preset_abs = str(pathlib.Path(preset).resolve())
            out_abs = out_dir.resolve()
            threads = 1 if cluster is not None and jobs > 1 else 0
            tag = uuid.uuid4().hex[:8]
            stop_event = Event(f"fbed-stop-{tag}", client=client)  # (the running cases poll it: see wait)
            futs = {client.submit(run_case, preset_abs, keys, combos[i], out_abs / f"case-{i:03d}", arch, threads,
                                  True, again, stop_event=stop_event.name, key=f"fbed-case-{i:03d}-{tag}",
                                  pure=False): i
                    for i, again in todo.items()}

            def on_signal(signum, frame):  # (Ctrl-C was not seen here while the cases ran; SIGTERM lost the table)
                if not stopped:
                    print(f"fbed sweep: {signal.Signals(signum).name}: no other case starts, and the running ones "
                          "stop with a checkpoint; go on later with the same command and --resume", file=sys.stderr, flush=True)
                stopped.append(signum)
                stop_event.set()
                client.cancel([f for f in futs if not f.done()])

            with signals_handled(on_signal):
                for fut in as_completed(list(futs)):
                    i = futs[fut]
                    try:
                        row = fut.result()
                    except Exception as err:  # noqa: BLE001 - a lost worker (KilledWorker), a task error, cancelled
                        why = f"{type(err).__name__}: {str(err).splitlines()[0][:120] if str(err) else ''}"
                        row = failed_row(keys, combos[i], out_dir / f"case-{i:03d}", why)
                        if stopped:
                            row.update(status=NOT_FINISHED, exit_code=EXIT_STOPPED)
                    done(i, row)
    finally:
        if cluster is not None:
            cluster.close()
    return bool(stopped)


def sweep_outputs(d: pathlib.Path) -> list[pathlib.Path]:
    """What a sweep wrote in ``d``: sweep.csv, its case folders and `fbed analyze`'s comparisons."""
    found = [d / "sweep.csv"] if (d / "sweep.csv").exists() else []
    found += sorted(p for p in d.glob("case-[0-9][0-9][0-9]*") if p.is_dir())
    return found + sorted(d.glob("mri_compare.*")) + sorted(d.glob("umf_compare.*"))


def planned_folder(preset: str, out: str | None) -> pathlib.Path:
    """Where the sweep will write: ``out``, else a new runs/<preset>-sweep, -2, ..."""
    return pathlib.Path(out) if out else fresh_folder(pathlib.Path("runs") / (pathlib.Path(preset).stem + "-sweep"))


def sweep_folder(preset: str, out: str | None, overwrite: bool) -> pathlib.Path:
    """The sweep's folder: by default a new one (runs/<preset>-sweep, -2, ...); a given one that holds a run is
    refused, one that holds a sweep too unless ``overwrite`` (its files then go first). Before, each case ran with
    --overwrite into case-NNN: a second sweep into the same folder replaced the first's cases without a word."""
    if not out:
        return out_folder(None, planned_folder(preset, out))
    d = pathlib.Path(out)
    if d.is_dir():
        if held := run_outputs(d):
            raise ConfigError(f"holds a run ({names(held)})", str(d), "--out", hint="give the sweep a folder of its own")
        held = sweep_outputs(d)
        if held and not overwrite:
            raise ConfigError(f"already holds a sweep ({names(held)})", str(d), "--out",
                              hint="pass --overwrite to replace it, or another --out")
        remove_paths(held)
    return out_folder(out, d)


def on_threads(jobs: int, preset: str, keys, combos, out_dir: pathlib.Path, arch: str, threads: int, done,
               todo: dict) -> bool:
    """The cases of ``todo`` ({index: resume it}), ``jobs`` at a time here; whether a signal stopped them. Ctrl-C
    or SIGTERM to the sweep stops it: the running cases are passed the signal (they stop with a checkpoint), and no
    case starts after it (before, the queued cases ran on to their ends after a Ctrl-C); the table says "not
    started" for those."""
    live = LiveCases()

    def on_signal(signum, frame):
        if live.stop(signum):
            print(f"fbed sweep: {signal.Signals(signum).name}: the running cases stop with a checkpoint, and no "
                  "other starts; go on later with the same command and --resume", file=sys.stderr, flush=True)

    def case(i, again):
        if live.signum is not None:  # (run_case checks again as it starts the process)
            return not_started(keys, combos[i], out_dir / f"case-{i:03d}")
        return run_case(preset, keys, combos[i], out_dir / f"case-{i:03d}", arch, threads, resume=again, live=live)

    with signals_handled(on_signal), concurrent.futures.ThreadPoolExecutor(max_workers=max(1, jobs)) as pool:
        futs = {pool.submit(case, i, again): i for i, again in todo.items()}
        for fut in concurrent.futures.as_completed(futs):
            done(futs[fut], fut.result())
    return live.signum is not None


def check_cases(preset: str, keys, combos, case: pathlib.Path, overwrite: bool) -> None:
    """Every case's overrides validated up front (no half-run sweep on a typo), and the videos the cases would
    write outside their folders (``case``: where case-000 goes): one each, none over an existing file."""
    videos = {}
    for values in combos:
        cfg = load(preset, [f"{k}={v}" for k, v in zip(keys, values)])
        outside = pathlib.PurePath(cfg.video.file).is_absolute() or ".." in pathlib.PurePath(cfg.video.file).parts
        if cfg.video.enabled and outside:  # each case runs with --overwrite: the last to end would keep its video
            videos.setdefault(os.path.normpath(case / cfg.video.file), []).append(values)
    for f, v in videos.items():
        if len(v) > 1:
            raise ConfigError(f"{f}: {len(v)} cases would write this one video, outside their folders", preset,
                              "video.file", hint="leave video.file relative to the run's folder (e.g. 'video.mp4': "
                              "one in each case's folder), or sweep it too")
        if os.path.isfile(f) and not overwrite:  # (the cases run with --overwrite, for their own folders)
            raise ConfigError(f"{f}: already exists: the sweep would write over it", preset, "video.file",
                              hint="pass --overwrite to replace it, or name another video file")


def earlier_rows(d: pathlib.Path, keys, combos) -> tuple[list[dict], dict]:
    """--resume: the rows of the sweep in ``d`` (it must have run these very cases) and what is left to do, {case
    index: resume from its checkpoint}. Finished cases are kept, and so are unstable ones (they would fail again
    as they did); an interrupted or killed case goes on from its checkpoint, one without a checkpoint runs anew."""
    if not (d / "sweep.csv").is_file():
        raise ConfigError("holds no sweep to resume (no sweep.csv)", str(d), "--out",
                          hint="give the folder of the sweep to go on with, or leave out --resume")
    with open(d / "sweep.csv", newline="") as f:
        table = csv.DictReader(f)
        rows, columns = list(table), list(table.fieldnames or [])
    ran = (columns[1:columns.index("status")] if "status" in columns else [],
           [tuple(r.get(k, "") for k in keys) for r in rows])
    if ran != (list(keys), [tuple(v) for v in combos]):
        raise ConfigError(f"the sweep there ran other cases ({', '.join(ran[0]) or 'none'}: {len(rows)} cases)",
                          str(d), "--resume", hint="give the --set lists of that sweep (its sweep.csv lists them), "
                          "or another --out")
    todo = {i: (d / r["case"] / "checkpoint.h5").is_file() for i, r in enumerate(rows)
            if r["status"] not in ("finished", "unstable")}
    return rows, todo


def sweep(preset: str, sets: list[str], jobs: int = 1, out: str | None = None, plot_figure: str | None = None,
          arch: str = "auto", scheduler: str | None = None, overwrite: bool = False, resume: bool = False) -> int:
    load(preset)  # the preset itself must be valid before anything runs
    keys, combos = cases(sets)
    if resume and (overwrite or not out):
        raise ConfigError("--resume goes on with the sweep in --out" if not out else "--resume keeps the earlier "
                          "cases: --overwrite would remove them", "--resume", "", hint="fbed sweep PRESET --set ... "
                          "--out DIR --resume (the same --set lists)")
    check_cases(preset, keys, combos, planned_folder(preset, out) / "case-000", overwrite or resume)
    if plot_figure is not None:
        check_figure_name(plot_figure)
    rows, todo = [None] * len(combos), {i: False for i in range(len(combos))}
    if resume:
        out_dir = pathlib.Path(out)
        rows, todo = earlier_rows(out_dir, keys, combos)
    else:
        out_dir = sweep_folder(preset, out, overwrite)
    threads = 1 if jobs > 1 else 0
    where = f"on the Dask scheduler {scheduler}" if scheduler and scheduler != "local" else f"{jobs} at a time"
    left = f" ({len(todo)} left to run)" if resume else ""
    print(f"fbed sweep: {len(combos)} case{'s' * (len(combos) != 1)}{left} of {preset} over {', '.join(keys)}; "
          f"{where}; output in {out_dir}", file=sys.stderr, flush=True)

    def done(i, row):
        rows[i] = row
        print(f"  case-{i:03d} {dict(zip(keys, combos[i]))}: {row['status']}", file=sys.stderr, flush=True)

    stopped = False
    if scheduler:
        stopped = on_dask(scheduler, jobs, preset, keys, combos, out_dir, arch, done, todo)
    else:
        stopped = on_threads(jobs, preset, keys, combos, out_dir, arch, threads, done, todo)
    columns = list(dict.fromkeys(["case", *keys, "status", "exit_code"] + [k for r in rows for k in r]))
    with open(out_dir / "sweep.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=columns)
        w.writeheader()
        w.writerows(rows)
    failed = sum(1 for r in rows if int(r["exit_code"]) != 0)  # (a kept row's figures are the table's text)
    print(f"fbed sweep: {len(rows) - failed} of {len(rows)} cases finished; table in {out_dir / 'sweep.csv'}",
          file=sys.stderr)
    if failed and any(r["status"] != "unstable" for r in rows if int(r["exit_code"]) != 0):  # (not started too)
        print("fbed sweep: to go on with the cases that did not finish: the same command with --resume",
              file=sys.stderr)
    if plot_figure:  # (a figure no case has: exit 2 after the table, which keeps every case's figures)
        plot_sweep(rows, keys, plot_figure, out_dir)
    return EXIT_STOPPED if stopped else 0 if failed == 0 else 1

"""One case of `fbed sweep`: an `fbed run` subprocess in its own folder, and its row of sweep.csv.

A signal to the sweep reaches its cases: on threads here through :class:`LiveCases` (passed on to the running
ones, none started after it); on a Dask cluster through a distributed Event the case's task polls while its run
goes (:func:`wait`), since cancelling a running task does not end the run it started.
"""
from __future__ import annotations

import json
import os
import pathlib
import signal
import subprocess
import sys
import threading

from .stopping import EXIT_INTERRUPTED as EXIT_STOPPED

#: the status of a case the sweep's stop ended (on threads: one killed as it started; on Dask: one cancelled)
NOT_FINISHED = "not finished (the sweep was stopped)"


def failed_row(keys, values, out: pathlib.Path, why: str) -> dict:
    row = {k: v for k, v in zip(keys, values)}
    row.update(case=out.name, exit_code=-1, status=f"failed: {why}")
    return row


class LiveCases:
    """The case processes a sweep runs here, and the signal that stopped it. A signal is passed on to every
    running case, and no case starts after it. Starting a case and stopping the sweep exclude each other (a
    re-entrant lock: the handler runs in the main thread, and may interrupt itself), so a case that starts as the
    signal comes is either passed it or not started: before, one started after the handler's check and before it
    was listed, and ran to its end."""

    def __init__(self):
        self._procs, self._lock, self.signum = set(), threading.RLock(), None

    def stop(self, signum: int) -> bool:
        """Pass ``signum`` to the running cases; whether it is the first to stop the sweep."""
        with self._lock:
            first, self.signum = self.signum is None, signum
            procs = list(self._procs)
        for proc in procs:
            proc.send_signal(signum)
        return first

    def start(self, popen):
        """``popen()``'s process, listed; None (nothing started) once the sweep is stopped."""
        with self._lock:
            if self.signum is not None:
                return None
            proc = popen()
            self._procs.add(proc)
            signum = self.signum  # (set while popen ran, by a handler that interrupted it)
        if signum is not None:
            proc.send_signal(signum)
        return proc

    def end(self, proc) -> None:
        with self._lock:
            self._procs.discard(proc)


def not_started(keys, values, out: pathlib.Path) -> dict:
    row = failed_row(keys, values, out, "")
    row.update(status="not started (the sweep was stopped)", exit_code=EXIT_STOPPED)
    return row


def cluster_stopped(name: str):
    """On a Dask worker: a callable saying whether the sweep was stopped (its distributed Event ``name`` set)."""
    from distributed import Event

    event = Event(name)

    def stopped() -> bool:
        try:
            return event.is_set()
        except Exception:  # noqa: BLE001 - the scheduler gone: the run goes on (it stops if its worker goes)
            return False
    return stopped


def wait(proc, stopped=None, poll: float = 1.0) -> int:
    """``proc``'s exit code; SIGINT is passed to it (once) when ``stopped()`` turns true. A remote cluster's worker
    lives on after its sweep is stopped, and cancelling a running task does not end the run it started: such runs
    ran on to their ends."""
    if stopped is None:
        return proc.wait()
    told = False
    while True:
        try:
            return proc.wait(timeout=poll)
        except subprocess.TimeoutExpired:
            if not told and stopped():
                proc.send_signal(signal.SIGINT)  # (the run stops at its next step, with a checkpoint)
                told = True


def run_case(preset: str, keys, values, out: pathlib.Path, arch: str, threads: int,
             stop_with_parent: bool = False, resume: bool = False, live: LiveCases | None = None,
             stop_event: str = "") -> dict:
    """One case as an `fbed run` subprocess into ``out`` (``resume``: from its checkpoint there); its row.
    ``live``: the sweep's running cases, this one among them while it runs (a signal to the sweep is passed on
    to them; once it came, the case does not start). ``stop_event``: on a Dask worker, the sweep's distributed
    Event, set when it is stopped (the run is then passed SIGINT; one not started does not start)."""
    if resume:  # (its config.toml holds its values)
        args = [sys.executable, "-m", "app", "run", "--resume", str(out), "--arch", arch]
    else:
        args = [sys.executable, "-m", "app", "run", preset, "--out", str(out), "--overwrite", "--arch", arch]
        for k, v in zip(keys, values):
            args += ["--set", f"{k}={v}"]
    if threads:
        args += ["--set", f"run.threads={threads}"]
    env = dict(os.environ)
    env["PYTHONPATH"] = str(pathlib.Path(__file__).resolve().parents[1]) + os.pathsep + env.get("PYTHONPATH", "")
    if stop_with_parent:  # on a Dask worker: the run stops itself if the worker dies (the case is rerun elsewhere,
        env["FBED_STOP_WITH_PARENT"] = str(os.getpid())  # and that rerun waits until the orphan has let go of the
        env["FBED_LOCK_WAIT"] = "300"                     # folder, at its next step)
    stopped = cluster_stopped(stop_event) if stop_event else None
    if stopped is not None and stopped():  # (a task that started as the sweep's cancel came)
        return not_started(keys, values, out)
    out.mkdir(parents=True, exist_ok=True)
    with open(out / "log.txt", "a" if resume else "w") as logf:
        def popen():
            return subprocess.Popen(args, stdout=logf, stderr=subprocess.STDOUT, env=env)

        proc = popen() if live is None else live.start(popen)
        if proc is None:
            return not_started(keys, values, out)
        try:
            rc = wait(proc, stopped)
        finally:
            if live is not None:
                live.end(proc)
    row = {k: v for k, v in zip(keys, values)}
    row.update(case=out.name, exit_code=rc)
    summary = out / "summary.json"
    if summary.exists():
        s = json.loads(summary.read_text())
        row["status"] = s.get("status", "")
        row.update({k: v for k, v in s.items() if isinstance(v, (int, float)) and not isinstance(v, bool)})
    elif rc != 0 and live is not None and live.signum is not None:  # (one signalled as it started dies before
        row["status"] = NOT_FINISHED  # its run can write anything)
    else:
        row["status"] = f"failed: {failure((out / 'log.txt').read_text())}"
    return row


def failure(log: str) -> str:
    """Why a case that wrote no summary failed, from its log: the last `fbed: error:` line (its hint follows it, and
    was the status before: "failed:   hint: fewer grains ..."), else the log's last line (a traceback's exception)."""
    lines = [ln.strip() for ln in log.strip().splitlines()]
    errors = [ln.removeprefix("fbed: error:").strip() for ln in lines if ln.startswith("fbed: error:")]
    return (errors or lines or [""])[-1]

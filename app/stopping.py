"""How a run is stopped from outside: Ctrl-C or SIGTERM, and (a sweep's case on a Dask worker) its parent gone.

The first Ctrl-C / SIGTERM stops the run after the step under way, with a checkpoint; a second says that again;
a third ends it at once, as kill -9 would (exit 137, killed): the last checkpoint written is whole (each is
written aside, then renamed) and a resume cuts run.h5 back to it.

A Python signal handler runs only between bytecodes, and a Taichi kernel holds the interpreter while it runs: on
one CPU thread a step's substeps are one launch (seconds to minutes in a large scene), during which three Ctrl-C's
were one, handled when the step ended; the run said nothing until then, and nothing short of kill -9 ended it
sooner. So the signals are counted as they arrive by a small watcher process: Python's C-level handler writes a
byte to its wake-up pipe for each, and the watcher, reading the other end, says what happens at once and ends the
run on the third. The run's own handler sets ``sim.stop_requested`` when the interpreter is free again (the
Simulation stops before its next step). Without the watcher (it could not start) the handler does the talking.
"""
from __future__ import annotations

import contextlib
import os
import pathlib
import signal
import subprocess
import sys
import threading
import time as wallclock

from .callbacks.progress import log

SIGNALS = (signal.SIGINT, signal.SIGTERM)
#: the exit code of a run stopped by a signal (128 + SIGINT, as a shell reports one)
EXIT_INTERRUPTED = 130


def said(count: int, name: str, out_dir, kept: bool = False) -> str:
    """What the ``count``-th signal (``name``) does, as the run says it (``kept``: a checkpoint is on disk)."""
    if count == 1:
        return f"fbed: {name}: stopping after this step and writing a checkpoint (a third signal ends it at once)"
    if count == 2:
        return ("fbed: already stopping: the step under way ends first, then the checkpoint is written; signal "
                "again to end it at once (the last checkpoint written is kept, the steps since it are lost)")
    return "fbed: ending at once: " + (f"the last checkpoint is kept; resume with: fbed run --resume {out_dir}"
                                       if kept else "no checkpoint was written yet")


#: the watcher (python -S: the standard library only): a byte per signal from fd argv[1]; says what each does
#: (:func:`said`'s words in argv[4:]: the first, the second, the third with and without the checkpoint argv[3]);
#: SIGKILLs the run, pid argv[2], on the third. It reads on to the pipe's end whatever happens (a pipe with no
#: reader made each later signal an "Exception ignored" traceback in the run).
WATCHER = """
import os, signal, sys
fd, pid, checkpoint, words = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3], sys.argv[4:]
count = 0
while byte := os.read(fd, 1):
    if byte[0] in (signal.SIGINT, signal.SIGTERM) and count < 3:
        count += 1
        say = words[count - 1] if count < 3 else words[2 if os.path.exists(checkpoint) else 3]
        print(say.replace("{SIGNAL}", signal.Signals(byte[0]).name), file=sys.stderr, flush=True)
        if count == 3:
            os.kill(pid, signal.SIGKILL)
"""


class StopOnSignals:
    """While open (``with StopOnSignals(sim, out_dir):``), SIGINT and SIGTERM stop the run as the module says."""

    def __init__(self, sim, out_dir: pathlib.Path):
        self.sim, self.out_dir, self.count, self.watcher = sim, pathlib.Path(out_dir), 0, None

    def __enter__(self):
        self.old = {sig: signal.signal(sig, self._handle) for sig in SIGNALS}  # (no KeyboardInterrupt mid-write)
        read_end, self.write_end = os.pipe()
        d = self.out_dir
        try:
            words = [said(1, "{SIGNAL}", d), said(2, "", d), said(3, "", d, kept=True), said(3, "", d)]
            self.watcher = subprocess.Popen(  # its own session: the terminal's Ctrl-C goes to the run alone
                [sys.executable, "-S", "-c", WATCHER, str(read_end), str(os.getpid()), str(d / "checkpoint.h5"),
                 *words], pass_fds=(read_end,), start_new_session=True)
        except (OSError, ValueError):  # (no fork, or no pass_fds: Windows) the handler says what happens
            pass
        os.close(read_end)
        os.set_blocking(self.write_end, False)
        self.old_fd = signal.set_wakeup_fd(self.write_end, warn_on_full_buffer=False)
        return self

    def _handle(self, signum, frame) -> None:
        self.count += 1
        if self.watcher is None:
            log(said(self.count, signal.Signals(signum).name, self.out_dir,
                     (self.out_dir / "checkpoint.h5").exists()))
            if self.count >= 3:
                os._exit(EXIT_INTERRUPTED)
        if not self.sim.stop_requested:
            self.sim.stop_requested = signal.Signals(signum).name

    def __exit__(self, *exc) -> None:
        signal.set_wakeup_fd(self.old_fd)
        for sig, handler in self.old.items():
            signal.signal(sig, handler)
        os.close(self.write_end)  # the watcher reads the end of its pipe, and ends
        if self.watcher is not None:
            try:
                self.watcher.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.watcher.kill()


def watch_parent(sim) -> None:
    """With FBED_STOP_WITH_PARENT = the pid of the process that started this run (set by `fbed sweep` on a Dask
    worker), stop cleanly, with a checkpoint, once that process is gone (a worker killed): the case is rerun
    elsewhere, and this run must not go on writing into its folder."""
    try:  # the pid of the process that started this one (read here, it may already be gone)
        parent = int(os.environ.get("FBED_STOP_WITH_PARENT", ""))
    except ValueError:
        return

    def watch():
        while not sim.stop_requested:
            if os.getppid() != parent:
                log("fbed: the process that started this run is gone: stopping with a checkpoint")
                sim.stop_requested = "parent gone"
                return
            wallclock.sleep(1.0)

    threading.Thread(target=watch, daemon=True).start()


@contextlib.contextmanager
def signals_handled(handler):
    """``handler`` for Ctrl-C and SIGTERM while open, the handlers before it again after."""
    old = {sig: signal.signal(sig, handler) for sig in SIGNALS}
    try:
        yield
    finally:
        for sig, before in old.items():
            signal.signal(sig, before)

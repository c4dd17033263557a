"""The output folder of `fbed run`: which files are a run's (RUN_OUTPUTS), choosing and protecting the
folder (never mixing two runs' files; one that cannot be written refused before anything runs), the run's config
and folder from its arguments (:func:`configure`), the other commands' output folders (:func:`out_folder`), and
the stop on a full disk (the last good checkpoint kept)."""
from __future__ import annotations

import errno
import math
import os
import pathlib
import shutil
import tempfile
import time

try:
    import fcntl
except ImportError:  # not on a POSIX system: folders go unlocked
    fcntl = None

import h5py

from . import config as cfgmod
from .callbacks.progress import log, window_notes
from .config import ConfigError
from .io import store
from .resume import check_readable, check_records, check_recording, check_same_scene

EXIT_DISK_FULL = 3


# every file and folder `fbed run` writes into its output folder (the video under its configured name too):
# a folder holding any of them holds a run; --overwrite removes exactly these before the new run writes
RUN_OUTPUTS = ("run.h5", "run.xdmf", "particles.xdmf", "checkpoint.h5", "checkpoint.xdmf", "bed.h5", "bed.xdmf",
               "config.toml", "summary.json", "summary_units.json", "video.mp4", "analysis", "rcfd.h5", "rcfd")
RUN_OUTPUT_PATTERNS = ("*.tmp", "*.tmp.mp4", "*.before_resume.mp4", "screenshot-*.png")


def run_outputs(d: pathlib.Path, video_file: str = "") -> list[pathlib.Path]:
    """The fbed outputs present in folder ``d``: the video under its configured name too, if that is a file in
    ``d`` (a video named elsewhere is no sign of a run in ``d``, and --overwrite must never remove what lies
    outside it: ``video.file = '/data'`` once took the folder /data with it)."""
    video = pathlib.PurePath(video_file) if video_file else None
    inside = video is not None and not video.is_absolute() and ".." not in video.parts and (d / video).is_file()
    names = set(RUN_OUTPUTS) | ({video_file} if inside else set())
    found = [d / n for n in sorted(names) if (d / n).exists()]
    for pat in RUN_OUTPUT_PATTERNS:
        found += sorted(p for p in d.glob(pat) if p not in found)
    return found


def check_writable(d: pathlib.Path, key: str) -> None:
    """Refuse, before anything runs, an output folder that cannot be made or written in (a read-only or virtual
    file system, no permission): tried by making and removing an empty folder in it, or in its nearest existing
    parent."""
    a = d
    while not a.exists() and a != a.parent:
        a = a.parent
    try:
        if not a.is_dir():
            raise NotADirectoryError(errno.ENOTDIR, "a file is in the way", str(a))
        tempfile.TemporaryDirectory(dir=a, prefix=".fbed-").cleanup()
    except OSError as err:
        raise ConfigError(f"cannot make or write this folder ({err.strerror or err}: {a})", str(d), key,
                          hint="name a folder on a disk you can write to") from None


def out_folder(out: str | None, default: pathlib.Path, key: str = "--out") -> pathlib.Path:
    """A command's output folder (``out``, else ``default``), made now; one that cannot be made (a file in the way,
    a read-only or virtual file system, no permission) is a clean error naming it and ``key``."""
    d = pathlib.Path(out) if out else pathlib.Path(default)
    try:
        d.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        if store.is_disk_full(err):
            raise  # the CLI's full-disk stop
        raise ConfigError(f"cannot make or write this folder ({err.strerror or err})", str(d), key,
                          hint="name a folder on a disk you can write to") from None
    return d


#: flock's errors when another process holds the lock (any other: a file system without locks, the folder unheld)
HELD_ELSEWHERE = (errno.EAGAIN, errno.EWOULDBLOCK, errno.EACCES)
#: folders this process holds the lock of (a resolved path -> the open descriptor whose flock holds it)
_held: dict[str, int] = {}


def hold_folder(d: pathlib.Path, key: str) -> None:
    """This process's exclusive lock on a run folder, for as long as it runs there: a flock on the folder itself,
    released by :func:`release_folders` or when the process ends, however it ends. A folder another run holds is
    refused: before, `--resume` called that run's run.h5 damaged (HDF5's own lock) and `--overwrite` removed the
    live run's files and wrote beside it."""
    name = str(d.resolve())
    if fcntl is None or name in _held or not d.is_dir():
        return
    fd = os.open(d, os.O_RDONLY)
    wait = float(os.environ.get("FBED_LOCK_WAIT") or 0)  # s: a sweep's rerun on Dask waits for the orphan to stop
    deadline = time.monotonic() + wait
    while True:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            break
        except OSError as err:
            if err.errno not in HELD_ELSEWHERE:  # a file system without locks (ENOLCK): the folder goes unheld
                os.close(fd)
                return
            if time.monotonic() < deadline:
                time.sleep(0.5)
                continue
        os.close(fd)
        raise ConfigError("another run is writing into this folder (it holds the folder's lock)", str(d), key,
                          hint="wait for it to end, or stop it (Ctrl-C, or kill -TERM its process: it writes a "
                          "checkpoint), then resume; or give another --out") from None
    _held[name] = fd


def refuse_live_folder(d: pathlib.Path, key: str) -> None:
    """A folder another run holds is refused for reading too: `fbed analyze` on a live run failed for want of its
    summary.json, `fbed rcfd analyze` in a traceback (HDF5 could not lock the rcfd.h5 being written)."""
    if fcntl is None or str(d.resolve()) in _held or not d.is_dir():
        return
    fd = os.open(d, os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)  # released when fd closes
        return
    except OSError as err:
        if err.errno not in HELD_ELSEWHERE:
            return
    finally:
        os.close(fd)
    raise ConfigError("a run is still writing into this folder (it holds the folder's lock)", str(d), key,
                      hint="read it when that run ends (or stop it: Ctrl-C, or kill -TERM its process, writes a "
                      "checkpoint)")


def held_folders() -> frozenset:
    """The folders this process holds now (for :func:`release_folders`'s ``keep``)."""
    return frozenset(_held)


def release_folders(keep=()) -> None:
    """Let go of the folders this process holds, but those in ``keep`` (an outer run's, around a preparation)."""
    for name in [n for n in _held if n not in keep]:
        os.close(_held.pop(name))


def pick_out_dir(preset: pathlib.Path, out: str | None, overwrite: bool, video_file: str = "") -> pathlib.Path:
    if out:
        d = pathlib.Path(out)
        if d.exists() and not d.is_dir():
            raise ConfigError("is a file, not a folder", str(d), "--out", hint="name a folder (new or holding a run)")
        if d.exists():
            held = run_outputs(d, video_file)
            if held and not overwrite:
                raise ConfigError(f"already holds a run ({names(held)})", str(d), "--out",
                                  hint="pass --overwrite to replace it, --resume to continue it, or another --out")
        return d
    return fresh_folder(pathlib.Path("runs") / preset.stem)


def fresh_folder(base: pathlib.Path) -> pathlib.Path:
    """``base``, or base-2, base-3, ...: the first that does not exist or is empty (a default output folder never
    writes over an earlier run's)."""
    d, k = base, 1
    while d.exists() and any(d.iterdir()):
        k += 1
        d = base.with_name(f"{base.name}-{k}")
    return d


def names(paths: list[pathlib.Path]) -> str:
    """The first four of ``paths`` by name, for a message."""
    return ", ".join(p.name for p in paths[:4]) + (", ..." if len(paths) > 4 else "")


def remove_paths(paths: list[pathlib.Path]) -> None:
    """Files and folders removed (a link as a link, not what it points to)."""
    for p in paths:
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p)
        else:
            p.unlink()


def remove_outputs(d: pathlib.Path, video_file: str = "") -> None:
    """--overwrite: the old run's files go before the new run writes, so none of them is left beside it."""
    remove_paths(run_outputs(d, video_file))


def stop_disk_full(out_dir: pathlib.Path, summary: dict, err) -> int:
    """The run stopped on a full disk: say what it needed, keep what was written, and how to go on."""
    ckpt = out_dir / "checkpoint.h5"
    try:
        store.write_json(out_dir / "summary.json", summary)
    except store.DiskFull:
        log("fbed: summary.json not written either (no space)")
    for tmp in out_dir.glob("*.tmp"):
        tmp.unlink(missing_ok=True)
    log(f"fbed: stopped: {err}")
    if ckpt.exists():
        with h5py.File(ckpt, "r") as f:
            t = float(f.attrs["time"])
        if t >= summary.get("duration", math.inf) - 1e-9:  # the last file of a finished run failed (the video)
            log(f"fbed: the run reached its end (t = {t:.6g} s) and its checkpoint is kept; free some space and run "
                f"it again for {err.path.name if isinstance(err, store.DiskFull) else 'what was not written'}")
        else:
            log(f"fbed: the last good checkpoint (t = {t:.6g} s) is kept; free some space, then resume with: "
                f"fbed run --resume {out_dir}")
    else:
        log(f"fbed: no checkpoint was written yet; free some space (or give another --out) and run again")
    return EXIT_DISK_FULL


def configure(preset, overrides, out, resume, overwrite):
    """`fbed run`'s config, preset path, output folder and name, from its arguments (``resume``: the folder to go on
    from); errors here lose nothing: nothing is written yet."""
    if resume:
        out_dir = pathlib.Path(resume)
        if not out_dir.is_dir():
            raise ConfigError("not a folder" if out_dir.exists() else "no such folder", str(out_dir), "--resume",
                              hint="give the output folder of an earlier run")
        hold_folder(out_dir, "--resume")
        if not (out_dir / "checkpoint.h5").exists():
            raise ConfigError("no checkpoint.h5 to resume from", str(out_dir), "--resume",
                              hint="give the output folder of an earlier run that was stopped or finished")
        check_readable(out_dir)
        preset_path = pathlib.Path(preset) if preset else out_dir / "config.toml"
        if preset or preset_path.exists():
            cfg = cfgmod.load(preset_path, overrides)
        else:  # config.toml deleted: every checkpoint holds the resolved config it was written with
            cfg = cfgmod.load_text(checkpoint_config(out_dir), str(preset_path), overrides)
            log(f"fbed: note: {out_dir / 'config.toml'} is missing: the run's configuration is read from its "
                "checkpoint.h5 (and config.toml written again)")
        run_cfg = cfgmod.load(out_dir / "config.toml") if (out_dir / "config.toml").exists() else None
        if run_cfg is not None:
            check_same_scene(cfg, run_cfg, preset_path, out_dir)
            check_records(cfg, run_cfg, out_dir)
        check_recording(cfg, out_dir)
    else:
        if not preset:
            raise ConfigError("no preset given", "", "PRESET", hint="fbed run presets/settle.toml")
        preset_path = pathlib.Path(preset)
        cfg = cfgmod.load(preset_path, overrides)
        out_dir = pick_out_dir(preset_path, out, overwrite, cfg.video.file)
        hold_folder(out_dir, "--out")
    check_writable(out_dir, "--resume" if resume else "--out")
    if cfg.video.enabled:  # the video may be named outside the run's folder
        video = out_dir / (cfg.video.file or "video.mp4")
        if not out_dir.exists():  # 'new/../v.mp4' is no path until 'new' is made: the '..' taken as written
            video = pathlib.Path(os.path.normpath(video))
        if video.is_dir():
            raise ConfigError("is a folder, not a video file", str(video), "video.file",
                              hint="name an .mp4 file (relative to the output folder), or leave video.file out")
        if video.is_file() and not resume and not overwrite:  # (one inside the folder is a run's: refused above)
            raise ConfigError("already exists: a new run would write over it", str(video), "video.file",
                              hint="pass --overwrite to replace it, or name another video file")
        check_writable(video.parent, "video.file")
    for note in window_notes(cfg):
        log(note)
    if cfg.run.start_from and overrides and not resume:
        log(f"fbed: note: --set changes this stage only; the preparation {pathlib.Path(cfg.run.start_from).name} "
            "runs as its own preset says (edit it, or copy it and point run.start_from at the copy)")
    name = cfg.run.name or preset_path.stem
    if resume and not cfg.run.name:  # the name the run started with (its preset's), not the folder's
        name = started_name(out_dir) or (out_dir.name if preset_path.name == "config.toml" else name)
    return cfg, preset_path, out_dir, name


def checkpoint_config(out_dir: pathlib.Path) -> str:
    """The resolved config text a run's checkpoint.h5 was written with."""
    with h5py.File(out_dir / "checkpoint.h5", "r") as f:
        if "config" not in f.attrs:
            raise ConfigError("config.toml is missing, and checkpoint.h5 holds no config", str(out_dir), "--resume",
                              hint=f"name the run's preset: fbed run PRESET --resume {out_dir}")
        return str(f.attrs["config"])


def started_name(out_dir: pathlib.Path) -> str:
    """The name a run in ``out_dir`` was started under (run.h5's ``preset``), or "" where none is recorded."""
    try:
        with h5py.File(out_dir / "run.h5", "r") as f:
            return str(f.attrs.get("preset", ""))
    except OSError:
        return ""

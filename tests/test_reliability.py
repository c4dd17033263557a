"""The failures a user can meet: a full disk, a wrong resume, stale outputs, signals, damaged files.

Each runs `python -m app` in a fresh process (as a user would) on a small DEM-only scene and asserts the exit
code, the message, no traceback, no temporary file left, and that earlier outputs are intact. A full disk is
made two ways: a small tmpfs (where this machine lets root mount one) and an injected ENOSPC in HDF5's writes
(always), both mid-run and at the final checkpoint.
"""
import hashlib
import json
import os
import pathlib
import signal
import subprocess
import sys
import time

import h5py
import numpy as np
import pytest

pytestmark = pytest.mark.restart

ROOT = pathlib.Path(__file__).resolve().parents[1]
SETTLE = ROOT / "presets" / "settle.toml"
ENV = dict(os.environ, PYTHONPATH=str(ROOT))
TINY = ["--arch", "cpu", "--set", "particles.count=300", "--set", "run.threads=1", "--set", "run.step=1e-3"]

# the run, with h5py's dataset creation made to fail with ENOSPC on the Nth dataset NAME created in a file
# whose name ends with TARGET (the test's fault, injected from outside the code under test)
INJECT = """
import errno, os, sys, h5py
target, name, nth = os.environ["FAULT_TARGET"], os.environ["FAULT_NAME"], int(os.environ["FAULT_NTH"])
seen = [0]
real = h5py.Group.create_dataset
def create_dataset(self, key, *a, **k):
    if self.file.filename.endswith(target) and key == name:
        seen[0] += 1
        if seen[0] >= nth:
            raise OSError(errno.ENOSPC, "No space left on device")
    return real(self, key, *a, **k)
h5py.Group.create_dataset = create_dataset
from app.cli import main
sys.exit(main(sys.argv[1:]))
"""


def fbed(*args, cwd=None, env=None, inject=None):
    cmd = [sys.executable, "-c", INJECT] if inject else [sys.executable, "-m", "app"]
    e = dict(ENV, **(env or {}))
    if inject:
        e.update(FAULT_TARGET=inject[0], FAULT_NAME=inject[1], FAULT_NTH=str(inject[2]))
    return subprocess.run(cmd + [str(a) for a in args], capture_output=True, text=True, cwd=cwd or ROOT,
                          env=e, timeout=600)


def digest(d: pathlib.Path) -> dict:
    return {p.name: hashlib.sha1(p.read_bytes()).hexdigest() for p in sorted(d.iterdir()) if p.is_file()}


def assert_clean_stop(r, out: pathlib.Path, code: int, *needles):
    assert r.returncode == code, r.stderr[-3000:]
    assert "Traceback" not in r.stderr, r.stderr[-3000:]
    for n in needles:
        assert n in r.stderr, r.stderr[-3000:]
    assert not list(out.rglob("*.tmp")), list(out.rglob("*.tmp"))


def checkpoint_time(path: pathlib.Path) -> float:
    with h5py.File(path, "r") as f:  # readable: a good checkpoint, not a torn one
        assert f["grains/position"].shape == (300, 3)
        return float(f.attrs["time"])


# -- disk full


@pytest.fixture
def small_disk(tmp_path):
    """A 3 MB tmpfs (root may mount one on this machine and CI's; elsewhere the test skips and the injected
    ENOSPC tests below cover the same stops)."""
    disk = tmp_path / "disk"
    disk.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=3m", "tmpfs", str(disk)],
                      capture_output=True).returncode != 0:
        pytest.skip("mounting a tmpfs is not permitted here (the injected ENOSPC tests cover the same stop)")
    try:
        yield disk
    finally:
        subprocess.run(["umount", str(disk)], check=False)


def test_disk_full_at_the_final_checkpoint_on_a_small_tmpfs(small_disk):
    """A run to 10 ms, then the disk filled to leave the margin and 90 kB, then a resume to 12 ms: its final
    snapshot (8 kB of data) fits, its final checkpoint (137 kB) does not."""
    from app.io import store

    out = small_disk / "run"
    r = fbed("run", SETTLE, *TINY, "--set", "run.duration=0.01", "--set", "output.particles_interval=0",
             "--out", out)
    assert r.returncode == 0, r.stderr[-2000:]
    before = {name: (out / name).read_bytes() for name in ("checkpoint.h5", "bed.h5")}
    filler = small_disk / "filler"
    with open(filler, "wb") as f:
        f.write(b"\0" * (os.statvfs(small_disk).f_bavail * os.statvfs(small_disk).f_frsize
                         - store.SPACE_MARGIN - 90_000))
    r = fbed("run", "--resume", out, "--set", "run.duration=0.012")
    assert_clean_stop(r, out, 3, "the disk is full: writing checkpoint.h5 needed", "free on its disk",
                      "t = 0.01 s) is kept", "resume with: fbed run --resume")
    for name, data in before.items():  # the last good checkpoint and the earlier bed, byte for byte
        assert (out / name).read_bytes() == data
    assert checkpoint_time(out / "checkpoint.h5") == pytest.approx(0.01)
    with h5py.File(out / "run.h5", "r") as f:  # still readable, its final snapshot in
        assert float(f["particles"][str(len(f["particles"]) - 1)]["time"][()]) == pytest.approx(0.012)
    filler.unlink()  # with room again, the run goes on from the kept checkpoint
    r = fbed("run", "--resume", out, "--set", "run.duration=0.012")
    assert r.returncode == 0, r.stderr[-2000:]
    assert checkpoint_time(out / "checkpoint.h5") == pytest.approx(0.012)


def test_a_video_that_fills_the_disk_is_a_disk_full_and_leaves_no_torn_file(small_disk):
    """ffmpeg, finding the disk full, dies and the next frame meets a broken pipe: the video writer names it as
    every writer of a run does (store.DiskFull, which stops a run cleanly with its last checkpoint, exit 3) and
    removes the torn mp4; before, the BrokenPipe ended the run in a traceback. Noise frames do not compress."""
    pytest.importorskip("imageio_ffmpeg")
    from app.gui.video import VideoWriter
    from app.io import store

    w = VideoWriter(small_disk / "video.mp4", 30, notify=lambda msg: None)
    rng = np.random.default_rng(0)
    with pytest.raises(store.DiskFull) as err:
        for _ in range(400):  # 400 x 197 kB raw: far beyond 3 MB even at libx264's compression of noise
            w.write(rng.integers(0, 255, (256, 256, 3), dtype=np.uint8))
        w.close()
    assert "the disk is full: writing video.mp4" in str(err.value)
    assert not (small_disk / "video.mp4").exists()
    w.close()  # closing again after the failure raises nothing


def test_an_mp4_is_whole_only_with_its_index_and_every_byte(tmp_path):
    """`mp4_complete`, which tells a finished video from one an encoder left torn (neither imageio-ffmpeg nor OpenCV
    reports ffmpeg's failure at its end): a file the writer finished is whole; the same file cut at any box edge or
    inside a box, or with its index box's type changed, is not."""
    pytest.importorskip("imageio_ffmpeg")
    from app.gui.video import VideoWriter, mp4_complete

    path = tmp_path / "video.mp4"
    w = VideoWriter(path, 10, notify=lambda msg: None)
    rng = np.random.default_rng(1)
    for _ in range(6):
        w.write(rng.integers(0, 255, (64, 96, 3), dtype=np.uint8))
    w.close()
    data = path.read_bytes()
    assert mp4_complete(path) and b"moov" in data
    cut = tmp_path / "cut.mp4"
    moov = data.index(b"moov") - 4
    for n in (8, 40, 48, len(data) // 2, moov, moov + 8, len(data) - 1):
        cut.write_bytes(data[:n])
        assert not mp4_complete(cut), n
    cut.write_bytes(data[:moov + 4] + b"free" + data[moov + 8:])
    assert not mp4_complete(cut)
    cut.write_bytes(data + b"\0" * 3)  # trailing bytes that are no box
    assert not mp4_complete(cut)


def test_a_video_whose_end_finds_the_disk_full_stops_the_run_and_leaves_no_torn_file(small_disk, gui):
    """The video named on a tmpfs left with 4 kB: ffmpeg fails only as it writes the file's end, and says so on
    stderr, but its exit status is not read (imageio-ffmpeg). Before, the run said "done" (exit 0) and left a torn
    4 kB video.mp4 with no index. Now it is a full disk like any other (exit 3, summary.json's status), the torn
    file is gone, the run's own folder is complete, and the advice is to run again, not to resume a run at its end."""
    pytest.importorskip("imageio_ffmpeg")
    video = small_disk / "video.mp4"
    preset = small_disk.parent / "drop.toml"
    preset.write_text(SETTLE.read_text().replace("[run]", f"[video]\nfile = \"{video}\"\nwidth = 160\n"
                                                  "height = 120\ninterval = 0.005\n\n[run]", 1))
    with open(small_disk / "filler", "wb") as f:
        f.write(b"\0" * (os.statvfs(small_disk).f_bavail * os.statvfs(small_disk).f_frsize - 4096))
    out = small_disk.parent / "run"
    r = fbed("run", preset, *TINY, "--set", "run.duration=0.02", "--video", "--out", out)
    assert_clean_stop(r, out, 3, "the disk is full: writing video.mp4 had", "the run reached its end (t = 0.02 s)",
                      "run it again for video.mp4")
    assert not video.exists()
    assert checkpoint_time(out / "checkpoint.h5") == pytest.approx(0.02)
    assert json.loads((out / "summary.json").read_text())["status"] == "disk_full"


def test_disk_full_mid_run_on_a_small_tmpfs(small_disk):
    out = small_disk / "run"
    # a snapshot every step (about 40 kB of run.h5 each) fills 3 MB within a few dozen steps; a checkpoint
    # every 5 steps leaves a good one behind
    r = fbed("run", SETTLE, *TINY, "--set", "run.duration=1", "--set", "output.particles_interval=1e-3",
             "--set", "output.checkpoint_interval=5e-3", "--out", out)
    assert_clean_stop(r, out, 3, "the disk is full", "needed", "MB", "the last good checkpoint")
    t = checkpoint_time(out / "checkpoint.h5")
    assert 0 < t < 1
    assert (out / "config.toml").read_text().startswith("# fbed resolved configuration")
    with h5py.File(out / "run.h5", "r") as f:  # run.h5 still opens: its series reach the checkpoint
        assert f["series/time"][-1] >= t - 1e-9


def test_disk_full_mid_run_injected(tmp_path):
    out = tmp_path / "run"
    r = fbed("run", SETTLE, *TINY, "--set", "run.duration=0.05", "--set", "output.particles_interval=1e-3",
             "--set", "output.checkpoint_interval=5e-3", "--out", out, inject=("run.h5", "position", 12))
    assert_clean_stop(r, out, 3, "the disk is full: writing run.h5 needed", "the last good checkpoint")
    t = checkpoint_time(out / "checkpoint.h5")
    assert 0 < t < 0.05
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "disk_full" and "run.h5" in s["message"]
    with h5py.File(out / "run.h5", "r") as f:  # the failed snapshot left no empty group behind
        snaps = f["particles"]
        assert len(snaps) == 11 and all("position" in snaps[k] for k in snaps)
    # run.xdmf as of the last checkpoint (written with each one): it names only snapshots run.h5 holds
    xml = (out / "run.xdmf").read_text()
    assert "/particles/10/position" in xml and "/particles/11/" not in xml
    # the kept checkpoint resumes once there is room again
    r = fbed("run", "--resume", out, "--set", "run.duration=0.03")
    assert r.returncode == 0, r.stderr[-2000:]
    assert json.loads((out / "summary.json").read_text())["status"] == "finished"


def test_disk_full_in_the_rcfd_probes_writer_thread_injected(tmp_path):
    """The rCFD probe hands its appends to rcfd.h5 to a writer thread: a full disk there (injected at its first
    boundary, 20 ms) stops the run cleanly at the next checkpoint or boundary with the run's disk-full message and
    exit code, keeps the last checkpoint, and leaves rcfd.h5 readable (before the probe's writes turned ENOSPC into
    the run's stop, it ended with a traceback)."""
    out = tmp_path / "run"
    r = fbed("run", ROOT / "presets" / "rcfd_small.toml", "--arch", "cpu", "--set", "run.duration=0.04",
             "--set", "probes.rcfd_from=0.02", "--set", "output.checkpoint_interval=0.01",
             # no checkpoint on the wall clock: on a loaded machine (a cold compile past 30 s) one came at 21 ms
             "--set", "output.checkpoint_wall_interval=0", "--out", out,
             inject=("rcfd.h5", "grains_counted", 1))
    assert_clean_stop(r, out, 3, "the disk is full: writing rcfd.h5 needed", "the last good checkpoint")
    # a checkpoint waits for rcfd.h5's appends (it saves the probe's open frame with rcfd.h5 as it stands): the
    # failure shows at the 20 ms checkpoint, which is not written, and the 10 ms one is kept; a resume from it
    # records from 20 ms anew (rcfd.h5 holds no boundary). (Before, the 20 ms checkpoint was written over a
    # boundary rcfd.h5 did not hold, and the failure showed at 25 ms.)
    with h5py.File(out / "checkpoint.h5", "r") as f:
        assert float(f.attrs["time"]) == pytest.approx(0.01, abs=1e-9)
    with h5py.File(out / "rcfd.h5", "r") as f:
        assert "grains_counted" not in f and f["boundary/time"].shape[0] == 0


def test_disk_full_at_the_final_checkpoint_injected(tmp_path):
    out = tmp_path / "run"
    # checkpoints at 5 and 10 ms, then the final one at 12 ms fails
    r = fbed("run", SETTLE, *TINY, "--set", "run.duration=0.012", "--set", "output.checkpoint_interval=5e-3",
             "--out", out, inject=("checkpoint.h5.tmp", "position", 3))
    assert_clean_stop(r, out, 3, "the disk is full: writing checkpoint.h5 needed", "t = 0.01 s) is kept")
    assert checkpoint_time(out / "checkpoint.h5") == pytest.approx(0.01)
    assert not (out / "bed.h5").exists()  # the final outputs stop at the first that fails
    assert json.loads((out / "summary.json").read_text())["status"] == "disk_full"


# -- resume, output protection, damaged files


@pytest.fixture(scope="module")
def done_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("done") / "run"
    r = fbed("run", SETTLE, *TINY, "--set", "run.duration=0.005", "--out", out)
    assert r.returncode == 0, r.stderr
    return out


def test_resume_with_another_scene_is_refused_and_touches_nothing(done_run, tmp_path):
    before = digest(done_run)
    r = fbed("run", ROOT / "presets" / "fluidize.toml", "--resume", done_run)
    assert_clean_stop(r, done_run, 2, "scene differs from the run's", "particles.count", "[gas]")
    r = fbed("run", "--resume", done_run, "--set", "contact.friction=0.1")
    assert_clean_stop(r, done_run, 2, "contact.friction: 0.1 here, 0.3 in the run")
    assert digest(done_run) == before


@pytest.mark.parametrize("record, key, value", [("mri", "mri_pixel", "[0.004, 0.008]"), ("mri", "slab_width", "0.012"),
                                                ("slab", "slab_width", "0.012")])
def test_a_resume_that_changes_a_records_layout_is_refused_and_touches_nothing(tmp_path, record, key, value):
    """run.h5's /mri and /slab frames have the layout their [probes] keys gave: a resume with another probes.mri_pixel
    had HDF5 cut the first leg's 12 x 24 MRI frames to 6 x 12 and append the new ones, silently (mri_small). Now it
    is refused before anything is written, naming the key, run.h5 and both values (a run folder made here: the
    run's config.toml, a checkpoint's attributes and one frame of the record)."""
    from app import config as cfgmod

    d = tmp_path / "run"
    d.mkdir()
    (d / "config.toml").write_text(cfgmod.dump(cfgmod.load(ROOT / "presets" / "mri_small.toml")))
    with h5py.File(d / "checkpoint.h5", "w") as f:
        f.attrs.update(time=0.004, step=4)
    with h5py.File(d / "run.h5", "w") as f:
        f.create_dataset(f"{record}/time", data=[0.004])
        f.create_dataset(f"{record}/porosity", data=np.ones((1, 12, 24), np.float32))
    before = digest(d)
    r = fbed("run", "--resume", d, "--set", f"probes.{key}={value}", "--arch", "cpu")
    assert_clean_stop(r, d, 2, f"run.h5: probes.{key}: probes.{key} = {value} here", f"whose /{record} frames",
                      "drop the --set")
    assert digest(d) == before


def test_a_frame_of_another_shape_is_not_appended_to_a_record(tmp_path):
    """The store's own guard under the resume check: h5py resizes a dataset to any shape within its maximum, so a
    frame of another shape would cut the record's earlier frames; it is refused, naming the record and both shapes."""
    from app.io import store

    rf = store.RunFile(tmp_path / "run.h5", "t")
    rf.frame("mri", 0.004, np.ones((12, 24)))
    rf.flush()
    rf.frame("mri", 0.008, np.ones((6, 12)))
    with pytest.raises(ValueError, match=r"/mri/porosity holds frames of shape \(12, 24\), not \(6, 12\)"):
        rf.flush()
    with h5py.File(tmp_path / "run.h5", "r") as f:
        assert f["mri/porosity"].shape == (1, 12, 24)


def test_a_resume_under_other_code_says_so(done_run, tmp_path):
    """A checkpoint keeps the fingerprint of the code that wrote it (app/provenance.py). A resume under other code
    (fbed upgraded or edited between the legs) goes on, and says that the result is not the straight run's; under
    the same code it says nothing of it."""
    import shutil

    d = tmp_path / "run"
    shutil.copytree(done_run, d)
    with h5py.File(d / "checkpoint.h5", "r") as f:  # the run's summary names the same code as its checkpoint
        assert json.loads((d / "summary.json").read_text())["fbed_code"] == f.attrs["fbed_code"]
    r = fbed("run", "--resume", d, "--set", "run.duration=0.006")
    assert r.returncode == 0 and "other fbed code" not in r.stderr, r.stderr
    with h5py.File(d / "checkpoint.h5", "r+") as f:
        f.attrs["fbed_code"] = "0123456789ab"
    r = fbed("run", "--resume", d, "--set", "run.duration=0.007")
    assert r.returncode == 0, r.stderr
    assert "was written by other fbed code (0123456789ab" in r.stderr and "not bit for bit" in r.stderr


def test_a_run_whose_config_toml_was_deleted_resumes_from_its_checkpoints_config(done_run, tmp_path):
    """config.toml gone (deleted by hand, or a copy of the folder without it): the checkpoint holds the resolved
    config it was written with, so `--resume DIR` goes on from it, says so and writes config.toml again; the
    result is the one a run straight to the same end gives, bit for bit (one CPU thread). Before, it was refused
    as "no such preset file" with nothing to suggest."""
    import shutil

    d = tmp_path / "run"
    shutil.copytree(done_run, d)
    (d / "config.toml").unlink()
    r = fbed("run", "--resume", d, "--set", "run.duration=0.01")
    assert r.returncode == 0 and "config.toml is missing: the run's configuration is read from its checkpoint.h5" \
        in r.stderr, r.stderr
    assert (d / "config.toml").read_text() == (done_run / "config.toml").read_text().replace(
        "duration = 0.005", "duration = 0.01")
    straight = tmp_path / "straight"
    assert fbed("run", SETTLE, *TINY, "--set", "run.duration=0.01", "--out", straight).returncode == 0
    with h5py.File(d / "checkpoint.h5", "r") as a, h5py.File(straight / "checkpoint.h5", "r") as b:
        assert float(a.attrs["time"]) == pytest.approx(0.01)
        for k in ("position", "velocity"):
            assert np.array_equal(a["grains"][k][...], b["grains"][k][...]), k
    with h5py.File(d / "checkpoint.h5", "r+") as f:  # a checkpoint without its config (none is written so)
        del f.attrs["config"]
    (d / "config.toml").unlink()
    r = fbed("run", "--resume", d, "--set", "run.duration=0.02")
    assert_clean_stop(r, d, 2, "config.toml is missing, and checkpoint.h5 holds no config",
                      f"fbed run PRESET --resume {d}")


def test_analyze_with_a_kind_the_run_cannot_give_changes_nothing(done_run):
    """`fbed analyze DIR --kind mri` on a run that recorded no MRI frames: exit 2 with the reason, and the run's
    files as they were. Before, the failure was written into its summary.json (analysis_error) and the message
    advised to rerun `fbed analyze DIR`, the command just given."""
    before = digest(done_run)
    for kind, said in (("mri", "run.h5 holds neither /mri nor /slab"), ("boyce", "the preset has no jet")):
        r = fbed("analyze", done_run, "--kind", kind)
        assert_clean_stop(r, done_run, 2, f"the {kind} analysis failed", said)
        assert "rerun it" not in r.stderr
    assert digest(done_run) == before and not (done_run / "analysis").exists()


def test_output_protection_covers_every_fbed_file(done_run, tmp_path):
    d = tmp_path / "old"
    d.mkdir()
    for name in ("bed.h5", "summary.json"):  # a folder with fbed files but no run.h5
        (d / name).write_bytes((done_run / name).read_bytes())
    before = digest(d)
    r = fbed("run", SETTLE, *TINY, "--set", "run.duration=0.002", "--out", d)
    assert_clean_stop(r, d, 2, "already holds a run", "bed.h5", "--overwrite")
    assert digest(d) == before
    # --overwrite removes the old run's files first: no stale video or analysis beside the new run
    (d / "video.mp4").write_bytes(b"old")
    (d / "analysis").mkdir()
    (d / "analysis" / "bubble.png").write_bytes(b"old")
    (d / "notes.txt").write_text("mine")  # not fbed's: kept
    r = fbed("run", SETTLE, *TINY, "--set", "run.duration=0.002", "--out", d, "--overwrite")
    assert r.returncode == 0, r.stderr
    assert not (d / "video.mp4").exists() and not (d / "analysis").exists()
    assert (d / "notes.txt").read_text() == "mine"
    assert json.loads((d / "summary.json").read_text())["time"] == pytest.approx(0.002)


def test_overwrite_never_removes_what_video_file_names_outside_the_run(done_run, tmp_path):
    """`video.file` is relative to the output folder, and --overwrite removed the old run's video under that name:
    `--set video.file=/data` (a folder) removed /data with everything in it, the output folder included, before
    the run failed with a traceback. Now video.file must name an .mp4 file, a folder in its place is refused, and
    --overwrite removes a video only inside the run's folder."""
    top = tmp_path / "data"
    d = top / "run"
    d.mkdir(parents=True)
    (top / "precious.txt").write_text("mine")
    (d / "bed.h5").write_bytes((done_run / "bed.h5").read_bytes())
    before = digest(top), digest(d)
    from app.config import ConfigError, load

    for value in ("..", "v.gif", "../data.mp4/"):  # refused with the preset (the same rule as the case below)
        with pytest.raises(ConfigError, match="not an .mp4 file's name") as err:
            load(SETTLE, ["video.enabled=true", f"video.file={value}"])
        assert err.value.key == "video.file" and "bubble.mp4" in err.value.hint
    r = fbed("run", SETTLE, *TINY, "--video", "--set", f"video.file={top}", "--out", d, "--overwrite")
    assert_clean_stop(r, top, 2, "not an .mp4 file's name", "video.file", "bubble.mp4")
    assert (digest(top), digest(d)) == before
    (top / "folder.mp4").mkdir()
    r = fbed("run", SETTLE, *TINY, "--video", "--set", "video.file=../folder.mp4", "--out", d, "--overwrite")
    assert_clean_stop(r, top, 2, "is a folder, not a video file", "video.file")
    assert (top / "folder.mp4").is_dir() and (d / "bed.h5").exists()
    # a video named outside the folder, the video off: the old run in d is replaced, the file outside kept
    (top / "mine.mp4").write_bytes(b"not fbed's")
    r = fbed("run", SETTLE, *TINY, "--set", "run.duration=0.002", "--set", "video.file=../mine.mp4", "--out", d,
             "--overwrite")
    assert r.returncode == 0, r.stderr
    assert (top / "mine.mp4").read_bytes() == b"not fbed's" and (top / "precious.txt").read_text() == "mine"
    assert json.loads((d / "summary.json").read_text())["time"] == pytest.approx(0.002)

def test_out_naming_a_file_and_a_damaged_run_h5_are_refused(done_run, tmp_path):
    f = tmp_path / "afile"
    f.write_text("x")
    r = fbed("run", SETTLE, *TINY, "--out", f)
    assert_clean_stop(r, tmp_path, 2, "is a file, not a folder", "--out")
    assert f.read_text() == "x"
    d = tmp_path / "damaged"
    d.mkdir()
    for p in done_run.iterdir():
        if p.is_file():
            (d / p.name).write_bytes(p.read_bytes())
    (d / "run.h5").write_bytes((d / "run.h5").read_bytes()[:3000])  # cut short, as by a crash of the disk
    before = digest(d)
    r = fbed("run", "--resume", d, "--set", "run.duration=0.01")
    assert_clean_stop(r, d, 2, "run.h5 is damaged", "--resume")
    assert digest(d) == before


def test_an_out_folder_that_cannot_be_written_is_refused_before_anything_runs(tmp_path):
    """Before the kernels compile and the grains are placed: an --out under a file, or on a file system where no
    folder can be made (/proc), is refused with the folder and the OS's reason, exit 2, no traceback, nothing made."""
    blocker = tmp_path / "afile"
    blocker.write_text("x")
    r = fbed("run", SETTLE, *TINY, "--out", blocker / "run")
    assert_clean_stop(r, tmp_path, 2, "cannot make or write this folder", "a file is in the way", "--out")
    assert blocker.read_text() == "x" and sorted(p.name for p in tmp_path.iterdir()) == ["afile"]
    if pathlib.Path("/proc").is_dir():  # Linux: mkdir under /proc fails whoever runs it (root included)
        r = fbed("run", SETTLE, *TINY, "--out", "/proc/fbed-run")
        assert_clean_stop(r, tmp_path, 2, "cannot make or write this folder", "/proc/fbed-run", "--out")
        r = fbed("run", SETTLE, *TINY, "--video", "/proc/fbed.mp4", "--out", tmp_path / "v")  # a video named outside
        assert_clean_stop(r, tmp_path, 2, "cannot make or write this folder", "video.file")  # (ffmpeg failed late)
    for cmd in (["sweep", SETTLE, "--set", "particles.count=100,200"], ["bench", "stress"]):  # the other commands
        r = fbed(*cmd, "--out", blocker / "x")
        assert_clean_stop(r, tmp_path, 2, "cannot make or write this folder", "--out")
    assert blocker.read_text() == "x" and sorted(p.name for p in tmp_path.iterdir()) == ["afile"]


def test_initial_state_of_other_sizes_is_refused_with_both_sizes(done_run, tmp_path):
    preset = tmp_path / "big.toml"
    text = SETTLE.read_text().replace("count = 2500", f'initial_state = "{done_run / "bed.h5"}"')
    preset.write_text(text.replace("diameter = 2.0e-3", "diameter = 3.0e-3"))
    assert "diameter = 3.0e-3" in preset.read_text()
    r = fbed("run", preset, "--arch", "cpu", "--out", tmp_path / "o")
    assert_clean_stop(r, tmp_path, 2, "the bed's grains have diameters 0.002", "the preset's 0.003",
                      "particles.initial_state")


def test_initial_state_with_non_finite_or_misshapen_grains_is_refused_naming_the_first(done_run, tmp_path):
    """A bed.h5 damaged or made by hand: a NaN position ran, and the guard stopped the run at t = 0 as unstable
    ("contacts are too soft or the step too long", exit 3), pointing at the wrong knobs. Now it is refused at the
    start (exit 2), naming the dataset, how many grains and the first of them; so are a zero radius and arrays of
    mismatched lengths. The untouched bed runs."""
    import shutil

    def run_with(edit):
        bed = tmp_path / "bed.h5"
        shutil.copy(done_run / "bed.h5", bed)
        with h5py.File(bed, "r+") as f:
            edit(f["grains"])
        preset = tmp_path / "from_bed.toml"
        preset.write_text(SETTLE.read_text().replace("count = 2500", f'initial_state = "{bed}"'))
        return fbed("run", preset, "--arch", "cpu", "--set", "run.duration=0.002", "--out", tmp_path / "o",
                    "--overwrite")

    def nan_at(name, i):
        def edit(g):
            a = g[name][...]
            a[i] = np.nan
            g[name][...] = a
        return edit

    def replace(name, value):
        def edit(g):
            del g[name]
            g[name] = value
        return edit

    for edit, said in ((nan_at("position", 7), "/grains/position is not finite for 1 grain(s) (the first: grain 7)"),
                       (nan_at("velocity", 3), "/grains/velocity is not finite for 1 grain(s) (the first: grain 3)"),
                       (replace("radius", np.r_[0.0, np.full(299, 1e-3)]), "/grains/radius is not finite and "
                        "positive for 1 grain(s) (the first: grain 0)"),
                       (replace("velocity", np.zeros((299, 3))), "/grains/velocity has shape (299, 3), not (300, 3)")):
        r = run_with(edit)
        assert_clean_stop(r, tmp_path, 2, "particles.initial_state: cannot use the grains in it", said)
    assert run_with(lambda g: None).returncode == 0


def test_grains_outside_the_domain_at_the_start_are_noted_and_counted_at_the_end(done_run, tmp_path):
    """A bed from a taller box run in a lower one: the DEM removes the grains outside the domain at its first
    substep, which ran without a word (the run said "300 grains" and "done"; only summary.json's grains_removed
    knew). Now the start says how many lie outside (exactly those above domain.hi, counted from the bed itself)
    and the end how many were removed, at least those (grains still moving just below the cut may follow them out,
    through the open top)."""
    with h5py.File(done_run / "bed.h5", "r") as f:
        z = f["grains/position"][:, 2]
    top = float(np.median(z))
    above = int((z > top).sum())
    preset = tmp_path / "low.toml"
    preset.write_text(SETTLE.read_text().replace("count = 2500", f'initial_state = "{done_run / "bed.h5"}"')
                      .replace("hi = [0.016, 0.016, 0.12]", f"hi = [0.016, 0.016, {top!r}]"))
    r = fbed("run", preset, "--arch", "cpu", "--set", "run.duration=0.002", "--out", tmp_path / "o")
    assert r.returncode == 0 and 0 < above < 300, r.stderr
    assert f"note: {above} of the 300 grains lie outside the domain" in r.stderr, r.stderr
    removed = json.loads((tmp_path / "o" / "summary.json").read_text())["grains_removed"]
    assert above <= removed < 300 and f"; {removed} grains left the domain and were removed" in r.stderr
    r = fbed("run", SETTLE, *TINY, "--set", "run.duration=0.002", "--out", tmp_path / "fill")
    assert r.returncode == 0 and "outside the domain" not in r.stderr and "left the domain" not in r.stderr


def test_a_bed_from_a_wider_vessel_is_refused_naming_the_misfit(done_run, tmp_path):
    """settle's bed (a 15 mm cylinder) in a 10 mm one: grains cut through the wall, and the guard stopped the run
    at t = 0 ("overlap by 241% of a diameter ... contacts are too soft or the step too long"), naming knobs that
    cannot help. Now the start refuses it (exit 2) with the grains beyond guard.max_overlap counted; the bed in
    its own vessel, where grains rest on the wall by far less, runs."""
    with h5py.File(done_run / "bed.h5", "r") as f:
        x = f["grains/position"][...]
        r = f["grains/radius"][...]
    clearance = 0.010 - np.hypot(x[:, 0], x[:, 1])  # to a 10 mm cylinder on the axis
    deep = int(((r - clearance) / (2 * r) > 0.2).sum())
    text = SETTLE.read_text().replace("count = 2500", f'initial_state = "{done_run / "bed.h5"}"')
    narrow = tmp_path / "narrow.toml"
    narrow.write_text(text.replace("radius = 0.015 ", "radius = 0.010 "))
    r = fbed("run", narrow, "--arch", "cpu", "--set", "run.duration=0.002", "--out", tmp_path / "o")
    assert 0 < deep < 300
    assert_clean_stop(r, tmp_path, 2, f"{deep} of the bed's 300 grains overlap the vessel's walls by more than "
                      "guard.max_overlap = 0.2", "the bed does not fit this vessel", "particles.initial_state")
    own = tmp_path / "own.toml"
    own.write_text(text)
    assert fbed("run", own, "--arch", "cpu", "--set", "run.duration=0.002", "--out", tmp_path / "o2").returncode == 0


# -- signals and schedules


def test_a_second_signal_waits_for_the_checkpoint(tmp_path):
    out = tmp_path / "run"
    p = subprocess.Popen([sys.executable, "-m", "app", "run", str(SETTLE), *TINY, "--set", "run.duration=100",
                          "--out", str(out)], stderr=subprocess.PIPE, text=True, env=ENV, cwd=ROOT)
    deadline = time.time() + 300
    while time.time() < deadline and not (out / "run.h5").exists():
        time.sleep(0.2)
    time.sleep(2)
    p.send_signal(signal.SIGINT)
    time.sleep(0.05)
    p.send_signal(signal.SIGINT)
    _, err = p.communicate(timeout=300)
    assert p.returncode == 130, err[-2000:]
    assert "Traceback" not in err and "resume with: fbed run --resume" in err
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "interrupted"
    assert checkpoint_time(out / "checkpoint.h5") == pytest.approx(s["time"])
    assert not list(out.glob("*.tmp"))


def test_a_third_signal_ends_the_run_at_once_mid_step_and_the_last_checkpoint_resumes(tmp_path):
    """On one CPU thread a step's substeps are one kernel launch, which holds the interpreter: steps of 1 s here
    (129,429 substeps, seconds each). Three Ctrl-C's during one were one, handled when the step ended, and the run
    said nothing until then. Each is now seen as it arrives (app.stopping's watcher): the first and second are
    answered at once, the third ends the run (killed, as kill -9) well before the step could end, and the
    checkpoint it had written resumes."""
    out, log = tmp_path / "run", tmp_path / "err.txt"
    with open(log, "w") as errf:
        p = subprocess.Popen([sys.executable, "-m", "app", "run", str(SETTLE), *TINY, "--set", "run.step=1",
                              "--set", "run.duration=100", "--set", "output.checkpoint_interval=1",
                              "--set", "output.particles_interval=1", "--set", "output.series_interval=1",
                              "--out", str(out)], stderr=errf, text=True, env=ENV, cwd=ROOT)
        try:
            deadline = time.time() + 300
            while time.time() < deadline and "kernels ready" not in log.read_text():
                time.sleep(0.1)
            # the line is written between steps, a few ms before the next step's launch: a signal sent at once could
            # land there on a loaded machine (CI saw it: the run stopped after that step, and the second signal
            # found Python's default handler back, exit -2), so the signals wait until that step is under way
            time.sleep(0.5)
            t0 = time.time()
            for _ in range(3):
                p.send_signal(signal.SIGINT)
                time.sleep(0.2)
            p.wait(timeout=300)
            quit_after = time.time() - t0
        finally:
            if p.poll() is None:
                p.kill()
    err = log.read_text()
    assert p.returncode == -signal.SIGKILL and "Traceback" not in err, err[-2000:]
    assert "SIGINT: stopping after this step" in err and "already stopping: the step under way ends first" in err
    assert "ending at once: the last checkpoint is kept" in err and "stopped by SIGINT" not in err, err[-2000:]
    assert quit_after < 2.0, quit_after  # a step here takes 3 s or more; the second signal came 0.2 s after the first
    t = checkpoint_time(out / "checkpoint.h5")
    r = fbed("run", "--resume", out, "--set", f"run.duration={t + 1}")
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr[-2000:]
    with h5py.File(out / "run.h5") as f:
        assert f["series/time"][-1] == pytest.approx(t + 1)


def test_an_output_folder_removed_mid_run_stops_it_cleanly(tmp_path):
    """The run's folder moved away (then deleted) while it runs: its next checkpoint cannot be written. Before,
    that was a FileNotFoundError traceback (exit 1); now the run stops at once with exit 3 and says the folder is
    gone, and what to do (run again; a folder that was moved holds the run up to its last checkpoint). Moved, not
    deleted in place: a delete races with the run's own next file (CI saw "Directory not empty")."""
    out = tmp_path / "run"
    p = subprocess.Popen([sys.executable, "-m", "app", "run", str(SETTLE), *TINY, "--set", "run.duration=100",
                          "--set", "output.checkpoint_interval=0.01", "--out", str(out)], stderr=subprocess.PIPE,
                         text=True, env=ENV, cwd=ROOT)
    deadline = time.time() + 300
    while time.time() < deadline and not (out / "checkpoint.h5").exists():
        time.sleep(0.2)
    out.rename(tmp_path / "moved")
    _, err = p.communicate(timeout=300)
    assert p.returncode == 3 and "Traceback" not in err, err[-3000:]
    assert f"the output folder {out} is gone (removed or moved while the run wrote into it)" in err
    assert "run it again" in err and not out.exists()
    assert checkpoint_time(tmp_path / "moved" / "checkpoint.h5") > 0  # the moved folder keeps its last checkpoint


def test_a_folder_another_run_is_writing_into_is_refused(tmp_path):
    """While a run is writing into its folder, `--resume DIR` said its run.h5 "is damaged" (HDF5's lock) and
    advised moving it aside, and `--out DIR --overwrite` removed the live run's files and ran beside it. The
    running run now holds a lock on its folder: both are refused (exit 2) and its files stay; once it has
    stopped (SIGTERM: a checkpoint), the resume goes on."""
    out = tmp_path / "run"
    p = subprocess.Popen([sys.executable, "-m", "app", "run", str(SETTLE), *TINY, "--set", "run.duration=100",
                          "--out", str(out)], stderr=subprocess.PIPE, text=True, env=ENV, cwd=ROOT)
    try:
        deadline = time.time() + 300
        while time.time() < deadline and not (out / "run.h5").exists():
            time.sleep(0.2)
        for args in (["--resume", out], [SETTLE, *TINY, "--out", out, "--overwrite"]):
            r = fbed("run", *args, "--set", "run.duration=200")
            assert_clean_stop(r, out, 2, "another run is writing into this folder")
            assert "damaged" not in r.stderr and (out / "run.h5").exists() and (out / "config.toml").exists()
        p.send_signal(signal.SIGTERM)
        _, err = p.communicate(timeout=300)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == 130, err[-2000:]
    t = checkpoint_time(out / "checkpoint.h5")
    r = fbed("run", "--resume", out, "--set", f"run.duration={t + 0.002!r}")
    assert r.returncode == 0, r.stderr[-2000:]


def test_a_folder_a_run_is_writing_into_is_not_analyzed(tmp_path, capsys):
    """`fbed analyze` on a live run failed for want of its summary.json (the analysis said "failed" with a
    FileNotFoundError); `fbed rcfd analyze|run` stopped in a traceback (HDF5 could not lock the rcfd.h5 being
    written). A folder another process holds is now refused (exit 2), naming it; once let go, it is read."""
    import fcntl

    from app.cli import main as cli_main

    d = tmp_path / "live"
    d.mkdir()
    for name in ("run.h5", "config.toml", "rcfd.h5"):
        (d / name).write_bytes(b"")
    fd = os.open(d, os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)  # as a live run holds its folder (outputs.hold_folder)
        for argv in (["analyze", str(d)], ["rcfd", "analyze", str(d)], ["rcfd", "run", str(d)]):
            assert cli_main(argv) == 2
            err = capsys.readouterr().err
            assert "a run is still writing into this folder" in err and "Traceback" not in err, err
    finally:
        os.close(fd)
    assert cli_main(["analyze", str(d)]) == 2  # let go: read, and the empty files are what it now says
    assert "a run is still writing" not in capsys.readouterr().err


def test_a_folder_on_a_file_system_without_locks_runs_unheld(tmp_path, monkeypatch):
    """flock on a file system without locks (some NFS mounts: ENOLCK) must not read as "another run holds it":
    the folder then goes unheld. Only EWOULDBLOCK (held elsewhere) refuses it."""
    import errno

    from app import outputs
    from app.config import ConfigError

    def flock(err):
        def f(fd, op):
            raise OSError(err, os.strerror(err))
        return f

    monkeypatch.setattr(outputs.fcntl, "flock", flock(errno.ENOLCK))
    outputs.hold_folder(tmp_path, "--out")
    assert str(tmp_path.resolve()) not in outputs._held
    monkeypatch.setattr(outputs.fcntl, "flock", flock(errno.EWOULDBLOCK))
    with pytest.raises(ConfigError, match="another run is writing into this folder"):
        outputs.hold_folder(tmp_path, "--out")


def test_wall_checkpoints_come_early_then_spread(monkeypatch):
    """The first wall checkpoint after 30 s (a run killed in its first minute can resume), then 60, 120 ...
    up to output.checkpoint_wall_interval."""
    from app.callbacks import writers as runmod

    clock = [0.0]
    monkeypatch.setattr(runmod.wallclock, "perf_counter", lambda: clock[0])
    written = []
    hook = runmod.WallCheckpoints(lambda sim: written.append(clock[0]), 300.0)
    for t in range(0, 1500):
        clock[0] = float(t)
        hook(None)
    assert written[:5] == [30.0, 90.0, 210.0, 450.0, 750.0]
    assert all(b - a == 300.0 for a, b in zip(written[4:], written[5:]))


def test_an_interrupted_preparation_resumes(tmp_path):
    """Ctrl-C during a run.start_from preparation: the next run goes on from its checkpoint, not from zero;
    and --set says that it reaches this stage only."""
    prep = tmp_path / "prep.toml"
    prep.write_text(SETTLE.read_text().replace("count = 2500", "count = 300"))
    main = tmp_path / "main.toml"
    main.write_text(prep.read_text().replace("[run]", '[run]\nstart_from = "prep.toml"', 1))
    env = dict(ENV)
    p = subprocess.Popen([sys.executable, "-m", "app", "run", str(main), "--arch", "cpu",
                          "--set", "run.threads=1"], stderr=subprocess.PIPE, text=True, env=env, cwd=tmp_path)
    head = ""
    for line in p.stderr:  # the preparation has started stepping (its signal handler is in place)
        head += line
        if "compiling kernels" in line:
            break
    assert "preparing prep.toml first" in head, head
    p.send_signal(signal.SIGINT)
    _, err = p.communicate(timeout=300)
    err = head + err
    assert "Traceback" not in err, err[-2000:]
    (cache,) = [d for d in tmp_path.glob("runs/prepared/prep-*") if d.is_dir()]
    assert json.loads((cache / "summary.json").read_text())["status"] == "interrupted", err[-2000:]
    t_stop = checkpoint_time(cache / "checkpoint.h5")
    r = fbed("run", main, "--arch", "cpu", "--set", "run.threads=1", "--set", "run.duration=0.31", cwd=tmp_path)
    assert r.returncode == 0, r.stderr[-2000:]
    assert "resuming the preparation prep.toml" in r.stderr
    assert "--set changes this stage only" in r.stderr
    with h5py.File(cache / "run.h5", "r") as f:  # the preparation's series go on from where it stopped
        t = f["series/time"][...]
    assert t[0] == 0 and (t[1:] > t[:-1]).all() and t[-1] == pytest.approx(0.3) and t_stop < 0.3
    assert json.loads((cache / "summary.json").read_text())["status"] == "finished"


def test_the_resume_hint_names_every_key_a_resume_may_change():
    """The refusal's hint said a resume may change "only run.duration, [output], ..." while run.precision, run.threads
    and run.name were taken too. The hint is now written from the table the check uses; each [run] key it names is
    taken, a key it does not name is refused."""
    from app.config import ConfigError, load
    from app.resume import check_same_scene, resume_free

    run_cfg = load(SETTLE)
    for key, value in (("run.duration", "1.0"), ("run.precision", '"float64"'), ("run.threads", "1"),
                       ("run.name", '"other"'), ("dem.dt", "1e-6"), ("dem.dt_fraction", "0.02")):
        assert key in resume_free()
        check_same_scene(load(SETTLE, [f"{key}={value}"]), run_cfg, SETTLE, ROOT)
    with pytest.raises(ConfigError) as err:
        check_same_scene(load(SETTLE, ["run.step=1e-3"]), run_cfg, SETTLE, ROOT)
    with pytest.raises(ConfigError):  # the guard's other knob, the contact stiffness, changes the material
        check_same_scene(load(SETTLE, ["contact.youngs_modulus=4e7"]), run_cfg, SETTLE, ROOT)
    assert "run.step" not in resume_free() and "run.precision, run.threads" in err.value.hint

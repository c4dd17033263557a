"""Restarting Taichi in one process (``runtime.init`` with other settings, as the agreement tests and the in-process
preset runs do) must leave the new program's arrays alone."""
import os
import pathlib
import subprocess
import sys

import pytest

pytestmark = pytest.mark.unit

ROOT = pathlib.Path(__file__).resolve().parents[1]

# Wrappers of the old program die after the restart, while the new program allocates at the freed addresses
# (with 1000 of each, seen at the first restart in each of 3 runs); a restart at most 8 times, until some address
# was reused.
SCENARIO = """
import gc
import taichi as ti
from app.sim import runtime

Pack = ti.types.argpack(member=ti.types.ndarray(ndim=1))

@ti.kernel
def fill(x: ti.types.ndarray(ndim=1), p: Pack, v: float):
    for i in x:
        x[i] = v
        p.member[i] = 2 * v

def make(n):
    arrays = [ti.ndarray(float, shape=(16,)) for _ in range(n)]
    return arrays, [Pack(member=ti.ndarray(float, shape=(16,))) for _ in range(n)]

runtime.init("cpu", "float64", 1)
for restart in range(8):
    old_arrays, old_packs = make(1000)
    runtime.init("cpu", "float32" if restart % 2 == 0 else "float64", 1)
    arrays, packs = make(1000)
    seen = {id(a.arr) for a in old_arrays} | {id(p._ArgPack__argpack) for p in old_packs}
    reused = sum(id(a.arr) in seen for a in arrays) + sum(id(p._ArgPack__argpack) in seen for p in packs)
    del old_arrays, old_packs  # their __del__ runs now, in the new program
    gc.collect()
    churn = [ti.ndarray(ti.i32, shape=(3, 5, 7)) for _ in range(50)]  # new allocations over anything freed
    for a, p in zip(arrays, packs):
        fill(a, p, 1.0)
        assert a.to_numpy().sum() == 16 and p.member.to_numpy().sum() == 32
    if reused:
        print("reused", reused, "after restart", restart + 1)
        break
"""


def test_wrappers_outliving_a_restart_leave_the_new_programs_arrays_alone(tmp_path):
    """Taichi 1.7.4 frees a program's ndarrays and argpacks at a restart, but a Python wrapper that dies later
    deletes its old pointer from the current program: once a new array sits at that address, the array is freed
    under its owner and its next launch reads a freed shape (a segfault, or "RuntimeError: argument not found",
    seen in the preset smoke tests after an in-process restart). ``runtime.init`` collects the dead wrappers
    before a restart and keeps the live ones: every launch here must find its arrays. Without that, this
    scenario segfaulted in 5 of 6 runs; it is only a check when some freed address was reused (asserted)."""
    script = tmp_path / "restarts.py"  # a file: Taichi reads a kernel's source
    script.write_text(SCENARIO)
    r = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, cwd=ROOT, timeout=300,
                       env=dict(os.environ, PYTHONPATH=str(ROOT)))
    errors = [line for line in r.stderr.splitlines() if "Error" in line or "Assertion" in line]
    assert r.returncode == 0, f"exit {r.returncode} (-11: segfault): {errors[-3:]}"
    assert "reused" in r.stdout, "no freed address was reused in 8 restarts: the scenario did not arise"


CACHE_SCENARIO = """
import taichi as ti
from app.sim import runtime

runtime.init("cpu", "float32", 1)

@ti.kernel
def twice(x: ti.types.ndarray(ndim=1)):
    for i in x:
        x[i] *= 2

a = ti.ndarray(float, shape=(4,))
twice(a)
"""


@pytest.mark.parametrize("age_s", [3600.0, 0.0], ids=["stale", "fresh"])
def test_a_stale_offline_cache_lock_is_removed_and_the_cache_is_written(tmp_path, age_s):
    """A killed process can leave Taichi's cache lock behind, and then no later process reads or writes the
    cache (every kernel is compiled from scratch, for good). ``runtime.init`` removes a lock older than
    ``STALE_LOCK_S``, so the kernel compiled here is written to the cache; a fresh lock (a live process may hold it)
    is left alone, and then nothing is written."""
    cache = tmp_path / "ticache"
    cache.mkdir()
    lock = cache / "ticache.lock"
    lock.touch()
    os.utime(lock, (lock.stat().st_atime - age_s, lock.stat().st_mtime - age_s))
    script = tmp_path / "compile.py"
    script.write_text(CACHE_SCENARIO)
    r = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, cwd=ROOT, timeout=300,
                       env=dict(os.environ, PYTHONPATH=str(ROOT), TI_OFFLINE_CACHE_FILE_PATH=str(cache)))
    assert r.returncode == 0, r.stderr[-2000:]
    written = sorted(p.name for p in cache.iterdir() if p.suffix in (".tic", ".tcb"))
    if age_s > 0:
        assert not lock.exists() and "ticache.tcb" in written and len(written) >= 2, written
    else:
        assert lock.exists() and written == [], written


def test_cpu_threads_are_at_most_the_cpus_available_and_a_cut_is_noted(monkeypatch, capsys):
    """run.threads above the CPUs this process may use (99999 on 2 cores did not finish a step in a minute; 1000
    took 15 s of wall for 2 steps where 4 threads took 5 s, one run each) runs on those CPUs and says so; at or
    below them it is taken as asked; 0 is the automatic choice (one thread on 2 cores or fewer, else all)."""
    from types import SimpleNamespace

    from app.callbacks.progress import cpu_note
    from app.sim import runtime

    for cores, asked, used in ((2, 99999, 2), (2, 2, 2), (2, 1, 1), (2, None, 1), (16, 4, 4), (16, None, 16)):
        monkeypatch.setattr(runtime, "available_cpus", lambda c=cores: c)
        assert runtime.cpu_threads(asked) == used, (cores, asked)
    scene = SimpleNamespace(cfg=SimpleNamespace(run=SimpleNamespace(threads=99999)), derived=None)
    cpu_note(scene, pathlib.Path("x.toml"), 0, 2)
    assert "run.threads = 99999 is more than the 2 CPUs this process may use: it runs on 2" in capsys.readouterr().err
    scene.cfg.run.threads = 2
    cpu_note(scene, pathlib.Path("x.toml"), 0, 2)
    assert capsys.readouterr().err == ""

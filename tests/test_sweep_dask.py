"""`fbed sweep --scheduler local`: every case an ordinary `fbed run` on a Dask worker (a LocalCluster of 2
workers); a case that fails is recorded in sweep.csv and the others finish."""
import csv
import json
import os
import pathlib
import subprocess
import sys

import pytest

pytestmark = pytest.mark.smoke

pytest.importorskip("distributed")  # the cluster extra (in the test extra too)

ROOT = pathlib.Path(__file__).resolve().parents[1]


def test_sweep_on_a_local_dask_cluster_records_a_failed_case(tmp_path):
    out = tmp_path / "sweep"
    # guard.max_speed = 1e-6 m/s trips the guard at the first check (exit 3); 10 and 20 m/s let the tiny bed run
    r = subprocess.run([sys.executable, "-m", "app", "sweep", str(ROOT / "presets" / "settle.toml"),
                        "--scheduler", "local", "--jobs", "2", "--arch", "cpu", "--out", str(out),
                        "--set", "guard.max_speed=10,1e-6,20", "--set", "particles.count=200",
                        "--set", "run.duration=0.004"],
                       capture_output=True, text=True, cwd=tmp_path, env=dict(os.environ, PYTHONPATH=str(ROOT)),
                       timeout=600)
    assert r.returncode == 1, r.stderr[-3000:]  # one case failed
    assert "Traceback" not in r.stderr, r.stderr[-3000:]
    assert "2 of 3 cases finished" in r.stderr
    rows = list(csv.DictReader(open(out / "sweep.csv")))
    assert [row["guard.max_speed"] for row in rows] == ["10", "1e-6", "20"]
    assert [row["exit_code"] for row in rows] == ["0", "3", "0"]
    assert [row["status"] for row in rows] == ["finished", "unstable", "finished"]
    for row in (rows[0], rows[2]):  # the finished cases carry their summary's numbers
        assert float(row["time"]) == pytest.approx(0.004) and float(row["grains"]) == 200
    assert (out / "case-001" / "checkpoint.h5").exists() or (out / "case-001" / "summary.json").exists()


def test_a_dead_worker_is_recorded_and_the_other_cases_finish(tmp_path):
    """The worker running case 0 is killed (kill -9) while the case runs; with Dask's retries off
    (allowed-failures 0) the case is recorded as failed with KilledWorker, the other case finishes, and the
    killed worker's `fbed run` stops itself with a checkpoint (it would otherwise write on beside a rerun)."""
    import time

    psutil = pytest.importorskip("psutil")  # a dependency of distributed
    out = tmp_path / "sweep"
    env = dict(os.environ, PYTHONPATH=str(ROOT), DASK_DISTRIBUTED__SCHEDULER__ALLOWED_FAILURES="0")
    p = subprocess.Popen([sys.executable, "-m", "app", "sweep", str(ROOT / "presets" / "settle.toml"),
                          "--scheduler", "local", "--jobs", "2", "--arch", "cpu", "--out", str(out),
                          "--set", "run.duration=30,0.004", "--set", "particles.count=200"],
                         stderr=subprocess.PIPE, text=True, cwd=tmp_path, env=env)
    victim = orphan = None
    try:
        deadline = time.time() + 300
        while time.time() < deadline and victim is None:  # the `fbed run` of case 0, and the worker above it
            for proc in psutil.Process(p.pid).children(recursive=True):
                try:
                    if "app" in proc.cmdline() and str(out / "case-000") in proc.cmdline():
                        orphan, victim = proc, proc.parent()
                except psutil.NoSuchProcess:
                    continue
            time.sleep(0.2)
        assert victim is not None, "case 0 never started"
        victim.kill()
        _, err = p.communicate(timeout=300)
        orphan.wait(timeout=120)  # it stops by itself once its worker is gone
    finally:
        if orphan is not None and orphan.is_running():
            orphan.kill()
        if p.poll() is None:
            p.kill()
    summary = json.loads((out / "case-000" / "summary.json").read_text())
    assert summary["status"] == "interrupted" and summary["time"] < 30  # stopped early, at whatever step it had
    assert (out / "case-000" / "checkpoint.h5").exists()
    assert "the process that started this run is gone" in (out / "case-000" / "log.txt").read_text()
    assert p.returncode == 1, err[-3000:]
    assert "Traceback" not in err, err[-3000:]
    # the local cluster's own log is silenced: its restarted worker once logged a heartbeat traceback while the
    # cluster closed (1 run in 4); fbed's line for the case says how it ended
    assert "distributed." not in err, err[-3000:]
    rows = list(csv.DictReader(open(out / "sweep.csv")))
    assert rows[0]["status"].startswith("failed: KilledWorker") and rows[0]["exit_code"] == "-1", rows[0]
    assert rows[1]["status"] == "finished" and rows[1]["exit_code"] == "0"


def test_a_signal_stops_a_dask_sweep_and_keeps_its_table(tmp_path):
    """On a Dask cluster, Ctrl-C on the sweep was not seen while the cases ran (they ran on, and the queued ones
    after them), and SIGTERM killed it without writing sweep.csv. Now the cases not done are cancelled (none
    starts after the signal), the running ones stop with a checkpoint as their workers go, the table says so,
    exit 130; --resume goes on from there (tested on threads: test_cli)."""
    import signal
    import time

    out = tmp_path / "sweep"
    p = subprocess.Popen([sys.executable, "-m", "app", "sweep", str(ROOT / "presets" / "settle.toml"),
                          "--scheduler", "local", "--jobs", "2", "--arch", "cpu", "--out", str(out),
                          "--set", "particles.count=200,300,400", "--set", "run.duration=100"],
                         stderr=subprocess.PIPE, text=True, cwd=tmp_path, env=dict(os.environ, PYTHONPATH=str(ROOT)))
    try:
        deadline = time.time() + 300
        while time.time() < deadline and not all((out / c / "run.h5").exists() for c in ("case-000", "case-001")):
            time.sleep(0.5)
        time.sleep(1.0)
        p.send_signal(signal.SIGINT)
        _, err = p.communicate(timeout=300)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == 130 and "Traceback" not in err, err[-3000:]
    assert "SIGINT: no other case starts, and the running ones stop with a checkpoint" in err and "--resume" in err, err[-3000:]
    rows = list(csv.DictReader(open(out / "sweep.csv")))
    assert [r["status"] for r in rows] == ["not finished (the sweep was stopped)"] * 3
    assert not (out / "case-002" / "run.h5").exists()  # never started
    deadline = time.time() + 60  # the running cases stop themselves, with a checkpoint, once their worker is gone
    while time.time() < deadline and not all((out / c / "summary.json").exists() for c in ("case-000", "case-001")):
        time.sleep(0.5)
    for c in ("case-000", "case-001"):
        assert json.loads((out / c / "summary.json").read_text())["status"] == "interrupted"
        assert (out / c / "checkpoint.h5").exists()

"""`fbed sweep --scheduler local`: every case an ordinary `fbed run` on a Dask worker (a LocalCluster of 2
workers); a case that fails is recorded in sweep.csv and the others finish."""
import csv
import os
import pathlib
import subprocess
import sys

import pytest

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

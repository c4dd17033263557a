"""Unit tier: run.h5's batched writer keeps every row and frame, in order, through flushes and resumes."""
import h5py
import numpy as np
import pytest

from app.io import store

pytestmark = pytest.mark.restart


def test_batched_rows_and_frames_all_reach_the_file(tmp_path, monkeypatch):
    """Rows are held and written in batches (here 3 rows): a series first seen late is NaN before, one
    missing from a row is NaN there, and frames keep their order and times; close writes what is held."""
    monkeypatch.setattr(store, "SERIES_BATCH", 3)
    rf = store.RunFile(tmp_path / "run.h5", "t")
    for i in range(7):
        row = {"time": i * 1e-3, "a": float(i)}
        if i >= 4:
            row["b"] = 10.0 * i
        if i == 5:
            del row["a"]
        rf.append(row)
        rf.frame("planes/z0.050", i * 1e-3, np.full((2, 3), i))
    with h5py.File(tmp_path / "run.h5", "r") as f:  # 6 rows written (two batches), the 7th held
        assert f["series/time"].shape == (6,)
    rf.close()
    with h5py.File(tmp_path / "run.h5", "r") as f:
        s = {k: f["series"][k][...] for k in f["series"]}
        np.testing.assert_allclose(s["time"], np.arange(7) * 1e-3)
        np.testing.assert_array_equal(s["a"], [0, 1, 2, 3, 4, np.nan, 6])
        np.testing.assert_array_equal(s["b"], [np.nan] * 4 + [40, 50, 60])
        g = f["planes/z0.050"]
        np.testing.assert_allclose(g["time"][...], np.arange(7) * 1e-3)
        assert g["porosity"].shape == (7, 2, 3) and np.all(g["porosity"][...][:, 0, 0] == np.arange(7))


def test_resume_truncates_after_the_checkpoint_time(tmp_path):
    rf = store.RunFile(tmp_path / "run.h5", "t")
    for i in range(10):
        rf.append({"time": i * 0.1, "x": i})
        rf.frame("slab", i * 0.1, np.zeros(4) + i)
    rf.flush()  # what a checkpoint at t = 0.9 does first
    rf.close()
    rf = store.RunFile(tmp_path / "run.h5", "t", resume_time=0.45)
    rf.append({"time": 0.5, "x": -1})
    rf.close()
    with h5py.File(tmp_path / "run.h5", "r") as f:
        np.testing.assert_allclose(f["series/time"][...], [0, 0.1, 0.2, 0.3, 0.4, 0.5])
        assert f["series/x"][-1] == -1
        assert f["slab/time"].shape == (5,) and f["slab/time"][-1] == pytest.approx(0.4)

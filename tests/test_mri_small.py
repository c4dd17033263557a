"""Smoke tier: presets/mri_small.toml runs the MRI pipeline end to end (fill, settle, fluidize, the synthetic
MRI and the slab recorded every 4 ms, the analysis), shortened for CI: a 10 mm bed (about 4,600 grains)
settles for 10 ms, the inlet opens over 10 ms, and 40 ms are recorded (about a minute on 2 cores)."""
import json

import h5py
import numpy as np
import pytest

from app.probes_mri import slab_volume
from test_cli import ROOT, fbed

pytestmark = pytest.mark.smoke

SHORT = ["run.duration=0.06", "particles.bed_height=0.01", "output.average_from=0.02",
         "boundary.bottom.schedule=[[0.0,0.0],[0.01,0.0],[0.02,1.0]]", "probes.mri_static_height=0.01"]


def test_mri_small_runs_the_whole_pipeline(tmp_path):
    args = ["run", ROOT / "presets" / "mri_small.toml", "--arch", "cpu", "--out", tmp_path / "o"]
    for s in SHORT:
        args += ["--set", s]
    r = fbed(*args, timeout=900)
    assert r.returncode == 0, r.stderr
    o = tmp_path / "o"
    s = json.loads((o / "summary.json").read_text())
    assert s["status"] == "finished" and "analysis_error" not in s, s.get("analysis_error")
    for src in ("mri", "slab"):
        for name in ("thresholds.csv", "metrics.csv", "radial.csv", "spectrum.csv", "tables.md", "mri.png"):
            assert (o / "analysis" / src / name).exists(), (src, name)
        # a bed is found: between the floor and the domain's top
        assert 0.0 < s[f"{src}_bed_height_mean"] < 0.096
    with h5py.File(o / "run.h5") as f:
        mri = f["mri"]
        assert np.allclose(mri["time"][...], 0.004 * np.arange(1, 16))  # every 4 ms, to 60 ms
        dx, dz = mri.attrs["pixel"]
        open_fraction = mri.attrs["open_fraction"]
        mri_origin = tuple(mri.attrs["origin"])
        void = mri["porosity"][-1].astype(float)
        last = f["particles"][str(len(f["particles"]) - 1)]
        assert float(last["time"][()]) == pytest.approx(float(mri["time"][-1]))
        x, rad = last["position"][...].astype(float), last["radius"][...].astype(float)
    # the last MRI frame holds the grains' slab volume of the last snapshot (float32 positions: 1e-4)
    cell = dx * dz * 0.01 * open_fraction[:, None]
    mask = open_fraction >= 0.5
    binned = np.sum(((1.0 - void) * cell)[mask])
    x0 = mri_origin[0]
    col = np.floor((x[:, 0] - x0) / dx).astype(int)
    inside = (col >= 0) & (col < mask.size)
    inside[inside] = mask[col[inside]]
    expect = np.sum(slab_volume(x[inside, 1], rad[inside], 0.005))
    assert binned == pytest.approx(expect, rel=1e-3)

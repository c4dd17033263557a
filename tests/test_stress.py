"""Stress tier: every hostile scene of `fbed bench stress` ends as specified (CPU-small sizes).

Each scene runs as its own `fbed run` process with a wall-clock limit. It must finish with finite
series, no grain outside the walls and the gas divergence below 1e-3 (mass conserved), or stop
with exit 3, a message naming the setting to change, and its outputs kept; never a NaN in
run.h5, a traceback or a hang (app/bench.py judges each)."""
import pytest

from app.bench import SCENES, run_scene


@pytest.mark.slow
@pytest.mark.parametrize("scene", SCENES, ids=[s.name for s in SCENES])
def test_stress_scene_ends_as_specified(scene, tmp_path):
    row = run_scene(scene, tmp_path, "cpu", limit=600)
    assert row["ok"], f"{scene.name}: {row['problems']} (exit {row['exit']}, message: {row['message']})"
    if scene.expect == "stop":
        assert row["outcome"] == "stopped"
    if scene.name == "dt_twice_stable":  # the guard stops it within a bounded number of steps
        assert row["reached_s"] <= 0.01
    if scene.name == "starved_pressure":
        assert "gas.max_iterations" in row["message"]

"""Stress tier: every hostile scene of `fbed bench stress` ends as specified (CPU-small sizes).

Each scene runs as its own `fbed run` process with a wall-clock limit. It must finish with finite
series, no grain outside the walls and the gas divergence below 1e-3 (mass conserved), or stop
with exit 3, a message naming the setting to change, and its outputs kept; never a NaN in
run.h5, a traceback or a hang (app/bench/stress.py judges each)."""
import pytest

from app.bench.stress import SCENES, run_scene

pytestmark = pytest.mark.stress


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


def test_accuracy_restitution_error_falls_with_the_step_and_is_small_at_the_default():
    """Symplectic Euler's rebound error is O(dt / t_c): it must fall as the step shrinks, and at the
    default dt_fraction = 0.05 stay below 1% (measured 0.30%; test_contact.py allows 2% for e = 0.5-0.9)."""
    from app.bench.dem_cases import DT_FRACTIONS, pair_collision

    rows = [pair_collision(f, precision="float64") for f in DT_FRACTIONS]
    errors = [r["restitution_error"] for r in rows]
    steps = [r["steps_per_contact"] for r in rows]
    assert steps == sorted(steps, reverse=True) and steps[0] > 150 and steps[-1] >= 4
    assert errors[-1] > errors[0]  # the coarsest step is the least accurate
    assert all(b >= a * 0.8 for a, b in zip(errors, errors[1:]))  # falls with the step (20% slack for rounding)
    assert rows[DT_FRACTIONS.index(0.05)]["restitution_error"] < 0.01


def test_energy_check_measures_growth_from_the_floor_and_one_interval_back():
    """The guard's energy rule on its own (no run): growth from rest is measured from the floor (a bed starting
    to move is not a blow-up), the reference moves once per guard interval, and the factor is the limit."""
    from app.callbacks.guard import Guard
    from app.sim.simulation import Unstable

    g = Guard(max_overlap=0.2, max_speed=100.0, max_energy_growth=100.0, energy_floor=1e-3, interval=1e-3)
    g._energy_check(0.0, 0.0)
    g._energy_check(0.09, 0.5e-3)    # 90x the floor within the interval: physical
    g._energy_check(0.09, 1.0e-3)    # the reference moves to 0.09 J at t = 1 ms
    g._energy_check(8.9, 1.5e-3)     # 99x the reference: still under the limit
    with pytest.raises(Unstable, match=r"grew 111x in 0.001 s .*guard.max_energy_growth = 100x"):
        g._energy_check(10.0, 2.0e-3)

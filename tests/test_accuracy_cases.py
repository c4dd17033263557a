"""The accuracy bench's cases (app.accuracy.dem_cases, gas_cases): each measure called with a settings
dict must give the error the physics predicts, and the runner must write its files.

Runs in float64 on the CPU (conftest); measured values at the time of writing are quoted next to
each bound.
"""
import math

import pytest

from app.accuracy import Unavailable, all_cases
from app.accuracy.dem_cases import pair_collision

CASES = {c.name: c for c in all_cases()}


def measure(name, size="small", **changes):
    case = CASES[name]
    return case.measure({**case.defaults, "precision": "float64", **changes}, size)


def test_contact_time_is_second_order_in_the_step_and_small_at_the_default():
    """The touching interval is interpolated between steps, so what is left is the integration's error,
    O((dt / t_c)^2): quartering the step divides it by ~16 (measured 16.0), and at the presets'
    dt_fraction 0.05 it is 0.13% (bound 0.2%)."""
    errors = {}
    for f in (0.2, 0.05):
        row = pair_collision(f, e=1.0, precision="float64")
        errors[f] = abs(row["contact_duration"] / row["hertz_duration"] - 1.0)
        assert row["steps_per_contact"] == pytest.approx(1.0 / f, abs=1)
    assert errors[0.05] < 2e-3
    assert 10 < errors[0.2] / errors[0.05] < 25


def test_hertz_reference_uses_the_exact_coefficient():
    """(4/5)(15/16)^(2/5) B(2/5, 1/2) = 2.8683; fbed's step picker rounds it to 2.868."""
    from app.config import load_text
    from app.accuracy.dem_cases import PAIR, hertz_duration_exact

    cfg = load_text(PAIR.format(precision="float64", e=1.0, f=0.05, v=0.5, E=5e6), "pair.toml")
    m_eff = 2500 * 4 / 3 * math.pi * 1e-9 / 2
    e_star = 5e6 / (2 * (1 - 0.3 ** 2))
    scale = (m_eff ** 2 / (0.5e-3 * e_star ** 2 * 0.5)) ** 0.2
    assert hertz_duration_exact(cfg, 1e-3, 0.5) / scale == pytest.approx(2.86827, abs=1e-5)


def test_terminal_velocity_error_is_first_order_in_the_fluid_step():
    """The grain's drag is implicit over the fluid step (backward Euler), so its relaxation lags by
    O(dt / tau): 0.048% at the presets' 1 ms (bound 0.1%, far inside the case's 2%), and 4x the step
    gives ~4x the error (measured 4.3). After 0.2 s the grain is at 98% of its terminal speed."""
    fine = measure("terminal_velocity")
    coarse = measure("terminal_velocity", fluid_step=4e-3)
    assert fine["error"] < 1e-3
    assert 0.975 < fine["speed_over_terminal"] < 0.99
    assert 3.0 < coarse["error"] / fine["error"] < 5.5


def test_ergun_error_is_the_smeared_bed_surface():
    """The bed's top and bottom are smeared over a cell, where the strongly nonlinear drag loses about
    a cell's worth of bed: the error is ~h / L (L = 80 mm): measured 5.4% at h = 4 mm (h/L = 5%;
    3.3% at 3 mm, 8.0% at 6 mm). The steady frozen bed needs
    almost no pressure iterations, so the solve tolerance moves it by < 1e-5 (measured 5e-6)."""
    default = measure("ergun")
    assert 0.5 * 4e-3 / 0.08 < default["error"] < 1.5 * 4e-3 / 0.08
    loose = measure("ergun", tolerance=1e-3)
    assert abs(loose["error"] - default["error"]) < 1e-4


def test_pipe_profile_converges_at_second_order():
    """Cut-cell Hagen-Poiseuille: RMS error 0.86% at 8 cells across, 0.20% at 16 (ratio 4.3: second
    order in h, first order only in the few wall cells)."""
    e8 = measure("pipe", cells_across=8)["error"]
    e16 = measure("pipe", cells_across=16)["error"]
    assert e16 < 3e-3
    assert 3.0 < e8 / e16 < 6.0


def test_cavity_reference_missing_is_unavailable(tmp_path, monkeypatch):
    monkeypatch.setenv("FBED_REFERENCE", str(tmp_path))
    with pytest.raises(Unavailable, match="FBED_REFERENCE") as err:
        measure("cavity", cells=16)
    assert str(tmp_path) in str(err.value)


def test_cavity_32_cells_within_ghia_scatter(reference_dir, monkeypatch):
    """32 cells already match Ghia to an RMS of 0.0026 of the lid speed, inside their own ~0.009
    difference from grid-converged solutions (bound 0.005)."""
    monkeypatch.setenv("FBED_REFERENCE", str(reference_dir))
    assert measure("cavity", cells=32)["error"] < 5e-3


def test_runner_writes_csv_plot_and_recommended_settings(tmp_path):
    """contact_time's cost is a step count, not a clock: its recommendation is deterministic. The
    cheapest dt_fraction within 1% is 0.1 (0.53%; 0.2 gives 2.1%), so the presets' 0.05 (0.13%, twice
    the steps) is not on the knee."""
    from app.accuracy.runner import accuracy

    assert accuracy(out=str(tmp_path), names=["contact_time"], size="small", arch="cpu") == 0
    rows = (tmp_path / "accuracy.csv").read_text().splitlines()
    assert rows[0].startswith("case,knob,value,error,cost")
    assert len(rows) == 1 + 1 + 5 + 1  # header, default, the other dt_fractions, float64
    assert (tmp_path / "pareto_contact_time.png").stat().st_size > 10_000
    md = (tmp_path / "ACCURACY.md").read_text()
    row = next(line for line in md.splitlines() if line.startswith("| contact_time | dt_fraction |"))
    cells = [c.strip() for c in row.split("|")[1:-1]]
    assert cells[4] == "0.1" and cells[-1] == "no"


def test_knee_picks_the_cheapest_of_equal_errors_when_none_is_within_tolerance():
    """Ergun at 4 mm cells: no tolerance value brings the error under 5% (the cell size sets it), so
    the errors tie within rounding; the knee must then pick the cheapest, not the value whose error
    happens to be 1e-9 smaller. A clearly better value (2% smaller error) still wins over cost."""
    from app.accuracy import Case
    from app.accuracy.runner import knee

    case = Case(name="t", title="", error_label="", cost_label="", knobs={"tolerance": (1e-3, 1e-8)},
                defaults={"tolerance": 1e-6}, tolerance=0.05, measure=lambda settings, size: {})
    rows = [{"knob": "default", "value": "", "error": 0.0539, "cost": 7.0},
            {"knob": "tolerance", "value": 1e-3, "error": 0.0539 + 1e-9, "cost": 5.4},
            {"knob": "tolerance", "value": 1e-8, "error": 0.0539 - 1e-9, "cost": 13.7}]
    k = knee(case, rows, "tolerance")
    assert k["recommended"] == 1e-3 and not k["default_on_knee"]
    rows[2]["error"] = 0.0539 * 0.98
    assert knee(case, rows, "tolerance")["recommended"] == 1e-8

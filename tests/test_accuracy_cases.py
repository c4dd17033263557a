"""The accuracy bench's cases (app.bench.dem_cases, gas_cases): each measure called with a settings
dict must give the error the physics predicts, and the runner must write its files.

Runs in float64 on the CPU (conftest); measured values at the time of writing are quoted next to
each bound.
"""
import math

import pytest

from app.bench.accuracy import all_cases
from app.bench.cases import Unavailable
from app.bench.dem_cases import pair_collision

pytestmark = pytest.mark.bench

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
    from app.bench.dem_cases import PAIR, hertz_duration_exact

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
    from app.bench.accuracy import accuracy

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
    from app.bench.accuracy import knee
    from app.bench.cases import Case

    case = Case(name="t", title="", error_label="", cost_label="", knobs={"tolerance": (1e-3, 1e-8)},
                defaults={"tolerance": 1e-6}, tolerance=0.05, measure=lambda settings, size: {})
    rows = [{"knob": "default", "value": "", "error": 0.0539, "cost": 7.0},
            {"knob": "tolerance", "value": 1e-3, "error": 0.0539 + 1e-9, "cost": 5.4},
            {"knob": "tolerance", "value": 1e-8, "error": 0.0539 - 1e-9, "cost": 13.7}]
    k = knee(case, rows, "tolerance")
    assert k["recommended"] == 1e-3 and not k["default_on_knee"]
    rows[2]["error"] = 0.0539 * 0.98
    assert knee(case, rows, "tolerance")["recommended"] == 1e-8


def test_a_default_is_on_the_knee_across_cases_only_where_a_case_binds_it(monkeypatch):
    """One case's knee says only that a cheaper value passes that case; a default serves every case. Knob
    dt_fraction (cheap side: larger): case A passes the cheaper 0.1, case B fails it (bound: on the knee), though
    B measured it dearer than the default (a bed's cost scatters). Knob j: the cheaper value passes the only
    case that sweeps it and no reason is on record (a candidate to change), or one is (it is quoted). Knob t: the
    default fails case A's tolerance and a cheaper value is as accurate, which counts as passing."""
    from app.bench import accuracy as runner
    from app.bench.cases import Case

    def case(name, knobs, defaults, tol=0.05):
        return Case(name=name, title="", error_label="", cost_label="", knobs=knobs, defaults=defaults,
                    tolerance=tol, measure=lambda settings, size: {})

    a = case("A", {"dt_fraction": (0.1,), "j": (2,)}, {"dt_fraction": 0.05, "j": 1})
    b = case("B", {"dt_fraction": (0.02, 0.1)}, {"dt_fraction": 0.05})
    c = case("C", {"t": (1e-3,)}, {"t": 1e-6}, tol=0.01)
    rows = [{"case": "A", "knob": "default", "value": "", "error": 0.01, "cost": 10.0},
            {"case": "A", "knob": "dt_fraction", "value": 0.1, "error": 0.03, "cost": 5.0},
            {"case": "A", "knob": "j", "value": 2, "error": 0.02, "cost": 4.0},
            {"case": "B", "knob": "default", "value": "", "error": 0.04, "cost": 10.0},
            {"case": "B", "knob": "dt_fraction", "value": 0.02, "error": 0.01, "cost": 25.0},
            {"case": "B", "knob": "dt_fraction", "value": 0.1, "error": 0.09, "cost": 10.5},
            {"case": "C", "knob": "default", "value": "", "error": 0.02, "cost": 3.0},
            {"case": "C", "knob": "t", "value": 1e-3, "error": 0.02 * (1 + 1e-4), "cost": 1.0}]
    monkeypatch.setattr(runner, "WHY_DEFAULT", {})
    got = {k["knob"]: k for k in runner.defaults_across([a, b, c], rows)}
    k = got["dt_fraction"]
    assert [e["verdict"] for e in k["cases"]] == ["passed", "bound"] and k["bound"]
    assert k["cases"][1]["value"] == 0.1  # the failing value on the cheap side, not the passing 0.02
    assert not got["j"]["bound"] and got["j"]["cheaper_passes"] and got["j"]["why"] == ""
    assert got["t"]["cases"][0]["verdict"] == "out" and got["t"]["cases"][0]["value"] == 1e-3
    table = "\n".join(runner._across_lines([a, b, c], rows))
    assert "| dt_fraction | A (0.05): 0.1 passes at 0.50x the cost (3.00e-02); B (0.05): bound, 0.1 gives " \
           "9.00e-02 > 0.05 | yes: B binds it |" in table
    assert "| j | A (1): 2 passes at 0.40x the cost (2.00e-02) | no, and nothing measured keeps it" in table
    monkeypatch.setattr(runner, "WHY_DEFAULT", {"j": "a reason measured elsewhere"})
    assert "| j | A (1): 2 passes at 0.40x the cost (2.00e-02) | no; kept: a reason measured elsewhere |" in \
        "\n".join(runner._across_lines([a, b, c], rows))


def test_stiffness_knee_is_the_softest_modulus_from_which_every_stiffer_one_is_close():
    """The study's knee: the softest modulus from which it and every stiffer one are within 5% (SETTLED) of the
    stiffest run. A soft modulus that lands within 5% while a stiffer one does not (scatter) is not the knee."""
    from app.bench import stiffness

    def row(e, height, cost):
        return {"youngs_modulus": e, "status": "finished", "cost": cost, "max_overlap_pct": 1.0,
                **{k: 1.0 for k in stiffness.COMPARED}, "bed_height_mean": height}

    rows = [row(1e5, 1.20, 1.0), row(1e6, 1.04, 2.0), row(5e6, 1.06, 3.0), row(1e7, 1.03, 4.0), row(1e8, 1.0, 8.0)]
    text = stiffness.verdict(rows)
    assert "From E = 1e+07 Pa up, every figure is within 5% of E = 1e+08 Pa's, at 0.50x its cost." in text
    assert "by 6.0% (bed_height_mean) at 0.38x its cost (it is softer than that)" in text
    rows[2]["bed_height_mean"] = 1.045
    assert "From E = 1e+06 Pa up" in stiffness.verdict(rows)
    assert "(it is stiffer than that)" in stiffness.verdict(rows)


def _fake_bench(monkeypatch, calls, before=None):
    """The runner's only case: its measure is arithmetic (error = dt_fraction^2, cost = 1/dt_fraction) and
    counts its calls; ``before(n)``, with n the calls so far, runs first (to interrupt the bench)."""
    from app.bench import accuracy as runner
    from app.bench.cases import Case

    def measure(settings, size):
        if before:
            before(len(calls))
        calls.append((settings["dt_fraction"], settings["precision"]))
        return {"error": settings["dt_fraction"] ** 2, "cost": 1.0 / settings["dt_fraction"]}

    case = Case(name="fake", title="arithmetic", error_label="e", cost_label="c",
                knobs={"dt_fraction": (0.01, 0.1, 0.2), "precision": ("float64",)},
                defaults={"dt_fraction": 0.05, "precision": "float32"}, tolerance=0.02, measure=measure)
    monkeypatch.setattr(runner, "all_cases", lambda: [case])


def test_resume_measures_only_what_an_interrupted_bench_had_not(tmp_path, monkeypatch, capsys):
    """A bench stopped by a signal mid-case keeps every row measured before the stop (written row by row),
    records none for the stopped run and ends with 130; --resume measures only the missing points, and the
    report covers them all. Resuming at another size is refused with the file and the fix named."""
    from app import cli
    from app.bench import accuracy as runner
    from app.bench.cases import Interrupted

    def stopped_on_the_third(n):
        if n == 2:
            raise Interrupted("SIGTERM")

    calls: list = []
    _fake_bench(monkeypatch, calls, stopped_on_the_third)
    assert runner.accuracy(out=str(tmp_path), size="small", arch="cpu") == 130
    first = (tmp_path / "accuracy.csv").read_text().splitlines()
    assert len(first) == 1 + 2 and len(calls) == 2
    assert first[0].split(",")[-3:] == ["size", "arch", "commit"]

    calls.clear()
    _fake_bench(monkeypatch, calls)
    assert runner.accuracy(out=str(tmp_path), size="small", arch="cpu", resume=True) == 0
    assert len(calls) == 5 - 2  # default, three dt_fractions, float64: the first two are kept
    rows = (tmp_path / "accuracy.csv").read_text().splitlines()
    assert rows[1:3] == first[1:3] and len(rows) == 1 + 5
    md = (tmp_path / "ACCURACY.md").read_text()
    knee_row = next(line for line in md.splitlines() if line.startswith("| fake | dt_fraction |"))
    assert [c.strip() for c in knee_row.split("|")[1:-1]][4] == "0.1"  # error 0.01 <= 0.02 at the lowest cost

    calls.clear()
    assert runner.accuracy(out=str(tmp_path), size="small", arch="cpu", resume=True) == 0 and not calls
    capsys.readouterr()
    assert cli.main(["bench", "accuracy", "--out", str(tmp_path), "--size", "full", "--resume"]) == 2
    err = capsys.readouterr().err
    assert "accuracy.csv: --resume" in err and "'small'" in err and "hint:" in err and "Traceback" not in err


def test_an_interrupted_bed_run_is_neither_a_row_nor_memoised(monkeypatch):
    """A bed run stopped by a signal ends 'interrupted' (exit 130): the bench must not record it as a setting
    that failed, nor hand its figures to the next case that shares the run."""
    from app.bench import bed_cases
    from app.bench.cases import Interrupted

    runs = []
    monkeypatch.setattr(bed_cases, "bed_text", lambda size, settings, start=None: "")
    monkeypatch.setattr(bed_cases, "run_scene",
                        lambda text, folder: runs.append(folder) or {"status": "interrupted", "exit": 130})
    for _ in range(2):
        with pytest.raises(Interrupted):
            bed_cases.bed_run({**bed_cases.DEFAULTS, "skin": 1.0e-3}, "small")
    assert len(runs) == 2


def test_stiffness_resume_keeps_the_measured_moduli(tmp_path, monkeypatch):
    """The stiffness study writes each modulus's row at once; --resume runs only the moduli missing."""
    from app.bench import stiffness
    from app.bench.cases import Interrupted

    calls = []

    def measure(e, size):
        calls.append(e)
        if e == 1.0e7 and len(calls) == 3:
            raise Interrupted("SIGTERM")
        return {"youngs_modulus": e, "status": "finished", "substeps": int(10 * e ** 0.2), "dem_dt": 1e-5,
                "stepping_wall_s": 1.0, "cost": e ** 0.2, "bed_height_mean": 0.05, "bed_height_std": 0.002,
                "bed_height_max": 0.06, "dp_over_weight": 0.99, "dp_over_weight_raw": 0.97, "bubble_diameter": 0.01,
                "bubbles": 3, "gas_pocket_height": 0.0, "max_overlap_pct": 1e3 * e ** -0.4, "umf_simulated": 1.2,
                "umf_predicted": 1.25}

    monkeypatch.setattr(stiffness, "measure", measure)
    moduli = (1.0e5, 1.0e6, 1.0e7)
    assert stiffness.stiffness(str(tmp_path), moduli=moduli) == 130
    assert len((tmp_path / "stiffness.csv").read_text().splitlines()) == 1 + 2
    calls.clear()
    assert stiffness.stiffness(str(tmp_path), moduli=moduli, resume=True) == 0
    assert calls == [1.0e7]
    md = (tmp_path / "STIFFNESS.md").read_text()
    assert "| 100000 | 100 |" in md and "| 1e+07 | 251 |" in md


def test_sigterm_ends_the_bench_with_its_rows_and_report(tmp_path, monkeypatch):
    """A time limit's SIGTERM in the middle of a measure (not a bed run, which handles its own) ends the bench
    like Ctrl-C: exit 130, the rows before it and the report written, the handler put back afterwards."""
    import os
    import signal
    import threading

    from app.bench import accuracy as runner

    if threading.current_thread() is not threading.main_thread():
        pytest.skip("signals are delivered to the main thread only")
    def terminated_on_the_second(n):
        if n == 1:
            os.kill(os.getpid(), signal.SIGTERM)

    _fake_bench(monkeypatch, [], terminated_on_the_second)
    before = signal.getsignal(signal.SIGTERM)
    assert runner.accuracy(out=str(tmp_path), size="small", arch="cpu") == 130
    assert signal.getsignal(signal.SIGTERM) is before
    assert len((tmp_path / "accuracy.csv").read_text().splitlines()) == 1 + 1
    assert (tmp_path / "ACCURACY.md").exists()

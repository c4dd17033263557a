"""The adaptive fluid step (Simulation: gas.max_cfl / gas.max_split): a step whose gas CFL passes the
limit makes the next steps split into pieces, the clock still counts whole steps, the pieces are
exactly smaller gas steps, and splitting a coupled step changes the physics by no more than its
O(dt) error."""
import numpy as np
import pytest

from app.scene import build_simulation
from app.sim.simulation import Simulation

from dem_helpers import grains, scene_of
from flow_helpers import jet_solver

pytestmark = pytest.mark.verification


def test_high_cfl_splits_the_fluid_step_and_pieces_are_exact_smaller_steps():
    sim = Simulation(None, 1e-3, 0, 0.012, flow=jet_solver())
    sim.max_gas_cfl, sim.max_gas_split = 2.0, 16
    notes, splits = [], []
    sim.notify = notes.append
    sim.before_step.append(lambda s: splits.append(s.gas_split))
    assert sim.run() == "finished"
    assert sim.step_count == 12 and sim.time == pytest.approx(0.012, rel=1e-12)  # the clock counts whole steps
    assert splits[0] == 1 and max(splits) >= 4  # a CFL of ~8 at 1 ms needs >= 4 pieces to stay under 2
    assert sim.flow_info.cfl <= 2.0 * 1.05, sim.flow_info  # once adapted the pieces stay under the limit
    assert notes and "gas.max_cfl = 2" in notes[0]
    assert sim.flow.time == pytest.approx(0.012, rel=1e-12)  # the pieces add up to the steps
    # the same gas stepped by hand with the same pieces: identical fields
    ref = jet_solver()
    for n in splits:
        for _ in range(n):
            ref.step(1e-3 / n)
    assert np.allclose(ref.cell_velocity(), sim.flow.cell_velocity(), rtol=1e-9, atol=1e-9)


def test_split_returns_to_one_when_the_flow_calms():
    sim = Simulation(None, 1e-3, 0, 0.02, flow=jet_solver())
    sim.max_gas_cfl, sim.max_gas_split = 2.0, 16
    sim.gas_split = 8  # as after a burst; the jet is off, the gas at rest: the CFL is ~0
    sim.flow.set_inlet_profile("bottom", np.zeros((16, 16)))
    sim.run()
    assert sim.gas_split == 1 and sim.gas_split_changes == 3  # 8 -> 4 -> 2 -> 1


def _settling_grain(split: int):
    """One 0.1 mm glass grain falling through still air (test_fluidization's terminal-velocity scene),
    run for 0.1 s with every fluid step cut into ``split`` pieces."""
    d = 1e-4
    scene = scene_of(
        grains([[0.004, 0.004, 0.3]], d / 2),
        domain={"lo": [-0.02, -0.02, 0.0], "hi": [0.02, 0.02, 0.32], "gravity": [0.0, 0.0, -9.81]},
        vessel={"shape": "box"}, particles={"diameter": d, "density": 2500.0, "count": 1},
        contact={"youngs_modulus": 1e3, "friction": 0.0}, run={"step": 2e-3, "duration": 0.1},
        gas={"cell_size": 8e-3, "viscosity": 1.8e-5, "density": 1.2, "pressure_form": "shared",
             "max_split": 1},  # the split fixed: the adaptive step off
        coupling={"drag": "schiller_naumann"}, boundary={"top": "pressure_outlet"})
    sim = build_simulation(scene)
    dem = sim.dem
    sim.gas_split = split  # fixed: max_gas_split = 1 keeps it
    sim.run()
    assert sum(sim._piece_substeps(split)) == scene.derived.substeps
    return -dem.read("velocity")[0, 2], dem.read("position")[0, 2]


def test_splitting_a_coupled_step_keeps_the_physics():
    """The grain's relaxation time (~0.06 s) is 30 fluid steps: its speed after 0.1 s must agree
    between whole and quartered fluid steps to well within the first-order coupling error
    (dt / tau ~ 3%); its drop agrees likewise."""
    v1, z1 = _settling_grain(1)
    v4, z4 = _settling_grain(4)
    assert v4 == pytest.approx(v1, rel=0.02)
    assert (0.3 - z4) == pytest.approx(0.3 - z1, rel=0.02)
    assert v1 > 0.1  # it did fall


def test_gas_speed_guard_names_the_fastest_cell():
    """A gas-speed stop says where: the 50 m/s jet enters through the 2x2 centre cells of the bottom."""
    from app.callbacks.guard import Guard
    from app.sim.simulation import Unstable

    sim = Simulation(None, 1e-3, 0, 0.01, flow=jet_solver())
    sim.add(Guard(max_overlap=0.2, max_speed=100.0, max_gas_speed=20.0), interval=1e-3)
    with pytest.raises(Unstable) as err:
        sim.run()
    msg = str(err.value)
    assert "guard.max_gas_speed = 20" in msg and "fastest in cell (" in msg
    assert "trace_forces" not in msg  # not this guard's suspect: it was not told the trace is on
    i, j, k = (int(x) for x in msg.split("fastest in cell (")[1].split(")")[0].split(","))
    assert i in (7, 8) and j in (7, 8) and k < 16, msg


def test_a_runaway_gas_names_the_force_trace_first_where_it_is_on():
    """The one gas set-up known to run away by itself is the force trace under MacCormack convection
    (benchmarks/gust_stability.py): a preset with it on (boyce_small, the default) gets a guard whose gas-speed and
    non-finite messages name gas.trace_forces = false first; one with it off (verma) gets the usual knobs only."""
    import pathlib

    from app.callbacks.guard import Guard
    from app.config import load
    from app.sim.simulation import Unstable

    presets = pathlib.Path(__file__).resolve().parents[1] / "presets"
    on, off = (Guard.of(load(presets / name), None) for name in ("boyce_small.toml", "verma.toml"))
    assert on.trace_forces and not off.trace_forces

    class Flow:  # both presets have a pressure outlet: no inlet imbalance to check
        def inflow_imbalance(self):
            return 0.0, 0.0

    class Sim:
        flow = Flow()

        def gas_fastest_cell(self):
            return ""

    for guard, named in ((on, True), (off, False)):
        for row in ({"gas_non_finite": True, "gas_cfl": 3.0},
                    {"gas_non_finite": False, "gas_cfl": 3.0, "gas_max_speed": 1e9, "divergence_residual": 0.0}):
            with pytest.raises(Unstable) as err:
                guard._gas_check(Sim(), row, 0.5)
            msg = str(err.value)
            assert ("set gas.trace_forces = false" in msg) == named, msg
            assert "lower run.step" in msg, msg


def test_headless_log_lines_say_where_the_gas_is_fastest(capsys):
    """A long GPU run leaves only its log: each line names the fastest gas cell (the jet's column)."""
    from app.callbacks.progress import Progress

    sim = Simulation(None, 1e-3, 0, 0.003, flow=jet_solver())
    progress = Progress(sim, "jet", 5.0)  # made before the steps: a line needs a step measured since
    sim.run()
    progress(sim)
    line = capsys.readouterr().err.strip().splitlines()[-1]
    # the short form of the line (under 100 characters): "gas <speed> m/s in i,j,k open <fraction> eps <fraction>"
    assert " m/s in " in line and (" in 7," in line or " in 8," in line) and len(line) < 100, line


def test_device_reductions_match_numpy_and_count_non_finite_cells():
    """The per-step diagnostics and the pressure drop are reduced on the device: they must equal the numpy
    figures from the copied fields (a cut-cell cylinder, so the open-area weights vary), and a NaN or
    infinity planted in one cell is counted once."""
    from app.sim import gas as flow
    from app.sim.geometry import CylinderWall

    cfg = flow.FlowConfig(shape=(12, 12, 10), h=0.005, rho=1.2, mu=1.8e-5, gravity=(0, 0, -9.81), tol=1e-8,
                          walls=(CylinderWall(center=(0.03, 0.03), radius=0.028),),
                          bcs={"bottom": flow.velocity_inlet((0, 0, 0.5)), "top": flow.pressure_outlet()})
    s = flow.FlowSolver(cfg)
    for _ in range(3):
        s.step(1e-3)
    u, p, vf = s.cell_velocity(), s.pressure(), s.fields.vol_frac.to_numpy()
    speed, bad = s.gas_extremes()
    assert speed == pytest.approx(np.sqrt((u ** 2).sum(-1)).max(), rel=1e-12) and bad == 0
    means = [(p[:, :, k] * vf[:, :, w]).sum() / vf[:, :, w].sum() for k, w in ((0, 0), (1, 0), (-2, -1), (-1, -1))]
    np.testing.assert_allclose(s.end_layer_pressures(), means, rtol=1e-12)
    open_bottom = vf[:, :, 0][vf[:, :, 0] > 0]
    assert open_bottom.min() < 0.5 and open_bottom.max() == 1.0  # the weights do vary
    s.fields.u_gas[3, 4, 5] = [np.nan, 0.0, 0.0]
    s.fields.p[6, 6, 6] = np.inf
    assert s.gas_extremes()[1] == 2


@pytest.mark.restart
def test_a_resumed_run_splits_its_steps_as_the_straight_run_did(tmp_path):
    """The split of the fluid step was not in the checkpoint: a run resumed while its steps were split started
    again from whole steps, and went another way (fluidize at run.step = 50 ms, resumed at 0.25 s: grains 17 mm
    apart at 0.35 s, 9 fewer gas steps). Now the split is kept, and the resumed run is the straight run, bit for
    bit (one thread). A gas alone (a jet into a box) shows it; no grain kernels to compile."""
    import h5py

    from app.run import run

    from dem_helpers import toml_text

    preset = tmp_path / "jet.toml"
    preset.write_text(toml_text({
        "run": {"duration": 0.012, "step": 2e-3, "precision": "float64", "threads": 1},  # as conftest's Taichi
        "domain": {"lo": [-0.012, -0.012, 0.0], "hi": [0.012, 0.012, 0.048], "gravity": [0.0, 0.0, -9.81]},
        "vessel": {"shape": "box"},
        "gas": {"cell_size": 4e-3, "max_cfl": 0.5, "max_split": 8},
        "boundary": {"bottom": {"kind": "velocity_inlet", "velocity": [0.0, 0.0, 0.3],
                                "jet_velocity": [0.0, 0.0, 3.0], "jet_radius": 3e-3},
                     "top": {"kind": "pressure_outlet"}},
        "output": {"checkpoint_interval": 0.006, "checkpoint_wall_interval": 0.0, "series_interval": 2e-3}}))
    assert run(str(preset), [], out=str(tmp_path / "straight"), arch="cpu") == 0
    assert run(str(preset), ["run.duration=0.006"], out=str(tmp_path / "split"), arch="cpu") == 0
    with h5py.File(tmp_path / "split" / "checkpoint.h5") as f:
        assert f["gas/adaptive_split"][0] > 1  # resumed while split
    assert run(None, ["run.duration=0.012"], resume=str(tmp_path / "split"), arch="cpu") == 0
    with h5py.File(tmp_path / "straight" / "checkpoint.h5") as a, h5py.File(tmp_path / "split" / "checkpoint.h5") as b:
        assert a.attrs["step"] == b.attrs["step"] == 6 and "grains" not in a
        differ = [k for k in a["gas"] if not np.array_equal(a["gas"][k][...], b["gas"][k][...])]
        assert not differ, differ

"""Unit tier: derived values against independent hand formulas."""
import math
import pathlib

import numpy as np
import pytest

from app.config import ConfigError, load, load_text
from app.config.derived import damping_from_restitution, derive, effective_moduli, hertz_duration

from dem_helpers import merged, toml_text

pytestmark = pytest.mark.unit


def cfg_of(**changes):
    return load_text(toml_text(merged(**changes)), "t.toml")


def test_effective_moduli_identical_materials():
    e, nu = 5e6, 0.3
    es, gs = effective_moduli(e, nu, e, nu)
    assert es == pytest.approx(e / (2 * (1 - nu ** 2)), rel=1e-12)
    assert gs == pytest.approx(e / (4 * (2 - nu) * (1 + nu)), rel=1e-12)


def test_mass_collision_time_and_step():
    cfg = cfg_of(particles={"diameter": 1e-3, "density": 2526.0}, contact={"youngs_modulus": 1e7, "poisson_ratio": 0.25})
    d = derive(cfg)
    m = 2526.0 * math.pi * 1e-9 / 6  # kg
    es = 1e7 / (2 * (1 - 0.25 ** 2))
    tc = 2.868 * ((m / 2) ** 2 / (0.25e-3 * es ** 2 * 1.0)) ** 0.2  # pair of equal grains at 1 m/s
    assert d.mass(1e-3) == pytest.approx(m, rel=1e-12)
    assert d.collision_time == pytest.approx(tc, rel=1e-12)
    assert d.substeps * d.dt == pytest.approx(1e-3, rel=1e-12)
    assert 0.05 * tc / 2 < d.dt <= 0.05 * tc * (1 + 1e-12)  # the default dt_fraction, rounded to whole substeps


def _rebound_rk4(model, c, h=2e-4):
    """Independent integration of the dimensionless clamped contact (fixed-step RK4)."""
    def acc(x, v):
        xp = max(x, 0.0)
        f = xp + 2 * c * v if model == "linear" else xp ** 1.5 + c * xp ** 0.25 * v
        return -max(f, 0.0)

    x, v = 0.0, 1.0
    while True:
        k1x, k1v = v, acc(x, v)
        k2x, k2v = v + 0.5 * h * k1v, acc(x + 0.5 * h * k1x, v + 0.5 * h * k1v)
        k3x, k3v = v + 0.5 * h * k2v, acc(x + 0.5 * h * k2x, v + 0.5 * h * k2v)
        k4x, k4v = v + h * k3v, acc(x + h * k3x, v + h * k3v)
        x += h / 6 * (k1x + 2 * k2x + 2 * k3x + k4x)
        v += h / 6 * (k1v + 2 * k2v + 2 * k3v + k4v)
        if x <= 0 and v < 0:
            return -v


@pytest.mark.parametrize("model", ["linear", "hertz_mindlin"])
@pytest.mark.parametrize("e", [0.5, 0.7, 0.9])
def test_damping_reproduces_restitution(model, e):
    c = damping_from_restitution(model, e)
    assert _rebound_rk4(model, c) == pytest.approx(e, abs=2e-3)  # RK4 step error dominates


def test_linear_damping_close_to_unclamped_formula_for_weak_damping():
    # with little damping the clamp hardly matters: zeta ~ -ln e / sqrt(pi^2 + ln^2 e)
    e = 0.98
    zeta = -math.log(e) / math.sqrt(math.pi ** 2 + math.log(e) ** 2)
    assert damping_from_restitution("linear", e) == pytest.approx(zeta, rel=0.05)


def test_dt_above_limit_is_refused_and_forcing_accepts_it():
    with pytest.raises(ConfigError) as err:
        derive(cfg_of(dem={"dt": 1e-4}))
    assert "dem.dt" in str(err.value) and "stable limit" in str(err.value)
    d = derive(cfg_of(dem={"dt": 1e-4, "force_dt": True}))
    assert d.dt == pytest.approx(1e-4)


@pytest.mark.parametrize("dem", [{"dt_fraction": 0.2}, {"max_dt_fraction": 0.001}])
def test_an_automatic_step_above_the_stable_fraction_names_dt_fraction_not_dt(dem):
    """dem.dt = 0: the step is dt_fraction x the collision time, so the refusal names dem.dt_fraction and both
    fractions (it had named dem.dt and said to lower it, while it was 0)."""
    with pytest.raises(ConfigError) as err:
        derive(cfg_of(dem=dem))
    assert err.value.key == "dem.dt_fraction"
    assert "dem.max_dt_fraction" in err.value.message and "lower dem.dt " not in str(err.value)
    derive(cfg_of(dem={**dem, "force_dt": True}))  # forced: taken as given


GAS = {"domain": {"lo": [-0.01, -0.01, 0.0], "hi": [0.01, 0.01, 0.04], "gravity": [0.0, 0.0, -9.81]},
       "gas": {"cell_size": 0.005}, "boundary": {"bottom": {"kind": "velocity_inlet", "velocity": [0.0, 0.0, 0.1]},
                                                 "top": {"kind": "pressure_outlet"}}}


@pytest.mark.parametrize("changes, key, words", [
    ({"gas": {"cell_size": 1e-300}}, "gas.cell_size", "gas cells, beyond"),  # had been a ZeroDivisionError
    ({"gas": {"cell_size": 1e-9}}, "gas.cell_size", "more than 1e+15 gas cells"),  # 1.6e22 cells
    ({"gas": {"tolerance": 0.01}}, "gas.tolerance", "guard.max_divergence = 0.001"),
    ({"gas": {"tolerance": 1e-4}, "guard": {"max_divergence": 1e-5}}, "gas.tolerance", "above"),
    ({"gas": {"density": 1e-300}}, "gas.density", ""),  # below the schema's 1e-6 kg/m^3
    ({"gas": {"viscosity": 1e30}}, "gas.viscosity", ""),  # above its 1e6 Pa s
    ({"run": {"step": 1e-300}}, "run.step", ""),  # below its 1e-12 s
    ({"boundary": {"bottom": {"kind": "velocity_inlet", "velocity": [0.0, 0.0, 1e6]}}}, "boundary.z-",
     "blows at 1e+06 m/s, above guard.max_gas_speed = 300"),
    ({"boundary": {"bottom": {"kind": "velocity_inlet", "velocity": [0.0, 0.0, 1.0],
                              "schedule": [[0.0, 0.0], [0.001, 1e9]]}}}, "boundary.z-", "schedule's largest fraction"),
    ({"boundary": {"bottom": {"kind": "velocity_inlet", "velocity": [0.0, 0.0, 1.0], "jet_radius": 0.003,
                              "jet_velocity": [0.0, 0.0, 60.0]}}, "guard": {"max_gas_speed": 50.0}}, "boundary.z-",
     "jet_velocity blows at 60 m/s"),
    ({"probes": {"rcfd_from": 0.0, "rcfd_interval": 5e-4}}, "probes.rcfd_interval", "shorter than run.step"),
])
def test_values_the_kernels_cannot_run_are_refused_naming_the_key(changes, key, words):
    """Found by running every schema key at its range's edges (stop 54): each of these ran into a traceback, a
    non-finite gas at the first step blamed on other knobs, or a guard stop naming gas.max_iterations."""
    base = merged(**GAS)
    for section, table in changes.items():
        base.setdefault(section, {}).update(table)
    with pytest.raises(ConfigError) as err:
        load_text(toml_text(base), "t.toml")
    assert err.value.key == key and words in str(err.value), str(err.value)


def test_the_edges_just_inside_the_new_bounds_load():
    base = merged(**GAS)
    for changes in ({"gas": {"tolerance": 1e-3, "density": 1e-6, "viscosity": 1e6}},
                    {"run": {"step": 1e-12, "duration": 1e-11}}, {"gas": {"cell_size": 0.0025}},
                    {"boundary": {"bottom": {"kind": "velocity_inlet", "velocity": [0.0, 0.0, 1.0], "jet_radius": 0.003,
                                             "jet_velocity": [0.0, 0.0, 300.0]}}},  # at the guard's limit
                    {"probes": {"rcfd_from": 0.0, "rcfd_interval": 1e-3}}):
        load_text(toml_text({**base, **{k: {**base.get(k, {}), **v} for k, v in changes.items()}}), "t.toml")


def test_a_dem_step_below_a_ten_thousandth_of_the_collision_time_is_refused():
    """dem.dt = 1e-12 s ran settle.toml at 2 x 10^9 substeps a step: a step no Ctrl-C or SIGTERM interrupts (the
    signal is taken between steps), under a note calling 2,500 grains a 'GPU-sized scene'. dem.dt_fraction's lower
    bound (1e-4) now holds for an explicit dem.dt too; at the bound it is taken."""
    tc = derive(cfg_of()).collision_time
    with pytest.raises(ConfigError) as err:
        derive(cfg_of(dem={"dt": 1e-12}))
    assert err.value.key == "dem.dt" and "times shorter than the" in str(err.value) and "dem.dt = 0" in err.value.hint
    assert derive(cfg_of(dem={"dt": 1.01e-4 * tc})).dt <= 1.01e-4 * tc


def test_mass_fractions_convert_to_number_fractions():
    cfg = cfg_of(particles={"diameter": 0.0, "diameters": [1e-3, 2e-3], "fractions": [0.5, 0.5], "fractions_by": "mass"})
    d = derive(cfg)
    # equal mass in both classes -> 8x as many small grains
    assert d.number_fractions[0] / d.number_fractions[1] == pytest.approx(8.0)
    assert d.polydisperse


@pytest.mark.parametrize("change,key", [
    ({"particles": {"cuont": 3}}, "particles.cuont"),
    ({"particles": {"density": "heavy"}}, "particles.density"),
    ({"particles": {"density": -5.0}}, "particles.density"),
    ({"vessel": {"shape": "cylindre"}}, "vessel.shape"),
    ({"domain": {"hi": [0.05, 0.05, -0.06]}}, "domain.hi"),
    ({"contact": {"rolling_friction": 0.1}}, "contact.rolling_model"),
])
def test_bad_values_name_their_key(change, key):
    with pytest.raises(ConfigError) as err:
        cfg_of(**change)
    assert key in str(err.value)


def test_unknown_key_suggests_the_right_one():
    with pytest.raises(ConfigError) as err:
        cfg_of(particles={"desnity": 2500.0})
    assert "did you mean 'density'" in str(err.value)


def test_override_is_validated_like_the_file():
    text = toml_text(merged())
    cfg = load_text(text, "t.toml", ["run.duration=0.5"])
    assert cfg.run.duration == 0.5
    with pytest.raises(ConfigError) as err:
        load_text(text, "t.toml", ["run.duration=-1"])
    assert "run.duration" in str(err.value)


def test_grain_volume_and_mass_one_formula_for_numpy_and_kernels():
    """A grain's volume is 4/3 pi r^3 (a 1 mm radius: 4.18879e-9 m^3 by hand); the coupling kernels' ti.func twin
    agrees with numpy in float64 to rounding (three products, each within half an ulp, which Taichi's fast math
    may reorder: 1e-15 is about four ulps), and Derived.mass by diameter agrees."""
    import taichi as ti

    from app.config.derived import grain_mass, grain_volume
    from app.sim.coupling import grain_volume_func

    assert grain_volume(1e-3) == pytest.approx(4.0 / 3.0 * math.pi * 1e-9, rel=1e-15)
    assert grain_mass(1e-3, 2526.0) == pytest.approx(2526.0 * 4.18879020478639e-9, rel=1e-14)
    r = np.linspace(1e-4, 3e-3, 16)
    rf, out = ti.field(float, 16), ti.field(float, 16)
    rf.from_numpy(r)

    @ti.kernel
    def run():
        for i in rf:
            out[i] = grain_volume_func(rf[i])

    run()
    assert np.allclose(out.to_numpy(), grain_volume(r), rtol=1e-15, atol=0)
    d = derive(cfg_of(particles={"diameter": 1e-3, "density": 2526.0}))
    assert d.mass(2 * r) == pytest.approx(2526.0 * grain_volume(r), rel=1e-15)
    assert d.mass_min == pytest.approx(float(grain_mass(0.5e-3, 2526.0)), rel=1e-15)


def test_a_scene_without_grains_has_no_floor_unless_one_is_given():
    """The floor plane holds grains up: a gas-only cylinder has the cylinder alone (a floor on the bottom face
    would be a second wall there and would close a periodic z axis); given vessel.floor, or grains, it has one."""
    from app.scene import Scene

    gas_only = ('[run]\nduration = 0.1\nstep = 0.01\n[domain]\nlo = [0.0, 0.0, 0.0]\nhi = [0.1, 0.1, 0.1]\n'
                '[vessel]\nshape = "cylinder"\ncenter = [0.05, 0.05]\nradius = 0.04\n{floor}[gas]\ncell_size = 0.01\n')
    names = lambda text: [w.name for w in Scene(load_text(text, "t.toml")).walls]  # noqa: E731
    assert names(gas_only.format(floor="")) == ["cylinder"]
    assert names(gas_only.format(floor="floor = 0.02\n")) == ["cylinder", "floor"]
    grains = gas_only.format(floor="") + "[particles]\ndiameter = 0.002\ndensity = 2500.0\ncount = 10\n"
    assert names(grains) == ["cylinder", "floor"]


def test_a_recorded_window_that_does_not_fit_in_the_run_is_noted_at_the_start():
    """output.average_from at or after run.duration (a preset shortened with --set), or probes.rcfd_from leaving
    fewer than the 3 frames `fbed rcfd` needs: the run says so at its start (the time means, the analysis reading
    that window, the rCFD database would hold nothing), which showed only at its end before; nothing where the
    windows fit, or are automatic (negative). Notes, not errors: shortening a preset for a quick look is fine."""
    import pathlib

    from app.config import load
    from app.callbacks.progress import window_notes

    presets = pathlib.Path(__file__).resolve().parents[1] / "presets"
    def windows(cfg):  # (fluidize's inlet opens at 0.15 s: shortened below it, that is noted too)
        return [n for n in window_notes(cfg) if "the inlet blows nothing" not in n]

    notes = windows(load(presets / "fluidize.toml", ["run.duration=0.01"]))  # average_from = 0.3 s there
    assert len(notes) == 1 and "output.average_from = 0.3 s" in notes[0] and "run.duration = 0.01 s" in notes[0]
    notes = window_notes(load(presets / "mri_small.toml", ["run.duration=0.45"]))  # at the end: nothing either
    assert len(notes) == 1 and "the mri analysis nothing to analyse" in notes[0]
    assert window_notes(load(presets / "fluidize.toml", ["run.duration=0.31"])) == []
    assert windows(load(presets / "fluidize.toml", ["run.duration=0.01", "output.average_from=-1"])) == []
    rcfd = presets / "rcfd_small.toml"  # frames of 5 ms
    for start, frames in ((0.59, 2), (0.6, 0), (0.7, 0)):
        notes = window_notes(load(rcfd, ["run.duration=0.6", f"probes.rcfd_from={start}"]))
        assert len(notes) == 1 and f"{frames} of probes.rcfd_interval" in notes[0], notes
    assert window_notes(load(rcfd, ["run.duration=0.6", "probes.rcfd_from=0.585"])) == []  # 3 frames


def test_a_video_of_fewer_than_two_frames_is_noted_at_the_start():
    """`--video` on fluidize shortened to 4 ms with video.interval = 10 ms wrote no video and said "done" (with gas
    the first frame waits for the first step's void fraction: frames at 10, 20 ms, ...); at 20 ms on settle (no gas:
    a frame at t = 0) the video was one still frame. The run now says so at its start; two frames, no note."""
    from app.callbacks.progress import window_notes
    from app.config import load

    presets = pathlib.Path(__file__).resolve().parents[1] / "presets"
    on = ["video.enabled=true", "output.average_from=-1"]
    for preset, duration, interval, said in (("fluidize", 0.004, 0.01, "no video will be written"),
                                             ("fluidize", 0.01, 0.01, "one frame"),
                                             ("settle", 0.01, 0.02, "one frame")):
        notes = [n for n in window_notes(load(presets / f"{preset}.toml", on + [f"run.duration={duration}",
                 f"video.interval={interval}"])) if "the inlet blows nothing" not in n]  # (fluidize's opens at 0.15 s)
        assert len(notes) == 1 and said in notes[0] and "video.interval" in notes[0], notes
    assert [n for n in window_notes(load(presets / "fluidize.toml", on + ["run.duration=0.02", "video.interval=0.01"]))
            if "the inlet blows nothing" not in n] == []
    assert window_notes(load(presets / "settle.toml", on + ["run.duration=0.01", "video.interval=0.01"])) == []
    # counted as the frames are fired: 2.5 ms in 1 ms steps is every 2 steps, two frames in 4 ms (the raw interval
    # gave one, a still, that the run would not have made)
    notes = window_notes(load(presets / "fluidize.toml", on + ["run.duration=0.004", "video.interval=0.0025"]))
    assert not [n for n in notes if "video.interval" in n and "frame" in n], notes


def test_an_inlet_or_a_jet_that_opens_after_the_end_is_noted():
    """fluidize shortened to 0.1 s (its inlet starts at 0.15 s) ran with no gas blown in, and boyce shortened below
    its jet_start (3.4 s) never opened the jet, each without a word until its analysis found nothing. Noted at the
    start now; an inlet or jet that opens before the end, none."""
    from app.callbacks.progress import window_notes

    presets = pathlib.Path(__file__).resolve().parents[1] / "presets"
    notes = window_notes(load(presets / "fluidize.toml", ["run.duration=0.1", "output.average_from=-1"]))
    assert notes == ["fbed: note: boundary.z-.start = 0.15 s is not before run.duration = 0.1 s: the inlet blows "
                     "nothing in this run"]
    assert window_notes(load(presets / "fluidize.toml", ["run.duration=0.16", "output.average_from=-1"])) == []
    notes = window_notes(load(presets / "boyce.toml", ["run.duration=3.4", "output.average_from=-1"]))
    assert len(notes) == 1 and "boundary.z-.jet_start = 3.4 s" in notes[0] and "never opens" in notes[0]
    assert window_notes(load(presets / "boyce.toml", ["run.duration=3.41", "output.average_from=-1"])) == []


def test_a_preset_saved_with_a_byte_order_mark_reads_as_without(tmp_path):
    """Windows editors may save UTF-8 with a byte-order mark: that preset was refused as "not valid TOML: Invalid
    statement (at line 1, column 1)", pointing at a character nobody can see. It now loads as the same file
    without the mark; CRLF line ends too."""
    settle = pathlib.Path(__file__).resolve().parents[1] / "presets" / "settle.toml"
    text = settle.read_text()
    (tmp_path / "bom.toml").write_bytes(b"\xef\xbb\xbf" + text.encode())
    (tmp_path / "crlf.toml").write_bytes(text.replace("\n", "\r\n").encode())
    plain = load(settle)
    for name in ("bom.toml", "crlf.toml"):
        cfg = load(tmp_path / name)
        assert {k: v for k, v in vars(cfg).items() if k != "source"} == \
            {k: v for k, v in vars(plain).items() if k != "source"}, name


def test_a_duration_that_is_not_a_whole_number_of_steps_is_noted_and_ends_on_the_next_step():
    """run.duration = 0.0105 s in steps of 2 ms: the run takes the next whole step (6 steps, t = 0.012 s), as the
    Simulation counts them (`run_steps`), and says so at the start instead of silently running past the duration;
    a whole number of steps, or a duration that rounding leaves 1e-15 off one, gives no note."""
    import pathlib

    from app.callbacks.progress import window_notes
    from app.config import load
    from app.config.derived import run_steps

    settle = pathlib.Path(__file__).resolve().parents[1] / "presets" / "settle.toml"  # run.step = 2 ms
    for duration, steps in ((0.0105, 6), (0.0005, 1), (0.0121, 7)):
        assert run_steps(duration, 0.002) == steps
        notes = window_notes(load(settle, [f"run.duration={duration}"]))
        assert len(notes) == 1 and f"run.duration = {duration:g} s" in notes[0], notes
        assert f"ends at t = {steps * 0.002:g} s, after {steps} step" in notes[0], notes
    for duration, steps in ((0.3, 150), (0.012, 6), (0.1 + 0.2, 150)):  # 0.1 + 0.2 = 0.30000000000000004
        assert run_steps(duration, 0.002) == steps
        assert window_notes(load(settle, [f"run.duration={duration!r}"])) == []


def test_a_scene_too_large_for_the_cpus_memory_is_refused_before_its_grains_are_made(monkeypatch):
    """On the CPU, a scene whose estimated peak memory (app.scene.CPU_BASE_BYTES + 3 x bytes_per_grain a grain,
    measured) exceeds what the system has available is a ConfigError naming particles.count, raised before the
    grains are generated (past it the out-of-memory killer would end the run without a word); it passes where
    the memory is there. The system's figure is replaced here by small and large ones."""
    import app.scene as scene_mod

    def no_fill(*args, **kwargs):
        raise AssertionError("the grains were generated before the memory check")

    cfg = load_text(toml_text(merged()), "t.toml")
    monkeypatch.setattr(scene_mod, "available_memory", lambda: 0.3e9)
    monkeypatch.setattr(scene_mod, "lattice_fill", no_fill)
    with pytest.raises(ConfigError) as err:
        scene_mod.Scene(cfg)
    assert "particles.count" in str(err.value) and "GB of memory on the CPU" in str(err.value), str(err.value)
    monkeypatch.undo()
    monkeypatch.setattr(scene_mod, "available_memory", lambda: 1e12)
    scene = scene_mod.Scene(cfg)
    assert scene.n > 0 and len(scene.initial["position"]) == scene.n


def test_a_gas_grid_too_large_for_the_cpus_memory_is_refused_before_it_is_built(monkeypatch):
    """gas.cell_size = 1e-5 m in fluidize's column (5 x 10^11 cells) ended in a numpy traceback ("Unable to allocate
    3.68 TiB") while the cut cells were built. The CPU memory estimate now counts the gas cells too (520 B a cell in
    float32, measured): it is a ConfigError naming gas.cell_size and the grid, in a scene with grains and in one with
    gas only; the preset's own 5 mm cells pass."""
    import app.scene as scene_mod

    fluidize = pathlib.Path(__file__).resolve().parents[1] / "presets" / "fluidize.toml"
    gas_only = ('[run]\nduration = 0.001\n[domain]\nlo = [-0.05, -0.05, 0.0]\nhi = [0.05, 0.05, 0.4]\n'
                '[vessel]\nshape = "box"\n[gas]\ncell_size = {h}\n[boundary]\n'
                'bottom = {{ kind = "velocity_inlet", velocity = [0.0, 0.0, 0.5] }}\ntop = {{ kind = "pressure_outlet" }}\n')
    # (no smoothing: its 3 mm on 1e-5 m cells are 3e5 passes a step, refused at load, naming gas.cell_size too)
    for cfg, grid in ((load(fluidize, ["gas.cell_size=1e-5", "coupling.smoothing_width=0"]), "(4500 x 4500 x 25000)"),
                      (load_text(gas_only.format(h=1e-4), "gas.toml"), "(1000 x 1000 x 4000)")):
        with pytest.raises(ConfigError) as err:
            scene_mod.Scene(cfg)
        assert err.value.key == "gas.cell_size" and grid in str(err.value), str(err.value)
    cells = 20 * 20 * 80  # 5 mm cells pass where the memory is what the estimate says they need, and not below it
    need = scene_mod.CPU_BASE_BYTES + cells * scene_mod.CPU_BYTES_PER_GAS_CELL["float32"]
    monkeypatch.setattr(scene_mod, "available_memory", lambda: need)
    assert scene_mod.Scene(load_text(gas_only.format(h=5e-3), "gas.toml")).flow.shape == (20, 20, 80)
    monkeypatch.setattr(scene_mod, "available_memory", lambda: 0.99 * need)
    with pytest.raises(ConfigError, match="32,000 gas cells"):
        scene_mod.Scene(load_text(gas_only.format(h=5e-3), "gas.toml"))


GAS_BOX = ('[run]\nduration = 0.001\nprecision = "{p}"\n[domain]\nlo = [-0.05, -0.05, 0.0]\nhi = [0.05, 0.05, {top}]\n'
           '[vessel]\nshape = "box"\n[gas]\ncell_size = 5e-3\n[boundary]\n'
           'bottom = {{ kind = "velocity_inlet", velocity = [0.0, 0.0, 0.5] }}\ntop = {{ kind = "pressure_outlet" }}\n')


def test_a_scene_too_large_for_the_gpus_memory_is_refused_before_it_is_built(monkeypatch):
    """On CUDA no memory was checked: gas.cell_size = 1e-5 m in fluidize's column ended in a numpy traceback (the
    host's cut cells of 5 x 10^11 cells), and a scene too large for the GPU in Taichi's. Now both the GPU's memory
    (Taichi's pool: 0.9 of the GPU's) and the host's are checked, naming the key. Taichi on CUDA and the GPU's
    memory are stood in for here (no GPU in CI): a GPU of 80 GB, then of 0.3 GB."""
    import app.scene as scene_mod
    from app.sim import runtime

    monkeypatch.setattr(runtime, "current", lambda: ("cuda", "float32", None, False))
    monkeypatch.setattr(scene_mod, "available_memory", lambda: 1e12)  # the host has room: the GPU is the limit
    monkeypatch.setattr(runtime, "cuda_memory", lambda: 80e9)
    root = pathlib.Path(__file__).resolve().parents[1] / "presets"
    with pytest.raises(ConfigError) as err:
        scene_mod.Scene(load(root / "fluidize.toml", ["gas.cell_size=1e-5", "coupling.smoothing_width=0"]))
    assert err.value.key == "gas.cell_size" and "(4500 x 4500 x 25000)" in str(err.value), str(err.value)
    assert "of the GPU's memory" in str(err.value) and "Taichi's pool (0.9 of the GPU's 80 GB)" in str(err.value)
    verma = load(root / "verma.toml")
    assert scene_mod.Scene(verma).n > 9e5  # the million grains fit an 80 GB GPU
    monkeypatch.setattr(runtime, "cuda_memory", lambda: 0.3e9)
    with pytest.raises(ConfigError) as err:
        scene_mod.Scene(verma)
    assert err.value.key == "particles.count" and "of the GPU's memory" in str(err.value), str(err.value)
    assert "a GPU with more memory" in err.value.hint
    monkeypatch.setattr(runtime, "cuda_memory", lambda: None)  # a driver that cannot say: the host is still checked
    monkeypatch.setattr(scene_mod, "available_memory", lambda: 0.3e9)
    with pytest.raises(ConfigError, match="of memory on the CPU"):
        scene_mod.Scene(verma)


def _gas_cell_device_bytes(precision: str) -> float:
    """Device bytes a gas cell takes (Taichi running in ``precision``): the slope of the gas solver's ndarrays over
    boxes of 16,000 and 48,000 cells, plus the coupling's per-cell fields."""
    from app.scene import Scene, flow_config
    from app.sim import runtime
    from app.sim.coupling import CouplingFields
    from app.sim.gas import FlowSolver

    sizes = []
    for top in (0.2, 0.6):
        before = runtime.ndarray_bytes()
        scene = Scene(load_text(GAS_BOX.format(p=precision, top=top), "box.toml"))
        solver = FlowSolver(scene.flow)
        sizes.append((math.prod(scene.flow.shape), runtime.ndarray_bytes() - before))
        del solver
    fields = CouplingFields((4, 5, 6))
    per = [getattr(fields, k) for k in ("solid", "solid_tmp", "vec_tmp", "k_sum", "k_v", "eps_prev")]
    coupling = sum(f.shape[0] * f.shape[1] * f.shape[2] * getattr(f, "n", 1) * (8 if precision == "float64" else 4)
                   for f in per) / 120
    return (sizes[1][1] - sizes[0][1]) / (sizes[1][0] - sizes[0][0]) + coupling


@pytest.mark.parametrize("precision", ["float64", "float32"])
def test_the_gpu_memory_of_a_gas_cell_is_what_the_solver_allocates(precision):
    """app.scene.GAS_DEVICE_BYTES_PER_CELL against the arrays the gas solver and the coupling allocate, counted: at
    least them (the check must not let through a grid that cannot fit) and within 3% (nor refuse one that fits).
    float32 in a process of its own (this worker's Taichi runs in float64)."""
    import subprocess
    import sys

    from app.scene import GAS_DEVICE_BYTES_PER_CELL

    if precision == "float64":
        per_cell = _gas_cell_device_bytes("float64")
    else:
        code = ("import sys; sys.path.insert(0, sys.argv[1]); from app.sim import runtime; runtime.init('cpu', "
                "'float32', threads=1); import test_config; print(test_config._gas_cell_device_bytes('float32'))")
        tests = pathlib.Path(__file__).resolve().parent
        r = subprocess.run([sys.executable, "-c", code, str(tests)], capture_output=True, text=True, cwd=tests,
                           timeout=300)
        assert r.returncode == 0, r.stderr[-2000:]
        per_cell = float(r.stdout.split()[-1])
    assert per_cell <= GAS_DEVICE_BYTES_PER_CELL[precision] <= 1.03 * per_cell, per_cell


def test_a_sampled_vessel_file_that_is_wrong_is_refused_saying_what_is_wrong(tmp_path):
    """vessel.sdf_file: a spacing given as a one-element array of 0 was a TypeError traceback, NaN clearances
    a vessel where "only 0 grains fit", a file that is no .npz a message about pickled data. Each is now a
    ConfigError naming the file and the array; a good file loads."""
    from app.scene import build_walls

    settle = pathlib.Path(__file__).resolve().parents[1] / "presets" / "settle.toml"
    good = dict(values=np.ones((3, 4, 5)), origin=np.zeros(3), spacing=0.01)
    cases = {"spacing": (dict(good, spacing=np.array([0.0])), "'spacing' must be one number > 0"),
             "nan": (dict(good, values=np.full((3, 4, 5), np.nan)), "60 not finite"),
             "flat": (dict(good, values=np.ones((3, 4))), "'values' must be a 3-D array"),
             "origin": (dict(good, origin=np.zeros(2)), "'origin' must be 3 finite numbers"),
             "missing": ({k: v for k, v in good.items() if k != "origin"}, "no array 'origin' in the file"),
             "good": (good, None)}
    for name, (arrays, said) in cases.items():
        np.savez(tmp_path / f"{name}.npz", **arrays)
    (tmp_path / "text.npz").write_text("not numpy")
    cases["text"] = (None, "not an .npz archive")
    for name, (_, said) in cases.items():
        cfg = load(settle, ["vessel.shape=sampled", f"vessel.sdf_file={tmp_path / (name + '.npz')}"])
        if said is None:
            assert build_walls(cfg)[0].name == "good"
            continue
        with pytest.raises(ConfigError, match=said) as err:
            build_walls(cfg)
        assert err.value.key == "vessel.sdf_file" and name in err.value.file, str(err.value)


def test_an_outlet_pressure_beyond_a_megapascal_is_refused():
    """boundary.<face>.pressure = 1e7 Pa ran, and in float32 the bed's pressure drop lost its digits (fluidize's
    read 5.1 Pa for 11.9 at one step): the solver is incompressible, only pressure differences matter, and 1e7 is
    no gauge pressure. |p| <= 1e6 Pa is taken (atmospheric entered as absolute, 101325 Pa, moved fluidize's drop by
    0.2%), beyond is refused naming the key."""
    fluidize = pathlib.Path(__file__).resolve().parents[1] / "presets" / "fluidize.toml"
    assert dict(load(fluidize, ["boundary.top.pressure=101325"]).boundary)["z+"].pressure == 101325.0
    for value in ("1e7", "-2e6"):
        with pytest.raises(ConfigError, match="out of range") as err:
            load(fluidize, [f"boundary.top.pressure={value}"])
        assert err.value.key == "boundary.top.pressure" and "gauge" in err.value.hint


def test_gas_blown_in_with_no_pressure_outlet_is_refused():
    """fluidize with its top made a wall (or free_slip) ran, and the guard stopped the first step saying the pressure
    solve had too few iterations: gas blown in and let out nowhere has no incompressible solution. Refused at load,
    naming the inlet; inlets of mixed sign (one drawing gas out) may balance, and are taken."""
    fluidize = pathlib.Path(__file__).resolve().parents[1] / "presets" / "fluidize.toml"
    for top, face in (('{kind="wall"}', "z-"), ('{kind="free_slip"}', "z-"),
                      ('{kind="velocity_inlet",velocity=[0,0,-0.5]}', "z+")):  # blowing in from the top too
        with pytest.raises(ConfigError, match="let out nowhere: no face is a pressure_outlet") as err:
            load(fluidize, [f"boundary.top={top}"])
        assert err.value.key == f"boundary.{face}" and "pressure_outlet" in err.value.hint
    jet_only = 'boundary.bottom={kind="velocity_inlet",jet_velocity=[0,0,5],jet_radius=0.004}'
    with pytest.raises(ConfigError, match="let out nowhere"):
        load(fluidize, [jet_only, 'boundary.top={kind="wall"}'])
    drawn = load(fluidize, ['boundary.top={kind="velocity_inlet",velocity=[0,0,1.1]}'])  # out through the top
    assert {b.kind for _, b in drawn.boundary} == {"velocity_inlet"}


def test_an_inviscid_gas_with_grains_is_refused_and_alone_is_taken():
    """gas.viscosity = 0 (its range was >= 0) ran: the grains' Reynolds number rho |w| d / mu is infinite, and four
    of the eight drag laws gave NaN for every grain (the others a drag with no viscous part, Stokes' none). Refused
    where grains feel the gas; a gas alone (the cavity) may be inviscid."""
    from app.sim.drag import LAWS, beta

    with np.errstate(all="ignore"):
        nan = [law for law in LAWS if np.isnan(beta(law, np.array([0.5]), np.array([1.0]), 1e-3, 1.2, 0.0)).any()]
    assert sorted(nan) == ["beetstra", "di_felice", "koch_hill", "tang"]  # the message's list, as it stands
    presets = pathlib.Path(__file__).resolve().parents[1] / "presets"
    with pytest.raises(ConfigError, match="Reynolds number .* infinite") as err:
        load(presets / "fluidize.toml", ["gas.viscosity=0"])
    assert err.value.key == "gas.viscosity" and "1.8e-5" in err.value.hint
    assert load(presets / "validation" / "cavity.toml", ["gas.viscosity=0"]).gas.viscosity == 0.0


def test_a_face_is_set_by_either_of_its_names():
    """A resumed run's config.toml names the faces 'z-', 'z+': `--resume DIR --set boundary.bottom.velocity=...` (the
    resume hint says [boundary] may change) was refused, "face z- given twice (through an alias)"; so was
    `--set boundary.z-.velocity` on a preset that says 'bottom'. Either name now sets the face the preset has, and a
    whole face given under one name replaces it under the other."""
    from app.config import dump

    fluidize = pathlib.Path(__file__).resolve().parents[1] / "presets" / "fluidize.toml"
    written = dump(load(fluidize))  # as a run's config.toml
    assert '"z-" = ' in written and "bottom" not in written
    for text, name in ((written, "bottom"), (fluidize.read_text(), "z-")):
        cfg = load_text(text, "config.toml", [f"boundary.{name}.velocity=[0, 0, 1.3]"])
        assert dict(cfg.boundary)["z-"].velocity == (0.0, 0.0, 1.3) and dict(cfg.boundary)["z-"].start == 0.15
        cfg = load_text(text, "config.toml", [f'boundary.{name}={{kind="velocity_inlet", velocity=[0, 0, 0.9]}}'])
        assert dict(cfg.boundary)["z-"].velocity == (0.0, 0.0, 0.9) and dict(cfg.boundary)["z-"].start == 0.0


def test_a_smoothing_width_of_more_than_a_thousand_passes_is_refused():
    """coupling.smoothing_width = 10 m on fluidize's 5 mm cells is 1.4e7 smoothing passes a fluid step: the run was
    still in its first step after 15 minutes, deaf to SIGTERM (which waits for the step). Passes are width^2 /
    (2 alpha h^2), alpha = 1/7: more than 1000 are refused naming the key; 3 cm (126 passes) is taken."""
    from app.config.derived import smoothing_passes

    fluidize = pathlib.Path(__file__).resolve().parents[1] / "presets" / "fluidize.toml"
    assert smoothing_passes(0.03, 0.005) == math.ceil(0.03 ** 2 * 7 / (2 * 0.005 ** 2)) == 126
    assert load(fluidize, ["coupling.smoothing_width=0.03"]).coupling.smoothing_width == 0.03
    with pytest.raises(ConfigError, match=r"= 10 m on gas.cell_size = 0.005 m cells is 1.4e\+07 smoothing pass") as err:
        load(fluidize, ["coupling.smoothing_width=10"])
    assert err.value.key == "coupling.smoothing_width"
    with pytest.raises(ConfigError, match=r"= 0.003 m on gas.cell_size = 1e-05 m cells is 3.15e\+05") as err:
        load(fluidize, ["gas.cell_size=1e-5"])  # the preset's 3 mm width: the cells are to blame
    assert err.value.key == "gas.cell_size"


def test_a_domain_far_larger_than_the_bed_fills_and_float32_refuses_one_that_cannot_resolve_the_grains():
    """domain.hi = [1e6, 1e6, 1e6] with vessel.shape = 'none': the filler built every lattice point of a layer
    (numpy: "Unable to allocate 1.57 EiB"); it now fills a centred patch of about 4n points where the layer is far
    larger (none of the presets' layers is). In float32 such a domain is refused at load: positions 1e6 m out are
    0.12 m apart, and the grains sat on one point (the run stopped blaming the contact stiffness)."""
    import numpy as np

    from app.scene import lattice_fill

    fluidize = pathlib.Path(__file__).resolve().parents[1] / "presets" / "fluidize.toml"
    huge = ["domain.hi=[1e6,1e6,1e6]", 'vessel.shape="none"', "gas.cell_size=1e5"]
    with pytest.raises(ConfigError, match=r"1e\+06 m from the origin are 0.12 m apart") as err:
        load(fluidize, huge)
    assert err.value.key == "domain.hi"
    cfg = load(fluidize, [*huge, 'run.precision="float64"'])
    pos = lattice_fill(cfg, [], 500, 1e-3, np.random.default_rng(0))
    assert pos.shape == (500, 3) and np.all(np.abs(pos[:, :2] - 5e5) < 0.2)  # about the centre, on the floor
    gaps = np.linalg.norm(pos[:, None] - pos[None], axis=-1) + np.eye(500)
    assert gaps.min() >= 2e-3 and pos[:, 2].max() < 0.01
    # the presets' fills are unchanged to the bit (the heights were np.arange's, now made one at a time)
    cfg = load(fluidize)
    pos = lattice_fill(cfg, [], 5000, 1e-3, np.random.default_rng(0))
    s = cfg.particles.fill_spacing * 2 * 1e-3  # the filler's own spacing, gap and margin
    gap = s - 2e-3
    m = 1e-3 + 0.5 * gap + 1e-9
    lines = [np.arange(lo + m, hi - m + 1e-12, s) for lo, hi in zip(cfg.domain.lo, cfg.domain.hi)]
    grid = np.stack(np.meshgrid(*lines, indexing="ij"), -1).transpose(2, 0, 1, 3).reshape(-1, 3)[:5000]
    assert np.array_equal(pos, grid + np.random.default_rng(0).uniform(-1, 1, (5000, 3)) * 0.45 * gap / 3 ** 0.5)


def test_two_heights_of_one_plane_are_refused():
    """probes.planes = [0.05, 0.05] recorded each frame twice into one run.h5 group (times 0.001, 0.001, 0.002,
    ...); 0.0501 and 0.0504 are one plane too (named z0.050). Refused at load; 1 mm apart is taken."""
    fluidize = pathlib.Path(__file__).resolve().parents[1] / "presets" / "fluidize.toml"
    for planes in ("[0.05,0.05]", "[0.0501,0.1,0.0504]"):
        with pytest.raises(ConfigError, match=r"two heights are the same plane, 0.050 m") as err:
            load(fluidize, [f"probes.planes={planes}", "probes.planes_interval=0.002"])
        assert err.value.key == "probes.planes"
    assert load(fluidize, ["probes.planes=[0.05,0.051]", "probes.planes_interval=0.002"]).probes.planes == [0.05, 0.051]


def test_an_rcfd_tag_outside_the_domain_is_refused():
    """probes.rcfd_tag = 'z>100' tagged no grain: every rCFD index was NaN, and `fbed rcfd validate` found it
    only after its runs. A tag value outside the domain (all or none of it) is refused at load."""
    rcfd_small = pathlib.Path(__file__).resolve().parents[1] / "presets" / "rcfd_small.toml"
    for tag in ("z>100", "x<=1e9", "y<-0.5"):
        with pytest.raises(ConfigError, match="tags all or none of the domain") as err:
            load(rcfd_small, [f'probes.rcfd_tag="{tag}"'])
        assert err.value.key == "probes.rcfd_tag"
    assert load(rcfd_small, ['probes.rcfd_tag="z>=0.03"']).probes.rcfd_tag == "z>=0.03"


def test_a_folder_given_as_the_initial_state_is_named_with_the_bed_file_in_it(tmp_path):
    """particles.initial_state = a run's folder (not its bed.h5) printed HDF5's dump of its read call ("file read
    failed: time = ..., filename = ..., file descriptor = 3, errno = 21, ..., buf = 0x7ff..."), over two lines.
    Now: "is a folder", and the bed file in it named as the fix."""
    from app.scene import Scene

    settle = pathlib.Path(__file__).resolve().parents[1] / "presets" / "settle.toml"
    run = tmp_path / "run"
    run.mkdir()
    (run / "bed.h5").write_bytes(b"")
    with pytest.raises(ConfigError, match="is a folder, not a bed file") as err:
        Scene(load(settle, ["particles.count=0", f"particles.initial_state={run}"]))
    assert err.value.key == "particles.initial_state" and err.value.hint == f"give {run / 'bed.h5'}"


def test_a_bed_file_of_another_kind_is_named_so(tmp_path):
    """particles.initial_state naming a JSON file said "cannot read grains from it: Unable to synchronously open
    file (file signature not found)", HDF5's words; a run.h5 (no grains) said "'no /grains group'" in quotes. Now
    "not an HDF5 file" and "no /grains group", with the hint to give a bed.h5 or checkpoint.h5."""
    import h5py

    from app.scene import Scene

    settle = pathlib.Path(__file__).resolve().parents[1] / "presets" / "settle.toml"
    (tmp_path / "summary.json").write_text("{}")
    with h5py.File(tmp_path / "run.h5", "w") as f:
        f.create_group("series")
    for name, said in (("summary.json", "cannot read grains from it: not an HDF5 file"),
                       ("run.h5", "cannot read grains from it: no /grains group")):
        cfg = load(settle, ["particles.count=0", f'particles.initial_state="{tmp_path / name}"'])
        with pytest.raises(ConfigError) as err:
            Scene(cfg, str(settle))
        assert str(err.value.message) == said and "bed.h5 or checkpoint.h5" in err.value.hint, err.value.message

"""What a new user meets first: --version, the compile notice, the ETA, the length of the log lines, the note
on a GPU-sized scene started on the CPU."""
import os
import pathlib
import subprocess
import sys
import pytest

pytestmark = pytest.mark.unit

ROOT = pathlib.Path(__file__).resolve().parents[1]


def test_version():
    r = subprocess.run([sys.executable, "-m", "app", "--version"], capture_output=True, text=True, cwd=ROOT,
                       env=dict(os.environ, PYTHONPATH=str(ROOT)))
    assert r.returncode == 0 and r.stdout.strip() == "fbed 0.1.0"
    import tomllib

    assert tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"] == "0.1.0"


def test_a_gpu_sized_scene_on_the_cpu_says_its_time_and_its_small_variant():
    from app.callbacks.progress import cpu_estimate_note

    # verma.toml: 965,000 grains, 106 DEM substeps per step, 6500 steps
    note = cpu_estimate_note(ROOT / "presets" / "verma.toml", 965_000, 106, 6500)
    assert note and "GPU-sized" in note and "presets/verma_small.toml" in note and " h " in note
    # its small variant (14,000 grains, 52 substeps, 1000 steps: 90 s of stepping measured) gets no note
    assert cpu_estimate_note(ROOT / "presets" / "verma_small.toml", 14_000, 52, 1000) is None
    # a few grains over many substeps (a stiff contact) are long too, and not for the scene's size
    note = cpu_estimate_note(ROOT / "presets" / "settle.toml", 2_500, 19_618, 15_000)
    assert note and "GPU-sized" not in note and " h on the CPU" in note and "19,618 DEM substeps" in note


class FakeSim:
    flow = None
    duration, total_steps, step_count = 0.6, 600, 0

    @property
    def time(self):
        return self.step_count * 1e-3


def test_progress_lines_wait_for_the_compilation_and_the_eta_and_stay_short(monkeypatch, capsys):
    from app.callbacks import progress as runmod

    clock = [0.0]
    monkeypatch.setattr(runmod.wallclock, "perf_counter", lambda: clock[0])
    sim = FakeSim()
    progress = runmod.Progress(sim, "fluidize", 5.0)
    progress(sim)  # still compiling: no line, no rate, no ETA
    assert capsys.readouterr().err == ""
    clock[0], sim.step_count = 90.0, 1  # the first step took the compilation's 90 s
    progress(sim)
    err = capsys.readouterr().err
    assert "kernels ready after 90 s" in err and "ETA ..." in err  # the rate is not yet measured
    clock[0], sim.step_count = 95.0, 51
    progress(sim)
    assert "ETA ..." in capsys.readouterr().err  # 5 s of stepping: not yet
    clock[0], sim.step_count = 100.0, 101  # 10 steps/s after the compilation: 499 steps left, 50 s
    progress(sim)
    line = capsys.readouterr().err.strip()
    assert "10 st/s" in line and "ETA 50 s" in line, line
    assert len(line) < 100
    # with gas, the fastest cell in short form
    assert runmod._fastest_cell("; fastest in cell (3, 4, 5) at (0.01, 0.02, 0.03) m, open volume fraction 0.52, "
                                "gas fraction 0.61") == " in 3,4,5 open 0.52 eps 0.61"


def test_a_float32_gas_scene_starts_without_a_compiler_warning(tmp_path):
    """Every float32 run with gas printed, from an empty kernel cache, a TaichiWarning "Assign may lose precision:
    f32 <- f64" with a source excerpt: the solver copied host values into its float32 arrays from float64 ones.
    The copies now come in the array's precision. A gas box is built in float32 in a fresh process with Taichi's
    offline cache off (so the copy kernel compiles here), and nothing Taichi warns of may be printed."""
    code = """
from app import config
from app.scene import Scene, build_simulation
from app.sim import runtime
runtime.init("cpu", "float32", threads=1)
text = ('[run]\\nduration = 0.001\\n[domain]\\nlo = [-0.02, -0.02, 0.0]\\nhi = [0.02, 0.02, 0.08]\\n[vessel]\\n'
        'shape = "box"\\n[gas]\\ncell_size = 5e-3\\n[boundary]\\n'
        'bottom = { kind = "velocity_inlet", velocity = [0.0, 0.0, 0.5] }\\ntop = { kind = "pressure_outlet" }\\n')
sim = build_simulation(Scene(config.load_text(text, "box.toml")))
print("built", sim.flow is not None)
"""
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=300,
                       env=dict(os.environ, PYTHONPATH=str(ROOT), TI_OFFLINE_CACHE="0"))
    assert r.returncode == 0 and "built True" in r.stdout, r.stderr[-2000:]
    assert "Warning" not in r.stdout + r.stderr and "lose precision" not in r.stdout + r.stderr, r.stderr[-2000:]

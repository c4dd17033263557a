"""benchmarks/device_run.sh, checked on the CPU before a GPU is lent.

A GPU comes for 15 minutes in all, one prepared call: a flag a benchmark no longer takes, or a preset key that was
renamed, would cost that call. Here every stage of the script runs with `python3` replaced by a recorder (and
`nvidia-smi`, `sleep`, `pkill`, `pgrep` by stubs), so the shell logic itself runs as on the device; then each
recorded command is checked as its program would check it: a benchmark's own argument parser, the `fbed` parser,
and every preset with its `--set` overrides (and the preparation preset it starts from) loaded and derived.
Nothing is simulated.
"""
import argparse
import importlib.util
import os
import pathlib
import subprocess

import pytest

from app.cli import build_parser
from app.config import derived, loader
from app.sweep import cases

pytestmark = pytest.mark.bench
ROOT = pathlib.Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "benchmarks" / "device_run.sh"
RECORDER = 'printf \'%s\\0\' "$@" >> "$FAKE_LOG"; printf \'\\n\' >> "$FAKE_LOG"\n'
STUBS = {"python3": RECORDER, "nvidia-smi": "exit 0\n", "sleep": "exit 0\n", "pkill": "exit 0\n",
         "pgrep": "exit 1\n"}


def stages() -> list[str]:
    """The stage names of the script's `case` (its own list, so a stage added later is checked too)."""
    text = SCRIPT.read_text()
    body = text[text.index('case "$stage" in'):text.index("esac")]
    names = []
    for line in body.splitlines():
        head = line.strip().split(")")[0]
        if line.startswith("    ") and not line.startswith("     ") and ")" in line and " " not in head:
            names += head.split("|")
    return names


def record(tmp_path: pathlib.Path, names: list[str], env_extra: dict, bed: bool, files=()) -> list[list[str]]:
    """Run the script's stages with the stubs first on PATH, in a folder that links the project's code (and holds
    ``files``, empty: what earlier stages or sessions left); return the argv of every python3 call."""
    bin_dir, work, out = tmp_path / "bin", tmp_path / "work", tmp_path / "out"
    for d in (bin_dir, work, out):
        d.mkdir(parents=True)
    for name, body in STUBS.items():
        (bin_dir / name).write_text("#!/bin/bash\n" + body)
        (bin_dir / name).chmod(0o755)
    for d in ("app", "benchmarks", "presets", "validation"):
        (work / d).symlink_to(ROOT / d)
    for rel in (["runs/mri_bed.h5"] if bed else []) + list(files):
        (work / rel).parent.mkdir(parents=True, exist_ok=True)
        (work / rel).write_bytes(b"")
    log = tmp_path / "calls"
    env = dict(os.environ, PATH=f"{bin_dir}{os.pathsep}{os.environ['PATH']}", FAKE_LOG=str(log), OUT=str(out),
               **env_extra)
    r = subprocess.run(["bash", str(SCRIPT), *names], cwd=work, env=env, capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0, r.stderr
    return [c.split("\0") for c in log.read_text().split("\0\n") if c]  # each call: its args, each ended by NUL


class _Parsed(Exception):
    pass


def check_benchmark(argv: list[str], monkeypatch) -> None:
    """The script's main() up to its parse_args, with the device's arguments: an unknown flag or a bad value
    stops it there (SystemExit), as it would on the device."""
    path = ROOT / argv[0]
    assert path.is_file(), f"{argv[0]} does not exist"
    spec = importlib.util.spec_from_file_location(f"_device_{path.stem}", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    original = argparse.ArgumentParser.parse_args

    def parse_then_stop(self, args=None, namespace=None):
        raise _Parsed(original(self, args, namespace))

    with monkeypatch.context() as m:
        m.setattr(argparse.ArgumentParser, "parse_args", parse_then_stop)
        with pytest.raises(_Parsed) as parsed:
            mod.main(argv[1:])
    ns = vars(parsed.value.args[0])
    if ns.get("preset"):  # series_reads.py: a preset and its overrides
        check_preset(ns["preset"], ns.get("overrides") or ns.get("set") or [])


def check_preset(preset: str, overrides: list[str]) -> None:
    cfg = loader.load(ROOT / preset, overrides)
    derived.derive(cfg, preset)
    if cfg.run.start_from:  # the preparation it runs first on a fresh machine
        prep = loader.resolve_path(cfg, cfg.run.start_from)
        derived.derive(loader.load(prep), str(prep))


def check_fbed(argv: list[str]) -> str:
    args = build_parser().parse_args(argv)
    if args.command == "run" and args.preset:
        check_preset(args.preset, list(args.overrides) + (["video.enabled=true"] if args.video is not None else []))
    elif args.command == "sweep":
        keys, combos = cases(args.sets)
        for values in combos:
            check_preset(args.preset, [f"{k}={v}" for k, v in zip(keys, values)])
    elif args.command == "bench" and args.kind == "accuracy" and args.cases:
        from app.bench.accuracy import all_cases

        assert set(args.cases) <= {c.name for c in all_cases()}
    return args.command


def check_all(calls, monkeypatch) -> set[str]:
    seen = set()
    for argv in calls:
        if argv[:2] == ["-m", "app"]:
            seen.add("fbed " + check_fbed(argv[2:]))
        else:
            if argv[0].startswith("benchmarks/"):
                check_benchmark(argv, monkeypatch)
            assert (ROOT / argv[0]).is_file(), argv
            seen.add(argv[0])
    return seen


def test_every_stage_of_the_device_script_calls_what_exists_with_arguments_it_takes(tmp_path, monkeypatch):
    names = stages()
    assert {"dem", "gas", "verma_start", "mri_law", "mri_prepare"} <= set(names), names
    calls = record(tmp_path, names, {}, bed=False)
    seen = check_all(calls, monkeypatch)
    # every kind of call was reached: the stubs did not short-circuit the stages
    assert {"fbed run", "fbed sweep", "fbed analyze", "fbed bench", "benchmarks/dem_substep.py",
            "benchmarks/flow_throughput.py", "fbed pack"} <= seen, seen
    # every file a stage calls travels to the device: validation/ is moved aside for the 64 MiB limit
    assert not any(s.startswith("validation/") for s in seen), seen


def test_the_mri_stages_from_a_carried_bed_with_extra_overrides(tmp_path, monkeypatch):
    calls = record(tmp_path, ["mri_law", "mri_sweep_start"],
                   {"MRI_LAW": "gidaspow", "MRI_SET": "--set run.duration=0.6"}, bed=True)
    assert len(calls) == 2
    run = calls[0]
    assert "coupling.drag=gidaspow" in run and "run.duration=0.6" in run and 'run.start_from=""' in run
    assert any(a.startswith("particles.initial_state=") and a.endswith('mri_bed.h5"') for a in run), run
    check_all(calls, monkeypatch)


def test_a_law_run_packs_its_moving_end_and_a_later_session_goes_on_from_it(tmp_path, monkeypatch):
    """A law's run ends (bed.h5, or the checkpoint of a run cut at its limit) packed with its speeds into $OUT; a
    later session carrying that pack as runs/mri_state_<law>.h5 starts from it, fluidized: the inlet at full speed
    from 0 and the analysis from 0.02 s. Without a moving state the carried bed is used, as before."""
    for end in ("bed.h5", "checkpoint.h5"):
        calls = record(tmp_path / end, ["mri_law"], {"MRI_LAW": "gidaspow"}, bed=True,
                       files=[f"runs/mri_gidaspow/{end}", "runs/mri_state_gidaspow.h5", "runs/mri_gidaspow/run.h5"])
        run, pack, keep = calls
        assert any(a.endswith('runs/mri_state_gidaspow.h5"') for a in run), run
        assert "boundary.bottom.schedule=[[0.0,1.0]]" in run and "output.average_from=0.02" in run
        assert pack == ["-m", "app", "pack", f"runs/mri_gidaspow/{end}", "runs/mri_state_gidaspow.h5",
                        "--resolution", "2e-6", "--speed-resolution", "1e-2"], pack
        # and its images, config and summary, for pooling the law's sessions back here (benchmarks/run_records.py)
        assert keep == ["benchmarks/run_records.py", "pack", "runs/mri_gidaspow",
                        str(tmp_path / end / "out" / "mri_records_gidaspow.h5"), "--groups", "mri", "slab"], keep
        check_all(calls, monkeypatch)
        assert (tmp_path / end / "out" / "mri_state_gidaspow.h5").exists()
    calls = record(tmp_path / "first", ["mri_law"], {"MRI_LAW": "gidaspow"}, bed=True)
    assert len(calls) == 1 and any(a.endswith('mri_bed.h5"') for a in calls[0])


def test_a_verma_run_packs_its_end_and_a_later_session_goes_on_from_it(tmp_path, monkeypatch):
    """`verma_pack` packs the run's last state with speeds into $OUT; a call that starts with that pack carried as
    runs/verma_state.h5 runs verma (and verma_start, through its bash -c) from it, fluidized, its own window analysed;
    without it, the preset as it is."""
    calls = record(tmp_path / "on", ["verma", "verma_start", "verma_pack"], {}, bed=False,
                   files=["runs/verma_state.h5", "runs/verma/checkpoint.h5", "runs/verma/run.h5"])
    run, start, pack, keep = calls
    for c in (run, start):
        assert "particles.count=0" in c and "boundary.bottom.schedule=[[0.0,1.0]]" in c, c
        assert any(a.startswith("particles.initial_state=") and a.endswith('runs/verma_state.h5"') for a in c), c
    assert pack == ["-m", "app", "pack", "runs/verma/checkpoint.h5", "runs/verma_state.h5", "--resolution", "2e-6",
                    "--speed-resolution", "1e-2"], pack
    assert keep[:3] == ["benchmarks/run_records.py", "pack", "runs/verma"] and keep[4:] == [
        "--groups", "planes", "series", "--quantize"], keep
    check_all(calls, monkeypatch)
    assert (tmp_path / "on" / "out" / "verma_state.h5").exists()
    run, start = record(tmp_path / "off", ["verma", "verma_start"], {}, bed=False)
    assert run == start == ["-m", "app", "run", "presets/verma.toml", "--arch", "cuda", "--out", "runs/verma",
                            "--overwrite"], (run, start)


def test_a_renamed_flag_or_key_is_caught(monkeypatch):
    """The checks can fail: the device's own commands with one flag or key misspelt."""
    with pytest.raises(SystemExit):
        check_all([["benchmarks/dem_substep.py", "--arch", "cuda", "--sizez", "1000000"]], monkeypatch)
    with pytest.raises(Exception, match="duratoin"):
        check_all([["-m", "app", "run", "presets/verma.toml", "--set", "run.duratoin=0.05"]], monkeypatch)
    with pytest.raises(Exception, match="drag"):
        check_all([["-m", "app", "sweep", "presets/mri_poppy.toml", "--set", "coupling.drag=koch_hill,koch_hil"]],
                  monkeypatch)


def test_a_device_call_has_room_for_the_kit_the_tree_and_the_packed_poppy_bed():
    """A call carries 64 MiB: the kit (56.8 MB), the tree with validation/ moved aside, and the MRI bed packed at
    0.5 um (958,000 grains x 4.58 B, benchmarks/RESULTS.md). A figure or a run committed outside validation/ that
    ate the room would have the GPU session's call refused; benchmarks/device_carry.py says what takes it."""
    spec = importlib.util.spec_from_file_location("device_carry", ROOT / "benchmarks" / "device_carry.py")
    device_carry = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(device_carry)
    total, items = device_carry.carry_bytes(["validation"], [".devkit"])
    if (ROOT / ".devkit").exists():  # this checkout's own kit: its size, not the measured one
        total += device_carry.KIT - device_carry.size(ROOT / ".devkit")
    bed = 958000 * 4.58
    assert total + bed <= device_carry.LIMIT, items[:6]
    # a later session's moving state (mri_law's pack: positions at 2 um, 3.83 B a grain, and speeds at 1 cm/s, 1.46
    # B a grain in the poppy seeds' small bed; benchmarks/RESULTS.md), with the same folders moved aside
    assert total + 958000 * (3.83 + 1.46) <= device_carry.LIMIT, items[:6]

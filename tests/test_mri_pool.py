"""Several runs of one case pooled (`fbed analyze RUN RUN ... --out DIR`, app/analysis/pooling.py and
``mri.summarize_pooled``): a million-grain law of the MRI study spans GPU sessions, each going on from the last one's
packed end state, so its sessions are realisations of one operating point. Pooled, no bubble track and no bootstrap
block may join two runs, the spectrum must not see the jump between them, and runs of different cases are refused
naming the key."""
import json
import math
import pathlib

import h5py
import numpy as np
import pytest

from app import config as cfgmod
from app.analysis import mri
from app.analysis.mri_stats import block_bootstrap, block_starts, sessions_agree
from app.cli import main

pytestmark = pytest.mark.unit

ROOT = pathlib.Path(__file__).resolve().parents[1]
DX, DZ, NX, NZ = 0.002, 0.004, 12, 24  # mri_small's MRI pixels over its 24 mm column, 96 mm high
DT = 0.004


def test_no_track_links_two_runs():
    """A bubble sitting at the same place at the end of one run and the start of the next is two bubbles."""
    frames = [[dict(x=0.01, z=0.03 + 1e-4 * f, diameter=0.008)] for f in range(10)]
    times = np.arange(10) * DT
    assert [len(t["frames"]) for t in mri.track(frames, times, 1e-3)] == [10]
    assert sorted(len(t["frames"]) for t in mri.track(frames, times, 1e-3, breaks=[6])) == [4, 6]


def test_bootstrap_blocks_stay_within_one_run():
    starts = block_starts(23, 4, [0, 10])
    assert list(starts) == list(range(0, 7)) + list(range(10, 20))
    # one run all 0, the next all 1, blocks of a run's whole length: a resample holds whole runs, so its mean is
    # 0, 1/2 or 1 and nothing between (blocks across the jump gave any tenth before)
    groups = [[0.0]] * 10 + [[1.0]] * 10
    b = block_bootstrap(groups, 10, 2000, segments=[0, 10])
    assert b["mean_lo_blocks"] in (0.0, 0.5) and b["mean_hi_blocks"] in (0.5, 1.0)
    free = block_bootstrap(groups, 10, 2000)
    assert not {free["mean_lo_blocks"], free["mean_hi_blocks"]} <= {0.0, 0.5, 1.0}


def test_pooled_spectrum_finds_the_period_of_runs_of_unequal_length():
    rng = np.random.default_rng(5)
    parts = [np.sin(2 * math.pi * 4.0 * np.arange(n) * DT + rng.uniform(0, 2 * math.pi)) + 0.3 * rng.standard_normal(n)
             for n in (300, 180, 240)]
    f, p, peak = mri.spectrum(np.concatenate(parts), DT, segments=[0, 300, 480])
    assert f[1] == pytest.approx(1.0 / (300 * DT))  # the longest run's frequencies
    assert abs(peak - 4.0) < f[1]


def _ar1(n, rng, tau=10.0, sd=1e-3):
    a = math.exp(-1.0 / tau)
    x = np.empty(n)
    x[0] = rng.normal(0, sd)
    for i in range(1, n):
        x[i] = a * x[i - 1] + rng.normal(0, sd * math.sqrt(1 - a * a))
    return x


def test_runs_of_one_operating_point_agree_and_a_shifted_one_does_not():
    """chi^2 of the runs' bed heights about their weighted mean, errors over blocks of correlated frames."""
    rng = np.random.default_rng(11)
    runs = [0.05 + _ar1(n, rng) for n in (600, 500, 700)]
    same = sessions_agree(np.concatenate(runs), [0, 600, 1100], 20)
    assert same["dof"] == 2 and same["p"] > 0.01
    se = same["rows"][1]["mean_se"]
    runs[1] = runs[1] + 6 * se  # one run 6 of its standard errors off: another operating point, or still settling
    assert sessions_agree(np.concatenate(runs), [0, 600, 1100], 20)["p"] < 1e-3


# ------------------------------------------------------------------ `fbed analyze A B --out C` end to end
def _frame(height, discs):
    """Void fraction (NX, NZ): an emulsion at solid fraction 0.6 below ``height`` with gas discs (x, z, d)."""
    xs, zs = (np.arange(NX * 8) + 0.5) * DX / 8, (np.arange(NZ * 8) + 0.5) * DZ / 8
    X, Z = np.meshgrid(xs, zs, indexing="ij")
    gas = np.zeros_like(X, bool)
    for x, z, d in discs:
        gas |= (X - x) ** 2 + (Z - z) ** 2 < 0.25 * d * d
    solid = 0.6 * ((Z < height) & ~gas)
    return 1.0 - solid.reshape(NX, 8, NZ, 8).mean((1, 3))


def _record(n, rng):
    """n frames of a bed 50-56 mm high with a 9 mm bubble rising at 0.3 m/s, born every 40 frames."""
    frames, births = [], int(rng.integers(0, 40))
    for f in range(n):
        age = (f + births) % 40
        frames.append(_frame(0.053 + 0.003 * math.sin(2 * math.pi * f / 50), [(0.012, 0.012 + 0.3 * age * DT, 0.009)]))
    return np.array(frames)


def _run(d: pathlib.Path, overrides, void, t0):
    d.mkdir(parents=True)
    cfg = cfgmod.load(ROOT / "presets" / "mri_small.toml", overrides)
    (d / "config.toml").write_text(cfgmod.dump(cfg))
    with h5py.File(d / "run.h5", "w") as f:
        g = f.create_group("mri")
        g["porosity"] = void.astype(np.float32)
        g["time"] = t0 + np.arange(len(void)) * DT
        g.attrs["pixel"], g.attrs["origin"] = (DX, DZ), (-0.012, 0.0)
    return d


FIRST = []  # the first session: settle, ramp, analysed from 0.45 s (mri_small as it is)
NEXT = ["run.duration=0.8", "output.average_from=0.02", "boundary.bottom.schedule=[[0.0,1.0]]", "run.seed=3"]


@pytest.fixture(scope="module")
def sessions(tmp_path_factory):
    root = tmp_path_factory.mktemp("pool")
    rng = np.random.default_rng(2)
    a = _run(root / "a", FIRST, np.concatenate([_record(50, rng), _record(60, rng)]), 0.25)  # 0.45 s at frame 50
    b = _run(root / "b", NEXT, _record(90, rng), 0.004)  # 0.02 s at frame 4
    return root, a, b


def test_fbed_analyze_pools_two_sessions_of_one_case(sessions, capsys):
    root, a, b = sessions
    assert main(["analyze", str(a)]) == 0 and main(["analyze", str(b)]) == 0
    one = [json.loads((d / "analysis" / "mri.json").read_text()) for d in (a, b)]
    out = root / "pooled"
    assert main(["analyze", str(a), str(b), "--out", str(out)]) == 0
    pooled = json.loads((out / "pooled.json").read_text())
    assert pooled["frames"] == {"mri": [60, 86]}  # a from 0.45 s, b from 0.02 s
    notes = pooled["session_differences"]
    assert any(n.startswith("run.duration") for n in notes) and any(n.startswith("boundary.z-.schedule") for n in notes)
    fig = pooled["figures"]
    assert fig == json.loads((out / "analysis" / "mri.json").read_text())
    # at every threshold: frame by frame metrics pool as the frames do; the tracks are the runs' own, none joined
    # across them (the threshold chosen per metric may differ from each run's: it is chosen on the pooled record)
    rows = [_thresholds(d / "analysis" / "mri") for d in (a, b, out)]
    for key in rows[2]:
        ra, rb, rp = (r[key] for r in rows)
        if key[0] == "bed_height":
            assert rp["mean"] == pytest.approx((60 * ra["mean"] + 86 * rb["mean"]) / 146, rel=1e-5)
        else:
            assert rp["n"] == ra["n"] + rb["n"]
    assert rows[2][("bubble_velocity", 0.3)]["n"] >= 4
    assert fig["mri_bubble_velocity_mean"] == pytest.approx(0.3, rel=0.05)
    assert fig["mri_runs"] == 2 and 0.0 <= fig["mri_runs_height_p"] <= 1.0
    assert "The pooled runs" in (out / "analysis" / "mri" / "tables.md").read_text()


def _thresholds(folder):
    import csv

    with open(folder / "thresholds.csv", newline="") as f:
        return {(r["metric"], float(r["threshold"])): {"n": int(r["n"]), "mean": float(r["mean"] or "nan")}
                for r in csv.DictReader(f)}


@pytest.mark.parametrize("override,key", [("contact.restitution=0.8", "contact.restitution"),
                                          ("boundary.bottom.schedule=[[0.0,0.5],[0.1,1.0]]",
                                           "boundary.z-.schedule"),
                                          ("probes.mri_interval=0.008", "probes.mri_interval")])
def test_runs_of_different_cases_are_refused_naming_the_key(sessions, override, key, capsys):
    root, a, b = sessions
    c = root / f"other-{key}"
    if not c.exists():
        _run(c, NEXT + [override], mri.read_images(b, "mri")[0], 0.004)
    assert main(["analyze", str(a), str(c), "--out", str(root / "refused")]) == 2
    err = capsys.readouterr().err
    assert key in err and "Traceback" not in err and not (root / "refused" / "pooled.json").exists()


def test_bad_pooling_invocations_name_the_flag(sessions, capsys):
    root, a, b = sessions
    for argv, flag in ((["analyze", str(a), str(b)], "--out"), (["analyze", str(a), "--out", str(root / "x")], "--out"),
                       (["analyze", str(a), str(b), "--out", str(a)], "--out"),
                       (["analyze", str(a), str(a), "--out", str(root / "x")], "twice"),
                       (["analyze", str(a), str(b), "--out", str(root / "x"), "--plot", "f"], "--plot")):
        assert main(argv) == 2
        assert flag in capsys.readouterr().err


def test_cases_run_apart_side_by_side_as_a_sweep(sessions, capsys):
    """The four laws run in separate GPU sessions (benchmarks/device_run.sh mri_law), some pooled: `fbed analyze ...
    --compare --out` makes the sweep's table, each case labelled by the keys it differs by (coupling.drag)."""
    import csv

    root, a, b = sessions
    pooled, other = root / "cmp-pooled", root / "cmp-beetstra"
    assert main(["analyze", str(a), str(b), "--out", str(pooled)]) == 0
    assert (pooled / "case.toml").read_text() == (a / "config.toml").read_text()  # the case, if the runs move
    _run(other, NEXT + ["coupling.drag=beetstra"], mri.read_images(b, "mri")[0], 0.004)
    out = root / "cmp"
    assert main(["analyze", str(pooled), str(other), "--compare", "--out", str(out)]) == 0
    with open(out / "mri_compare.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert [(r["case"], r["coupling.drag"], r["status"]) for r in rows] == [
        ("cmp-pooled", "koch_hill", "2 runs pooled"), ("cmp-beetstra", "beetstra", "run")]
    assert list(rows[0])[:3] == ["case", "coupling.drag", "status"]  # the session keys (run.duration, ...) are not
    fig = json.loads((pooled / "pooled.json").read_text())["figures"]
    assert float(rows[0]["mri_bed_height_mean"]) == pytest.approx(fig["mri_bed_height_mean"], rel=1e-5)
    assert (out / "mri_compare.png").exists() and "beetstra" in (out / "mri_compare.md").read_text()
    assert main(["analyze", str(other), "--compare", "--out", str(out)]) == 2
    assert "--compare" in capsys.readouterr().err
    # a run of another analysis is refused before it is analysed: nothing in it rewritten
    verma_run = root / "cmp-verma"
    _run(verma_run, NEXT + ['probes.analysis="verma"'], mri.read_images(b, "mri")[0], 0.004)
    assert main(["analyze", str(other), str(verma_run), "--compare", "--out", str(out)]) == 2
    assert "probes.analysis" in capsys.readouterr().err and not (verma_run / "analysis").exists()
    assert main(["analyze", str(other), str(verma_run), "--out", str(root / "mixed")]) == 2
    assert "different analyses (mri, verma)" in capsys.readouterr().err


def _run_records():
    import importlib.util

    spec = importlib.util.spec_from_file_location("run_records", ROOT / "benchmarks" / "run_records.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_a_sessions_records_come_back_small_and_pool_as_the_run_would(sessions, tmp_path):
    """A GPU session returns no run.h5 (benchmarks/device_run.sh); it keeps its images, config and summary in one
    file (benchmarks/run_records.py). Unpacked here, the sessions pool to the very figures of the runs themselves;
    quantized, each value is kept within half a step of 1/65535; a file over the size limit is not kept."""
    rr = _run_records()
    root, a, b = sessions
    back = []
    for d in (a, b):
        assert rr.pack(d, tmp_path / f"{d.name}.h5", ["mri"]) > 0
        rr.unpack(tmp_path / f"{d.name}.h5", tmp_path / f"{d.name}-back")
        back.append(tmp_path / f"{d.name}-back")
        assert (back[-1] / "config.toml").read_text() == (d / "config.toml").read_text()
    assert main(["analyze", str(a), str(b), "--out", str(tmp_path / "orig")]) == 0
    assert main(["analyze", *map(str, back), "--out", str(tmp_path / "back")]) == 0
    figs = [json.loads((tmp_path / x / "pooled.json").read_text())["figures"] for x in ("orig", "back")]
    assert figs[0] == figs[1]
    assert rr.pack(a, tmp_path / "q.h5", ["mri"], quantize=True) > 0
    rr.unpack(tmp_path / "q.h5", tmp_path / "q")
    orig, again = mri.read_images(a, "mri")[0], mri.read_images(tmp_path / "q", "mri")[0]
    assert np.abs(again - orig).max() <= 0.5 * rr.STEP + 1e-7  # (+ float32's rounding of the value near 1)
    assert rr.pack(a, tmp_path / "big.h5", ["mri"], max_mb=1e-3) == 0 and not (tmp_path / "big.h5").exists()


def test_the_sessions_records_back_here_become_pooled_cases_side_by_side(sessions, tmp_path, capsys):
    """benchmarks/pool_sessions.py: records of two Koch & Hill sessions and one Beetstra session give the Koch & Hill
    pair pooled, the Beetstra run analysed, and the two cases side by side, named by their law."""
    import csv
    import importlib.util

    rr = _run_records()
    root, a, b = sessions
    c = root / "pool-beetstra"
    if not c.exists():
        _run(c, NEXT + ["coupling.drag=beetstra"], mri.read_images(b, "mri")[0], 0.004)
    files = []
    for d in (a, b, c):
        assert rr.pack(d, tmp_path / f"{d.name}.h5", ["mri"]) > 0
        files.append(str(tmp_path / f"{d.name}.h5"))
    spec = importlib.util.spec_from_file_location("pool_sessions", ROOT / "benchmarks" / "pool_sessions.py")
    ps = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(ps)
    out = tmp_path / "laws"
    assert ps.main([*files, "--out", str(out)]) == 0
    assert len(json.loads((out / "koch_hill" / "pooled.json").read_text())["runs"]) == 2
    assert (out / "beetstra" / "analysis" / "mri.json").exists()
    with open(out / "compare" / "mri_compare.csv", newline="") as f:
        assert [(r["case"], r["coupling.drag"]) for r in csv.DictReader(f)] == [("koch_hill", "koch_hill"),
                                                                                ("beetstra", "beetstra")]

"""The MRI pipeline (app/analysis/mri.py) on synthetic slab images whose bubbles, bed height, radial profile
and period are known by construction. Images are rendered with each pixel's partial coverage (8 x 8
sub-samples), so a pixel is gas at threshold 0.30 when more than half of it lies in a bubble of an emulsion
at solid fraction 0.60: the digitised area is then an unbiased estimate of the disc's."""
import math
import pathlib

import numpy as np
import pytest

from app.analysis import mri

pytestmark = pytest.mark.unit

EMULSION = 0.60
SUB = 8


def coverage(nx, nz, dx, dz, inside):
    """Fraction of each pixel for which inside(x, z) holds (SUB x SUB sub-samples)."""
    xs = (np.arange(nx * SUB) + 0.5) * dx / SUB
    zs = (np.arange(nz * SUB) + 0.5) * dz / SUB
    X, Z = np.meshgrid(xs, zs, indexing="ij")
    return inside(X, Z).reshape(nx, SUB, nz, SUB).mean((1, 3))


def frame(nx, nz, dx, dz, height, discs=(), profile=None):
    """Solid fraction: the emulsion (or profile(x)) below ``height``, nothing above, discs (xc, zc, d) empty."""
    bed = coverage(nx, nz, dx, dz, lambda X, Z: Z < height)
    base = EMULSION if profile is None else profile((np.arange(nx) + 0.5) * dx)[:, None]
    gas = np.zeros((nx, nz))
    for xc, zc, d in discs:
        gas = np.maximum(gas, coverage(nx, nz, dx, dz, lambda X, Z: (X - xc) ** 2 + (Z - zc) ** 2 < 0.25 * d * d))
    return base * bed * (1.0 - gas)


@pytest.mark.parametrize("dx,dz,d", [(0.002, 0.002, 0.020), (0.002, 0.002, 0.035), (0.004, 0.008, 0.060),
                                     (0.001, 0.001, 0.010)])
def test_bubble_diameter_and_aspect_of_known_discs_and_ellipse(dx, dz, d):
    nx, nz = int(0.096 / dx), int(0.3 / dz)
    alpha = frame(nx, nz, dx, dz, 0.2, [(0.048, 0.09, d)])
    bs = mri.bubbles(mri.binarise(alpha, 0.30), dx, dz, surface=mri.bed_height(alpha >= 0.30, dz))
    assert len(bs) == 1
    assert bs[0]["diameter"] == pytest.approx(d, rel=0.03)
    assert bs[0]["x"] == pytest.approx(0.048, abs=0.5 * dx) and bs[0]["z"] == pytest.approx(0.09, abs=0.5 * dz)
    # the bounding rectangle of a disc is a square to within one pixel each way
    assert bs[0]["aspect"] == pytest.approx(1.0, abs=dx / d + dz / d)


def test_bubbles_touching_the_surface_or_inlet_or_below_4mm2_are_left_out():
    dx = dz = 0.001
    nx, nz = 96, 300
    alpha = frame(nx, nz, dx, dz, 0.15, [(0.02, 0.145, 0.02),   # breaks the surface: freeboard
                                          (0.05, 0.004, 0.012),  # sits on the inlet
                                          (0.08, 0.0805, 0.0015),  # 1.8 mm^2 < 4 mm^2
                                          (0.05, 0.07, 0.015)])  # the one bubble
    solid = mri.binarise(alpha, 0.3)
    bs = mri.bubbles(solid, dx, dz, surface=mri.bed_height(solid, dz))
    assert [round(b["diameter"], 3) for b in bs] == [0.015]


def test_bubble_velocities_from_tracks():
    dx = dz = 0.002
    nx, nz = 48, 150
    dt = 0.004
    times = np.arange(60) * dt
    v1, v2 = 0.30, 0.55
    frames = [frame(nx, nz, dx, dz, 0.25, [(0.025, 0.03 + v1 * t, 0.018), (0.07, 0.02 + v2 * t, 0.026)])
              for t in times]
    solid = [mri.binarise(a, 0.3) for a in frames]
    found = [mri.bubbles(s, dx, dz, surface=mri.bed_height(s, dz)) for s in solid]
    tracks = mri.track(found, times, mri.max_displacement(dt, dx, dz))
    assert len(tracks) == 2
    got = sorted(t["vz"] for t in tracks)
    assert got[0] == pytest.approx(v1, rel=0.05) and got[1] == pytest.approx(v2, rel=0.05)
    assert all(abs(t["vx"]) < 0.02 for t in tracks)


def test_bed_height_within_one_pixel():
    dx, dz = 0.004, 0.008
    nx, nz = 24, 75
    for h in (0.130, 0.1537, 0.2012, 0.171):
        alpha = frame(nx, nz, dx, dz, h, [(0.05, 0.06, 0.03)])
        for thr in mri.THRESHOLDS:
            assert abs(mri.bed_height(mri.binarise(alpha, thr), dz) - h) <= dz


def test_radial_profile_and_period_through_the_whole_pipeline():
    dx, dz = 0.004, 0.008
    nx, nz = 24, 75
    dt, f0 = 0.004, 4.0
    times = np.arange(500) * dt
    R = 0.048

    def profile(x):
        return 0.45 + 0.15 * (1.0 - ((x - R) / R) ** 2)

    heights = 0.16 + 0.024 * np.sin(2 * math.pi * f0 * times)
    rows = np.floor(heights / dz) * dz  # on row edges: the whole-bed average has no partial row
    void = np.stack([1.0 - frame(nx, nz, dx, dz, h, profile=lambda x, t=t: profile(x) *
                                 (1.0 - 0.1 * np.sin(2 * math.pi * f0 * t)))
                     for h, t in zip(rows, times)])
    res = mri.analyse(void, times, dx, dz, n_boot=200)
    xc = (np.arange(nx) + 0.5) * dx
    # time mean of profile * (1 - 0.1 sin) over whole periods is the profile itself
    assert res["radial_static"] == pytest.approx(profile(xc), abs=1e-3)
    # over the whole bed each frame weighs by its rows, and the rows rise and fall with the modulation
    n_rows, mod = np.round(rows / dz), 1.0 - 0.1 * np.sin(2 * math.pi * f0 * times)
    assert res["radial_whole"] == pytest.approx(profile(xc) * np.sum(n_rows * mod) / np.sum(n_rows), abs=1e-6)
    assert res["x"] == pytest.approx(xc - R)
    assert res["f_peak"] == pytest.approx(f0, rel=0.02)
    assert np.max(np.abs(res["height"] - (rows - 0.5 * dz))) < 1e-12  # the centre of the top row
    assert res["height_stats"]["mean"] == pytest.approx(np.mean(rows) - 0.5 * dz)


def test_bootstrap_interval_covers_the_mean_and_ks_and_threshold_choice():
    rng = np.random.default_rng(1)
    v = rng.normal(10.0, 2.0, 400)
    b = mri.bootstrap(v, 10_000)
    assert b["mean_lo"] < 10.0 < b["mean_hi"]
    # the interval's half-width is 1.96 sigma / sqrt(n) to within 10%
    assert 0.5 * (b["mean_hi"] - b["mean_lo"]) == pytest.approx(1.96 * 2.0 / 20.0, rel=0.1)
    assert b["cv"] == pytest.approx(20.0, rel=0.1)
    # a metric that is flat then jumps: the jump's neighbours have excessive sensitivity
    q = mri.gradient_quality([1.0, 1.1, 1.2, 1.3, 3.0, 3.1])
    assert q[3] < 0.3 and q[4] < 0.3 and q[0] == pytest.approx(1.0)
    # a threshold with no bubble (nan) is left out and the others are scored among themselves
    # (regression: one nan made every score nan, so mri_small's grid slab failed 'gradient' at every threshold)
    q = mri.gradient_quality([math.nan, 1.0, 1.1, 1.2, 1.3, 3.0])
    assert math.isnan(q[0]) and q[1] == pytest.approx(1.0) and q[4] < 0.3 and q[5] < 0.3
    assert all(math.isnan(x) for x in mri.gradient_quality([math.nan, 1.0, math.nan, math.nan, math.nan, math.nan]))
    rows = [dict(cv=10.0, ci_width_pct=w, ks_p=0.5, gradient_quality=g, mean=1.0, n=50)
            for w, g in ((12.0, 0.9), (5.0, 0.1), (8.0, 0.8), (4.0, 0.95))]
    rows[3]["cv"] = 45.0
    k, fails = mri.choose_threshold(rows)
    assert k == 2 and fails[1] == "gradient" and fails[3] == "cv"
    k, fails = mri.choose_threshold([dict(rows[0], mean=1.2)], velocity=True)
    assert fails == ["velocity_range"]


def test_block_intervals_allow_for_correlated_frames_where_the_studys_do_not():
    """A bed height correlated over ~20 frames (AR(1), phi = 0.95: the mean's true standard error is
    sigma sqrt((1 + phi) / (1 - phi) / n), 6.2x the independent one): the interval over blocks of frames is within
    a factor 2 of the truth, where resampling frames one by one (the study's) is under a quarter of it, in each of
    ten records; on independent frames the two agree to 15% (a block of two frames)."""
    from scipy.signal import lfilter

    from app.analysis.mri_stats import block_bootstrap, block_frames

    n, phi, sigma = 2000, 0.95, 0.01
    true_se = sigma * math.sqrt((1 + phi) / (1 - phi) / n)
    for seed in range(10):
        rng = np.random.default_rng(seed)
        e = rng.standard_normal(n) * sigma * math.sqrt(1 - phi ** 2)
        e[0] = rng.standard_normal() * sigma
        h = 0.2 + lfilter([1.0], [1.0, -phi], e)
        blk = block_frames(h)
        assert 20 <= blk <= 80  # two integral times: 39 frames for this process, estimated from the record
        b = block_bootstrap([[x] for x in h], blk, 4000, seed)
        i = mri.bootstrap(h, 4000, seed)
        assert 0.5 <= (b["mean_hi_blocks"] - b["mean_lo_blocks"]) / (2 * 1.96 * true_se) <= 2.0
        assert (i["mean_hi"] - i["mean_lo"]) / (2 * 1.96 * true_se) < 0.25
        w = 0.2 + sigma * rng.standard_normal(n)
        bw, iw = block_bootstrap([[x] for x in w], block_frames(w), 4000, seed), mri.bootstrap(w, 4000, seed)
        assert (bw["mean_hi_blocks"] - bw["mean_lo_blocks"]) == pytest.approx(iw["mean_hi"] - iw["mean_lo"], rel=0.15)
    # values per frame (bubbles): frames without any are skipped, the mean is over the values
    b = block_bootstrap([[1.0, 3.0], [], [2.0]], 1, 2000)
    assert 1.0 <= b["mean_lo_blocks"] <= 2.0 <= b["mean_hi_blocks"] <= 3.0
    assert math.isnan(block_bootstrap([[], []], 1, 10)["mean_lo_blocks"])


def test_velocity_per_size_class_has_block_intervals_of_its_own_tracks():
    """Tracks of two size classes, one starting each frame: the 15 mm class rises at 0.4 m/s plus an AR(1) surge
    correlated over ~20 frames (phi = 0.95), the 35 mm class at 0.8 m/s plus independent noise. The 15 mm class's
    interval over blocks of frames is within a factor 2 of the mean's true standard error, where resampling tracks
    one by one is under a quarter of it; the 35 mm class's block interval is its own (it covers 0.8 m/s, not the
    two classes' mixture) and agrees with the one-by-one interval to 20%. Without the record's frames there is no
    block interval (the earlier call)."""
    from scipy.signal import lfilter

    n, phi, sigma = 2000, 0.95, 0.05
    rng = np.random.default_rng(3)
    e = rng.standard_normal(n) * sigma * math.sqrt(1 - phi ** 2)
    e[0] = rng.standard_normal() * sigma
    surge = lfilter([1.0], [1.0, -phi], e)
    tracks = [dict(frames=[k, k + 1], mean_diameter=0.015, vz=0.4 + surge[k]) for k in range(n)]
    tracks += [dict(frames=[k, k + 1], mean_diameter=0.035, vz=0.8 + sigma * rng.standard_normal())
               for k in range(0, n, 2)]
    small, big = mri.velocity_classes(tracks, 4000, frames=n + 1, block=40)
    assert (small["d_lo"], big["d_lo"]) == (0.010, 0.030) and (small["n"], big["n"]) == (n, n // 2)
    true_se = sigma * math.sqrt((1 + phi) / (1 - phi) / n)
    assert 0.5 <= (small["mean_hi_blocks"] - small["mean_lo_blocks"]) / (2 * 1.96 * true_se) <= 2.0
    assert (small["mean_hi"] - small["mean_lo"]) / (2 * 1.96 * true_se) < 0.25
    assert big["mean_lo_blocks"] < 0.8 < big["mean_hi_blocks"]
    assert big["mean_hi_blocks"] - big["mean_lo_blocks"] == pytest.approx(big["mean_hi"] - big["mean_lo"], rel=0.2)
    assert "mean_lo_blocks" not in mri.velocity_classes(tracks, 100)[0]


def test_the_windows_halves_say_whether_the_bed_was_steady():
    """A bed height whose spread falls from 8 to 5 mm within the analysed window (3,000 frames, correlated over ~20)
    is named unsteady in 20 of 20 records; a steady one in at most 4 of 20 (the block errors are themselves
    uncertain; 0 of 20 measured, 2026-12-07; the drifting ones lay 3.7 or more apart). Too few frames for two
    blocks a half: said so, no verdict."""
    from scipy.signal import lfilter

    from app.analysis.mri import _steady_line
    from app.analysis.mri_stats import halves

    def bed(rng, sigmas):
        e = np.concatenate([rng.standard_normal(1500) * s for s in sigmas]) * math.sqrt(1 - 0.95 ** 2)
        return 0.2 + lfilter([1.0], [1.0, -0.95], e)

    flagged = {"steady": 0, "drift": 0}
    for seed in range(20):
        rng = np.random.default_rng(seed)
        for name, sig in (("steady", (0.006, 0.006)), ("drift", (0.008, 0.005))):
            hv = halves(bed(rng, sig), 40)
            flagged[name] += "not yet the bed's steady state" in _steady_line(hv)
    assert flagged["drift"] == 20 and flagged["steady"] <= 4, flagged
    assert "too short to tell" in _steady_line(halves(np.linspace(0.1, 0.2, 10), 4))


def test_umf_read_off_a_fluidization_curve():
    """A curve with an Ergun fixed-bed branch dp = a U + b U^2 up to U_mf and the weight W above it, sampled
    as the holds of an inlet schedule with noise: U_mf from the fixed-bed fit within 2%."""
    from app.analysis import umf

    a, b, weight = 4000.0, 2000.0, 1200.0
    u_mf = (-a + math.sqrt(a * a + 4 * b * weight)) / (2 * b)
    levels = [0.6, 0.5, 0.45, 0.4, 0.35, 0.3, 0.25, 0.2, 0.15, 0.1]
    sched, t = [[0.0, 0.0], [0.1, 0.6], [0.2, 0.6]], 0.2
    for u in levels[1:]:
        sched += [[t + 0.002, u], [t + 0.04, u]]
        t += 0.04
    stretches = umf.holds(sched, 1.0)
    assert [round(s[2], 6) for s in stretches] == levels
    time = np.arange(0.0, t + 1e-9, 1e-3)
    rng = np.random.default_rng(0)
    dp = np.zeros_like(time)
    for t0, t1, u in stretches:
        sel = (time >= t0 - 1e-9) & (time <= t1 + 1e-9)
        dp[sel] = min(a * u + b * u * u, weight) + rng.normal(0, 10.0, sel.sum())
    rows = umf.curve(time, dp, stretches)
    fit = umf.umf(rows, weight)
    assert fit["umf"] == pytest.approx(u_mf, rel=0.02)
    assert fit["fixed_bed_points"] == sum(a * u + b * u * u < 0.8 * weight for u in levels)
    # fluidized holds that read below 0.8 W (a slugging bed partly carried by rough walls) stay off the branch
    for r in rows:
        if r["velocity"] >= 0.5:
            r["pressure_drop"] = 0.7 * weight
    again = umf.umf(rows, weight)
    assert again["fixed_bed_points"] == fit["fixed_bed_points"] and again["umf"] == pytest.approx(fit["umf"])


def test_sweep_cases_side_by_side(tmp_path):
    """`fbed analyze SWEEP_DIR` for mri cases: one row per case with its swept value and figures."""
    import csv
    import json

    with open(tmp_path / "sweep.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["case", "coupling.drag", "status", "exit_code", "steps"])
        w.writerow(["case-000", "koch_hill", "finished", 0, 10])
        w.writerow(["case-001", "gidaspow", "finished", 0, 10])
    for case, h in (("case-000", 0.17), ("case-001", 0.19)):
        (tmp_path / case / "analysis").mkdir(parents=True)
        (tmp_path / case / "analysis" / "mri.json").write_text(json.dumps(
            {"mri_bed_height_mean": h, "slab_bed_height_mean": h + 0.001, "mri_bubble_diameter_max": 0.05}))
    md = mri.compare(tmp_path).read_text()
    rows = [line for line in md.splitlines() if line.startswith("| case-")]
    assert rows[0].startswith("| case-000 | koch_hill | finished | 0.17 | 0.05 | 0.171 |")
    assert rows[1].startswith("| case-001 | gidaspow | finished | 0.19 |")
    assert (tmp_path / "mri_compare.png").exists() and (tmp_path / "mri_compare.csv").exists()


def _umf_run(tmp_path, schedule: str, t_end: float, dp: float = 100.0):
    """A run folder for umf.summarize: mri_umf's preset with ``schedule``, a flat pressure-drop series to t_end."""
    import json
    import re

    import h5py

    root = pathlib.Path(__file__).resolve().parents[1]
    text = (root / "presets" / "mri_umf.toml").read_text()
    text = re.sub(r"schedule = \[\[.*?\]\] ", f"schedule = {schedule} ", text)
    text = text.replace('start_from = "mri_umf_prepare.toml"', 'start_from = ""')
    (tmp_path / "config.toml").write_text(text)
    time = np.arange(0.0, t_end + 1e-9, 1e-3)
    with h5py.File(tmp_path / "run.h5", "w") as f:
        f["series/time"], f["series/pressure_drop"] = time, np.full_like(time, dp)
    (tmp_path / "summary.json").write_text(json.dumps({"bed_weight_per_area": 1000.0}))
    return tmp_path


def test_umf_without_holds_or_fixed_bed_points_says_why(tmp_path):
    """A schedule that only ramps (rcfd_small's) gave an empty umf.csv and U_mf NaN without a word; a run that
    ended before its first hold's second half the same. Both are now errors naming the cause; a curve whose
    holds are all fluidized keeps its table and says why U_mf is NaN (too few fixed-bed holds)."""
    from app.analysis import umf

    with pytest.raises(ValueError, match="holds no velocity"):
        umf.summarize(_umf_run(tmp_path, "[[0, 0], [0.15, 0], [0.25, 1.0]]", 0.5))
    with pytest.raises(ValueError, match=r"ended at t = 0.19 s, before the second half of the schedule's first hold"):
        umf.summarize(_umf_run(tmp_path, "[[0, 0], [0.1, 0.5], [0.3, 0.5]]", 0.19))
    fig = umf.summarize(_umf_run(tmp_path, "[[0, 0], [0.1, 0.5], [0.3, 0.5], [0.31, 0.4], [0.5, 0.4]]", 0.5, 1000.0))
    assert math.isnan(fig["umf_simulated"]) and fig["umf_fixed_bed_points"] == 0
    assert "0 hold(s) on the fixed-bed branch" in fig["umf_note"]
    assert len((tmp_path / "analysis" / "umf.csv").read_text().splitlines()) == 3  # header and both holds


def test_umf_sweep_compare_keeps_a_failed_case(tmp_path):
    """`fbed analyze SWEEP_DIR` on the U_mf sweep: each case's U_mf in one table and its curve on one figure. A
    case whose run or analysis failed vanished from the table without a word; it keeps its row, with its status."""
    import csv
    import json

    from app.analysis import umf

    with open(tmp_path / "sweep.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["case", "coupling.drag", "status"])
        w.writerow(["case-000", "koch_hill", "finished"])
        w.writerow(["case-001", "gidaspow", "failed: exit 3"])
    a = tmp_path / "case-000" / "analysis"
    a.mkdir(parents=True)
    (a / "umf.json").write_text(json.dumps({"umf_simulated": 0.31, "umf_fixed_bed_points": 4,
                                            "umf_weight_per_area": 1000.0, "drag": "koch_hill"}))
    (a / "umf.csv").write_text("velocity [m/s],pressure_drop [Pa]\n0.2,600\n0.1,300\n")
    text = umf.compare(tmp_path).read_text()
    assert "| case-000 | koch_hill | 0.31 | 4 | 1000 |" in text
    assert "| case-001 | gidaspow | no analysis: failed: exit 3 | - | - |" in text
    assert (tmp_path / "umf_compare.png").stat().st_size > 0


def test_a_bed_height_constant_over_the_window_is_analysed():
    """A fixed bed (or one whose surface stays in one 8 mm row) has a constant bed height. Its mean minus the mean
    is 5.6e-17, not 0, in floating point, with variance 0: the integral time divided by zero, and the analysis
    failed with OverflowError. A constant series is uncorrelated by convention: one frame, blocks of two."""
    from app.analysis.mri_stats import block_frames, integral_time

    h = np.full(300, 0.236)
    assert integral_time(h) == 1.0 and integral_time(h, 0.004) == 0.004 and block_frames(h) == 2
    dx, dz, nx, nz = 0.004, 0.008, 24, 75
    void = np.stack([1.0 - frame(nx, nz, dx, dz, 0.236)] * 40)
    res = mri.analyse(void, np.arange(40) * 0.004, dx, dz, n_boot=50)
    assert res["height_stats"]["mean"] == pytest.approx(0.236, abs=dz) and res["height_stats"]["std"] < 1e-12
    assert res["diameter_stats"]["n"] == 0

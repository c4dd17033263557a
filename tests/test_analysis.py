"""Porosity post-processing (app.analysis) on synthetic data with known answers.

Tolerances: 5 % on bubble diameter and rise velocity is the issue's requirement. The
discretisation error of the method itself is smaller: a sharp disc of >= 6 cells in diameter,
sampled as area fractions and refined 4x by bilinear interpolation, comes out 1-3 % small
(measured: 2.6-3.0 % at 6.4 cells, 1.1-1.4 % at 9.6 and 12.8 cells, depending on where the
centre sits on the grid; the 0.7 contour sits at 53 % of the 0.42 -> 0.95 step and the
interpolant rounds the cell-fraction profile), and the cross-correlation lag of a bubble train
sampled at 2 ms is exact to well under 1 % (measured 0.3 %). The rise-velocity checks are
exact to the same order: noses and tails timed cell by cell with linearly ramped edges come back
within 0.03 %, and the centroid of a cell-averaged sphere followed through 3-D frames within
0.03 % in velocity and 1.4 % in diameter; 5 % stays the bound.
"""
import csv
import json
import math
import pathlib

import h5py
import numpy as np
import pytest
from scipy import ndimage

from app.analysis import bubbles as bb
from app.analysis import rise
from app.analysis import verma

pytestmark = pytest.mark.unit

D_COL = 0.1
N = 32
H = D_COL / N            # 3.125 mm, the Verma grid
EPS_E, EPS_B = 0.42, 0.95  # emulsion and bubble porosity
REL = 0.05               # issue requirement (see module docstring)


# ---- synthetic fields -----------------------------------------------------------------------
def _subpoints(n0, n1, h, sub):
    x = (np.arange(n0 * sub) + 0.5) * h / sub
    y = (np.arange(n1 * sub) + 0.5) * h / sub
    return np.meshgrid(x, y, indexing="ij")


def _cell_mean(ind, n0, n1, sub):
    return ind.reshape(n0, sub, n1, sub).mean(axis=(1, 3))


def disc_plane(discs, n=N, h=H, sub=16):
    """Porosity plane with sharp discs [(x, y, diameter)]: cell value = area-weighted mix."""
    X, Y = _subpoints(n, n, h, sub)
    ind = np.zeros(X.shape, bool)
    for x, y, d in discs:
        ind |= (X - x) ** 2 + (Y - y) ** 2 < (0.5 * d) ** 2
    return EPS_E + (EPS_B - EPS_E) * _cell_mean(ind, n, n, sub)


def circle_mask(n=N, h=H):
    c = (np.arange(n) + 0.5) * h - 0.5 * n * h
    return c[:, None] ** 2 + c[None, :] ** 2 < (0.5 * n * h) ** 2


# ---- plane bubbles ----------------------------------------------------------------------------
def test_refine_plane_is_cell_centred_bilinear():
    r = np.random.default_rng(1).random((7, 5))
    for f in (2, 4):
        ref = ndimage.zoom(r, f, order=1, mode="nearest", grid_mode=True)
        assert np.allclose(bb.refine_plane(r, f), ref, atol=1e-12)
    # a linear field is reproduced exactly at the sub-cell centres (inside the outer half cell)
    i = np.arange(8)[:, None] + 0.0 * np.arange(6)[None, :]
    fine = bb.refine_plane(i, 4)
    u = (np.arange(32) + 0.5) / 4 - 0.5
    assert np.allclose(fine[2:-2, 0], u[2:-2])


@pytest.mark.parametrize("d", [0.020, 0.030, 0.040])
def test_disc_diameter(d):
    # off-centre so the disc does not sit symmetrically on the grid
    eps = disc_plane([(0.047, 0.053, d)])
    found = bb.plane_bubbles(eps, H)
    assert len(found) == 1
    b = found[0]
    assert b["diameter"] == pytest.approx(d, rel=REL)
    assert b["area"] == pytest.approx(math.pi * d * d / 4, rel=2 * REL)
    assert np.hypot(b["centroid"][0] - 0.047, b["centroid"][1] - 0.053) < H
    assert b["aspect"] < 1.1
    mean, count = bb.equivalent_diameter(np.stack([eps, eps]), H)
    assert count == 2 and mean == pytest.approx(d, rel=REL)


def test_several_discs_and_min_area():
    ds = [0.020, 0.030, 0.040]
    eps = disc_plane([(0.022, 0.025, ds[0]), (0.070, 0.025, ds[1]), (0.045, 0.070, ds[2])])
    got = sorted(b["diameter"] for b in bb.plane_bubbles(eps, H))
    assert len(got) == 3
    for g, d in zip(got, ds):
        assert g == pytest.approx(d, rel=REL)
    mean, count = bb.equivalent_diameter(eps[None], H)
    assert count == 3 and mean == pytest.approx(np.mean(ds), rel=REL)
    # a single hot cell (area ~ h^2 after refinement) is below the default 2 h^2 and dropped
    eps1 = np.full((N, N), EPS_E)
    eps1[5, 5] = 0.99
    assert bb.plane_bubbles(eps1, H) == []
    assert len(bb.plane_bubbles(eps1, H, min_area=0.0)) == 1


def test_mask_excludes_outside():
    mask = circle_mask()
    d = 0.030
    # one disc in the middle, one 5 mm from the wall; outside the cylinder porosity is 1
    discs = [(0.050, 0.050, 0.020), (0.050 + 0.030, 0.050, d)]
    eps = disc_plane(discs)
    eps[~mask] = 1.0
    unmasked = bb.plane_bubbles(eps, H)
    masked = bb.plane_bubbles(eps, H, mask=mask)
    # without the mask the outside corners are "bubbles" (and the wall disc merges with them)
    assert len(unmasked) > 2
    assert len(masked) == 2
    got = sorted(b["diameter"] for b in masked)
    assert got[0] == pytest.approx(0.020, rel=REL)
    assert got[1] == pytest.approx(d, rel=REL)   # no leak of the outside porosity near the wall
    # an all-outside mask finds nothing
    assert bb.plane_bubbles(eps, H, mask=np.zeros_like(mask)) == []


def test_max_area_drops_freeboard():
    eps = np.full((N, N), 1.0)
    mask = circle_mask()
    assert len(bb.plane_bubbles(eps, H, mask=mask)) == 1
    assert bb.plane_bubbles(eps, H, mask=mask, max_area=0.5 * mask.sum() * H * H) == []


# ---- rise velocity ---------------------------------------------------------------------------
def sphere_planes(v, z_lo, z_up, dt, nt, n_bubbles, seed, sub=4):
    """Two planes crossed by spheres rising at v; sphere i crosses z_lo (centre) at t_i."""
    rng = np.random.default_rng(seed)
    mask = circle_mask()
    X, Y = _subpoints(N, N, H, sub)
    t = np.arange(nt) * dt
    bub = []
    for _ in range(n_bubbles):
        d = rng.uniform(0.020, 0.040)
        rmax = 0.5 * D_COL - 0.5 * d - 0.003
        rr, th = rmax * math.sqrt(rng.uniform()), rng.uniform(0, 2 * math.pi)
        bub.append((rng.uniform(0.05, t[-1] - 0.1), 0.05 + rr * math.cos(th), 0.05 + rr * math.sin(th), d))
    planes = []
    for zp in (z_lo, z_up):
        eps = EPS_E + 0.02 * rng.standard_normal((nt, N, N))
        for it, tt in enumerate(t):
            ind = None
            for ti, x, y, d in bub:
                dz = zp - (z_lo + v * (tt - ti))
                r2 = (0.5 * d) ** 2 - dz * dz
                if r2 > 0:
                    c = (X - x) ** 2 + (Y - y) ** 2 < r2
                    ind = c if ind is None else ind | c
            if ind is not None:
                eps[it] += (EPS_B - EPS_E) * _cell_mean(ind, N, N, sub)
        eps[:, ~mask] = 1.0
        planes.append(eps.astype(np.float32))
    return planes[0], planes[1], mask


def test_rise_velocity_spheres():
    v, dt, spacing = 0.6, 0.002, 0.011
    lo, up, mask = sphere_planes(v, 0.050, 0.050 + spacing, dt, nt=1000, n_bubbles=12, seed=3)
    vel, lag = rise.rise_velocity(lo, up, dt, spacing, mask=mask)
    assert lag == pytest.approx(spacing / v, rel=REL)
    assert vel == pytest.approx(v, rel=REL)
    # reversed planes: the bubbles would move down, no peak at a positive lag
    vel_r, lag_r = rise.rise_velocity(up, lo, dt, spacing, mask=mask, max_lag=5)
    assert math.isnan(vel_r) and math.isnan(lag_r)
    # pure noise-free constant field: no correlation at all
    flat = np.full((50, 4, 4), 0.4)
    assert math.isnan(rise.rise_velocity(flat, flat, dt, spacing)[0])


def stretching_plug_planes(v_nose, v_tail, z_lo, z_up, dt, T=3.0, L0=0.02, D=0.030, seed=5):
    """Planes crossed by plug bubbles whose nose rises at v_nose and tail at v_tail (a bubble
    that stretches as it rises). Each cell's value is its volume fraction of bubble (the disc's
    area fraction times the fraction of the cell's height inside the plug), so edges ramp
    linearly over one cell height, as in a cell-averaged field."""
    rng = np.random.default_rng(seed)
    mask = circle_mask()
    t = np.arange(int(round(T / dt))) * dt
    t0 = 0.05 + 0.25 * np.arange(int((T - 0.3) / 0.25)) + rng.uniform(0, 0.02, int((T - 0.3) / 0.25))
    discs = []
    for _ in t0:
        rr, th = 0.015 * math.sqrt(rng.uniform()), rng.uniform(0, 2 * math.pi)
        discs.append(disc_plane([(0.05 + rr * math.cos(th), 0.05 + rr * math.sin(th), D)]) - EPS_E)
    planes = []
    for z in (z_lo, z_up):
        eps = EPS_E + 0.01 * rng.standard_normal((len(t), N, N))
        for ti, disc in zip(t0, discs):
            tail, nose = v_tail * (t - ti), L0 + v_nose * (t - ti)
            frac = np.clip((nose - z) / H + 0.5, 0, 1) * np.clip((z - tail) / H + 0.5, 0, 1)
            eps += frac[:, None, None] * disc[None]
        eps[:, ~mask] = 1.0
        planes.append(eps.astype(np.float32))
    return planes[0], planes[1], mask


def test_edge_velocities_stretching_bubbles():
    """Noses and tails timed cell by cell come back at their own speeds; the correlation of the
    whole signal lands between them."""
    v_nose, v_tail, dt, spacing = 0.8, 0.5, 0.002, 0.011
    lo, up, mask = stretching_plug_planes(v_nose, v_tail, 0.050, 0.050 + spacing, dt)
    e = rise.edge_velocities(lo, up, dt, spacing, mask=mask)
    assert e["nose"]["count"] > 500 and e["tail"]["count"] > 500   # ten plugs of about 70 cells
    assert e["nose"]["velocity"] == pytest.approx(v_nose, rel=REL)
    assert e["tail"]["velocity"] == pytest.approx(v_tail, rel=REL)
    corr, _ = rise.rise_velocity(lo, up, dt, spacing, mask=mask)
    assert v_tail * (1 - REL) < corr < v_nose * (1 + REL)
    # planes swapped: every upper crossing comes first, nothing pairs within the window
    none = rise.edge_velocities(up, lo, dt, spacing, mask=mask, min_velocity=0.2)
    assert none["nose"]["count"] < 0.05 * e["nose"]["count"]


def rising_sphere_frames(v, D, dt, nt, nz=40, sub=4, z_start=0.02, freeboard=0.11):
    """3-D frames of one sphere of diameter D rising at v, cell-averaged, with a freeboard
    (porosity 1) above ``freeboard`` that is open to the top."""
    X, Y = _subpoints(N, N, H, sub)
    zf = (np.arange(nz * sub) + 0.5) * H / sub
    mask = circle_mask()
    frames = []
    for k in range(nt):
        zc = z_start + v * k * dt
        ind = ((X - 0.05) ** 2 + (Y - 0.05) ** 2)[:, :, None] + (zf[None, None, :] - zc) ** 2 < (0.5 * D) ** 2
        frac = ind.reshape(N, sub, N, sub, nz, sub).mean(axis=(1, 3, 5))
        eps = EPS_E + (EPS_B - EPS_E) * frac
        eps[:, :, (np.arange(nz) + 0.5) * H > freeboard] = 1.0
        eps[~mask] = 1.0
        frames.append(eps)
    return np.asarray(frames, dtype=np.float32), np.arange(nt) * dt, mask


def test_track_bubbles_rising_sphere():
    v, D, dt, nt = 0.6, 0.030, 0.010, 10
    frames, t, mask = rising_sphere_frames(v, D, dt, nt)
    tr = bb.track_bubbles(frames, t, H, mask=mask)
    assert len(tr["velocity"]) == nt - 1          # one bubble, matched in every pair of frames
    assert np.all(tr["z"] < 0.11)                 # the freeboard is not a bubble
    assert np.mean(tr["velocity"]) == pytest.approx(v, rel=REL)
    assert np.allclose(tr["diameter"], D, rtol=REL)
    assert np.allclose(tr["time"], t[:-1] + 0.5 * dt)
    # a bubble that doubles its volume between frames (a coalescence) is left out
    grown = frames.copy()
    grown[5:] = rising_sphere_frames(v, D * 2 ** (1 / 3), dt, nt)[0][5:]
    assert len(bb.track_bubbles(grown, t, H, mask=mask)["velocity"]) == nt - 2


# ---- vertical slab ----------------------------------------------------------------------------
def ellipse_slab(ellipses, nx=32, nz=64, h=H, sub=16):
    X, Z = _subpoints(nx, nz, h, sub)
    ind = np.zeros(X.shape, bool)
    for x, z, a, b in ellipses:
        ind |= ((X - x) / a) ** 2 + ((Z - z) / b) ** 2 < 1.0
    return EPS_E + (EPS_B - EPS_E) * _cell_mean(ind, nx, nz, sub)


def test_slab_bubble_ellipse():
    a, b, x0, z0 = 0.012, 0.018, 0.050, 0.080
    eps = ellipse_slab([(x0, z0, a, b), (0.050, 0.150, 0.008, 0.008)])
    s = bb.slab_bubble(eps, H)
    assert s["area"] == pytest.approx(math.pi * a * b, rel=REL)
    assert s["diameter"] == pytest.approx(2 * math.sqrt(a * b), rel=REL)
    assert s["aspect"] == pytest.approx(b / a, rel=0.10)      # ratio of two extents: 10 %
    assert s["height"] == pytest.approx(2 * b, rel=REL)
    assert s["width"] == pytest.approx(2 * a, rel=REL)
    assert abs(s["centroid"][0] - x0) < H and abs(s["centroid"][1] - z0) < H
    assert abs(s["bottom"] - (z0 - b)) < H and abs(s["top"] - (z0 + b)) < H
    small = bb.slab_bubble(eps, H, seed=(0.050, 0.150))
    assert small["diameter"] == pytest.approx(0.016, rel=REL)
    assert bb.slab_bubble(eps, H, seed=(0.005, 0.005)) is None
    assert bb.slab_bubble(np.full((32, 64), EPS_E), H) is None


# ---- pdf, correlations, profile -----------------------------------------------------------------
def test_porosity_pdf_normalised():
    vals = np.random.default_rng(0).uniform(0.35, 1.0, 5000)
    c, d = bb.porosity_pdf(vals, bin=0.04)
    assert len(c) == 25 and c[0] == pytest.approx(0.02) and c[-1] == pytest.approx(0.98)
    assert np.sum(d) * 0.04 == pytest.approx(1.0, abs=1e-12)
    assert np.all(d[c < 0.32] == 0.0)


def test_correlations_hand_values():
    uex, Hh = 0.5 * 0.68, 0.1
    # independent arithmetic from the formulas in verma2014.json, and the hand-computed values
    dart = 0.54 * math.pow(uex, 0.4) * math.pow(Hh, 0.8) * math.pow(9.81, -0.2)
    wert = 0.00853 * math.pow(1 + 27 * uex, 1 / 3) * math.pow(1 + 6.4 * Hh, 1.21)
    assert float(bb.darton(Hh)) == pytest.approx(dart, rel=1e-12)
    assert float(bb.werther(Hh)) == pytest.approx(wert, rel=1e-12)
    assert dart == pytest.approx(0.03521, rel=1e-3)   # 0.54 * 0.6495 * 0.1585 * 0.6334
    assert wert == pytest.approx(0.03364, rel=1e-3)   # 0.00853 * 2.1672 * 1.8196
    assert np.allclose(bb.darton(np.array([0.05, 0.1])), [bb.darton(0.05), bb.darton(0.1)])


def test_diameter_profile_layers():
    d, nz = 0.030, 6
    frame = np.repeat(disc_plane([(0.05, 0.05, d)])[:, :, None], nz, axis=2)
    frame[:, :, :2] = EPS_E      # no bubble in the two lowest layers
    z = (np.arange(nz) + 0.5) * H
    zz, mean, count = bb.diameter_profile(frame[None], H, z)
    assert np.array_equal(zz, z)
    assert list(count) == [0, 0, 1, 1, 1, 1]
    assert np.all(np.isnan(mean[:2]))
    assert np.allclose(mean[2:], d, rtol=REL)


# ---- analyze() on a synthetic run folder ----------------------------------------------------------
SYN = {"D": 0.030, "L": 0.040, "v": 0.55, "dt": 0.002, "T": 1.6, "W": 1500.0, "dpw": 0.92}


def write_synthetic_run(run_dir, D=SYN["D"], L=SYN["L"], v=SYN["v"], dt=SYN["dt"], T=SYN["T"],
                        weight=SYN["W"], dp_ratio=SYN["dpw"], seed=7):
    """A run folder in the simulator's layout: vertical plug bubbles (cylinders of diameter D,
    length L) rising at v through plane pairs at 0.050/0.061 and 0.100/0.111 m, a few 3-D frames
    (plugs between z = 0.03 and 0.07 m, freeboard above 0.11 m), a pressure-drop series.
    Plugs are spaced in time so that no two are in a plane at once: every disc has diameter D."""
    rng = np.random.default_rng(seed)
    mask = circle_mask()
    t = np.arange(int(round(T / dt)) + 1) * dt
    nplug = int((T - 0.2) / 0.11)
    t0 = 0.1 + 0.11 * np.arange(nplug) + rng.uniform(0, 0.01, nplug)  # bottom crosses z = 0
    pos = []
    for _ in range(nplug):
        rr, th = 0.015 * math.sqrt(rng.uniform()), rng.uniform(0, 2 * math.pi)
        pos.append((0.05 + rr * math.cos(th), 0.05 + rr * math.sin(th)))
    discs = [disc_plane([p + (D,)]) for p in pos]
    empty = np.full((N, N), EPS_E)
    run_dir.mkdir(parents=True, exist_ok=True)
    with h5py.File(run_dir / verma.RUN_FILE, "w") as f:
        gp = f.create_group(verma.PLANES)
        gp.create_dataset(verma.PLANES_MASK, data=mask.astype(np.uint8))
        for z, pair, level in ((0.050, "5cm", "lower"), (0.061, "5cm", "upper"),
                               (0.100, "10cm", "lower"), (0.111, "10cm", "upper")):
            eps = np.repeat(empty[None], len(t), axis=0)
            for i, ti in enumerate(t0):
                zb = v * (t - ti)
                on = (zb <= z) & (z <= zb + L)
                eps[on] = discs[i]
            eps[:, ~mask] = 1.0
            g = gp.create_group(f"z{z:.3f}")
            g.create_dataset(verma.TIME, data=t)
            g.create_dataset(verma.POROSITY, data=eps.astype(np.float32))
            g.attrs.update({verma.ATTR_Z: z, verma.ATTR_H: H, verma.ATTR_ORIGIN: (0.0, 0.0),
                            verma.ATTR_PAIR: pair, verma.ATTR_LEVEL: level})
        nz = 40
        zc = (np.arange(nz) + 0.5) * H
        t3 = np.arange(0.2, T + 1e-9, 0.2)
        vol = np.full((len(t3), N, N, nz), EPS_E)
        vol[..., zc > 0.11] = 1.0
        for k in range(len(t3)):
            plug = disc_plane([pos[k % nplug] + (D,)])
            vol[k][:, :, (zc > 0.03) & (zc < 0.07)] = plug[:, :, None]
        vol[:, ~mask, :] = 1.0
        g3 = f.create_group(verma.POROSITY3D)
        g3.create_dataset(verma.TIME, data=t3)
        g3.create_dataset(verma.POROSITY, data=vol.astype(np.float32))
        g3.attrs.update({verma.ATTR_H: H, verma.ATTR_ORIGIN: (0.0, 0.0, 0.0)})
        gs = f.create_group(verma.SERIES)
        gs.create_dataset(verma.TIME, data=t)
        gs.create_dataset(verma.PRESSURE_DROP, data=weight * (dp_ratio + 0.03 * np.sin(2 * np.pi * t / 0.1)))
    (run_dir / verma.SUMMARY_FILE).write_text(json.dumps({verma.BED_WEIGHT_KEY: weight}))
    return run_dir


@pytest.fixture
def synthetic_run(tmp_path):
    return write_synthetic_run(tmp_path / "run")


def _mini_reference(path):
    """The parts of shared/reference/verma2014.json that analyze() reads, same layout."""
    path.write_text(json.dumps({
        "comparison_table": {"columns": ["xray", "paper_TFM", "seed_000_CFD-DEM"],
                             "De_at_H_0.10m_mm": [38, 33, 41.5], "De_at_H_0.05m_mm": [26, 20, 35.2],
                             "rise_velocity_at_0.05m_m_s": [0.55, 0.45, 0.63],
                             "rise_velocity_at_0.10m_m_s": [0.60, 0.62, 0.89],
                             "mean_dP_over_bed_weight_per_area": [None, None, 0.92]},
        "xray_bubble_diameter_vs_height": {"H_m": [0.04, 0.05, 0.1], "De_m": [0.022, 0.026, 0.038]},
        "tfm_bubble_diameter_vs_height": {"H_m": [0.02, 0.1, 0.2], "De_m": [0.015, 0.033, 0.045]},
        "porosity_pdf_peaks": {"xray_emulsion": 0.56, "xray_bubble": 0.88},
    }))
    return path


def test_analyze_synthetic_run(synthetic_run, tmp_path):
    ref = _mini_reference(tmp_path / "verma2014.json")
    res = verma.analyze(synthetic_run, reference=ref)
    out = synthetic_run / verma.ANALYSIS_DIR
    assert res["out_dir"] == out
    assert res["t_cut"] == pytest.approx(0.8)        # 1.0 s clipped to half of the 1.6 s run
    for name in verma.FIGURES:
        p = out / f"{name}.png"
        assert p.is_file() and p.stat().st_size > 1000 and res["figures"][name] == p
    assert (out / verma.TABLE_MD).is_file()
    with open(out / verma.TABLE_CSV) as fh:
        rows = {r["quantity"]: r for r in csv.DictReader(fh)}
    assert list(next(iter(rows.values())).keys()) == ["quantity", *verma.COLUMNS]
    D, v = SYN["D"], SYN["v"]
    for key in ("De_at_H_0.05m_mm", "De_at_H_0.10m_mm"):
        assert float(rows[key]["fbed"]) == pytest.approx(1e3 * D, rel=REL)
    for key in ("rise_velocity_at_0.05m_m_s", "rise_velocity_at_0.10m_m_s"):
        assert float(rows[key]["fbed"]) == pytest.approx(v, rel=REL)
    assert float(rows["mean_dP_over_bed_weight_per_area"]["fbed"]) == pytest.approx(SYN["dpw"], abs=0.01)
    assert float(rows["De_at_H_0.10m_mm"]["xray"]) == 38 and float(rows["De_at_H_0.05m_mm"]["seed_000"]) == 35.2
    assert rows["mean_dP_over_bed_weight_per_area"]["xray"] == ""
    # 3-D profile: plug layers give D, the freeboard (whole cross-section above 0.7) is no bubble
    prof = res["profile"]
    inplug = (prof["z"] > 0.03) & (prof["z"] < 0.07)
    assert np.all(prof["count"][inplug] > 0)
    assert np.allclose(prof["De"][inplug], D, rtol=REL)
    assert np.all(prof["count"][prof["z"] > 0.11] == 0)
    # the rise-velocity check: sharp plugs rising at v, their noses and tails timed between the planes
    with open(out / verma.RISE_CSV) as fh:
        rise = {r["pair"]: r for r in csv.DictReader(fh)}
    assert set(rise) == {"5cm", "10cm"}
    for r in rise.values():
        assert float(r["nose_m_s"]) == pytest.approx(v, rel=REL)
        assert float(r["tail_m_s"]) == pytest.approx(v, rel=REL)
        assert float(r["correlation_m_s"]) == pytest.approx(v, rel=REL)


def test_analyze_without_reference(synthetic_run, tmp_path):
    res = verma.analyze(synthetic_run, out_dir=tmp_path / "a", reference=None, t_discard=0.5)
    assert res["t_cut"] == pytest.approx(0.5)
    with open(tmp_path / "a" / verma.TABLE_CSV) as fh:
        header = next(csv.reader(fh))
    assert header == ["quantity", "fbed"]
    assert res["table"]["De_at_H_0.05m_mm"]["fbed"] == pytest.approx(1e3 * SYN["D"], rel=REL)


def test_analyze_a_run_without_planes_or_volume_is_refused(tmp_path):
    """`fbed analyze RUN --kind verma` on a run without plane or 3-D records wrote a table of dashes beside the
    X-ray's and said "written": now the analysis fails, naming the probe keys that record them."""
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    with h5py.File(run_dir / verma.RUN_FILE, "w") as f:
        f.create_dataset(f"{verma.SERIES}/{verma.TIME}", data=np.linspace(0, 2, 201))
        f.create_dataset(f"{verma.SERIES}/{verma.PRESSURE_DROP}", data=np.full(201, 1400.0))
    (run_dir / verma.SUMMARY_FILE).write_text(json.dumps({verma.BED_WEIGHT_KEY: 1500.0}))
    with pytest.raises(ValueError, match="neither /planes nor /porosity3d.*probes.planes.*probes.volume_interval"):
        verma.analyze(run_dir, reference=None)


@pytest.mark.parametrize("analysis, probes, said", [
    ("mri", "mri_interval = 0.004\nslab_interval = 0.004", "probes.mri_interval = 0.004 s or probes.slab_interval"),
    ("boyce", "slab_interval = 0.002", "probes.slab_interval = 0.002 s: run longer than 0.002 s"),
    ("verma", "planes = [0.05]\nplanes_interval = 0.003", "probes.planes_interval = 0.003 s: run longer"),
])
def test_an_analysis_of_a_run_that_ended_before_its_first_record_says_so(tmp_path, analysis, probes, said):
    """A run shorter than its probes' interval records nothing, and its analysis told it to set the interval it
    had set ("run.h5 holds neither /mri nor /slab: set probes.mri_interval", on a 0.1 ms run of mri_poppy). It
    now says when the run ended, and how long it must run."""
    import pathlib

    from app.postprocess import post_process

    text = (pathlib.Path(__file__).parents[1] / "presets" / "fluidize.toml").read_text()
    (tmp_path / "config.toml").write_text(text.replace("[output]", f"[probes]\n{probes}\nanalysis = \"{analysis}\"\n\n"
                                                       "[output]", 1))
    with h5py.File(tmp_path / "run.h5", "w") as f:
        f["series/time"] = [0.0, 0.001]
    why = post_process(analysis, tmp_path)["analysis_error"]
    assert why.startswith("ValueError: the run ended at t = 0.001 s, before the first record of") and said in why, why


def test_the_run_analysis_starts_at_output_average_from(tmp_path):
    """At a run's end (and in `fbed analyze`) the window is the preset's own, as the MRI analysis: a Verma session
    going on from a carried fluidized state (benchmarks/device_run.sh VERMA_FROM: average_from 0.02, 3 s) discarded
    its first 1 s, whatever the preset said. Negative: the second half of the records."""
    from app import config as cfgmod

    run_dir = tmp_path / "run"
    write_synthetic_run(run_dir)
    root = pathlib.Path(__file__).resolve().parents[1]
    cfg = cfgmod.load(root / "presets" / "verma_small.toml", ["output.average_from=0.02"])
    (run_dir / "config.toml").write_text(cfgmod.dump(cfg))
    assert verma.summarize(run_dir)["verma_analysed_from"] == pytest.approx(0.02)
    for t_from, window in ((0.3, 0.3), (-1.0, 0.8), (None, 0.8)):  # None: analyze() alone, its first 1 s clipped
        assert verma._read_run(run_dir / verma.RUN_FILE, 1.0, t_from)["t_cut"] == pytest.approx(window)


def test_an_average_from_after_the_records_is_refused_naming_it(tmp_path):
    from app import config as cfgmod

    run_dir = tmp_path / "run"
    write_synthetic_run(run_dir)
    root = pathlib.Path(__file__).resolve().parents[1]
    (run_dir / "config.toml").write_text(cfgmod.dump(cfgmod.load(root / "presets" / "verma_small.toml",
                                                                 ["output.average_from=2.0"])))
    with pytest.raises(ValueError, match="output.average_from = 2 s"):
        verma.summarize(run_dir)


# ---- several runs of one case pooled (fbed analyze RUN RUN --out DIR on verma runs) ---------------------------
def test_pooled_correlation_ignores_the_jump_between_runs():
    """Two runs whose emulsion sits at different porosity (0.15 apart). Each run's correlation formed alone (its own
    means subtracted) and summed: the offset cancels exactly and the lag is the bubbles'. Correlated as one record,
    the step between the runs enters the correlation and moves the velocity."""
    v, dt, spacing = 0.6, 0.002, 0.011
    lo1, up1, mask = sphere_planes(v, 0.050, 0.050 + spacing, dt, nt=600, n_bubbles=7, seed=3)
    lo2, up2, _ = sphere_planes(v, 0.050, 0.050 + spacing, dt, nt=400, n_bubbles=5, seed=4)
    plain = [np.concatenate([x, y]).astype(float) for x, y in ((lo1, lo2), (up1, up2))]
    step = [np.concatenate([x, np.where(mask, y + 0.15, y)]).astype(float) for x, y in ((lo1, lo2), (up1, up2))]
    vel, lag = rise.rise_velocity(*step, dt, spacing, mask=mask, segments=[0, 600])
    assert vel == pytest.approx(v, rel=REL)
    # (to 1e-7: the offset was added in float32, whose rounding of the values is 6e-8)
    assert vel == pytest.approx(rise.rise_velocity(*plain, dt, spacing, mask=mask, segments=[0, 600])[0], rel=1e-7)
    naive = [rise.rise_velocity(*x, dt, spacing, mask=mask)[0] for x in (plain, step)]
    assert abs(naive[1] - naive[0]) > 1e-3 * v


def test_noses_pair_within_one_run():
    """A nose in the lower plane at the end of one run and one in the upper plane at the start of the next are two
    bubbles, not one 4 ms apart."""
    lo, up = np.full((20, 1, 1), 0.4), np.full((20, 1, 1), 0.4)
    lo[8:10], up[11:14] = 0.9, 0.9
    assert rise.edge_velocities(lo, up, 0.002, 0.011)["nose"]["count"] == 1
    assert rise.edge_velocities(lo, up, 0.002, 0.011, segments=[0, 10])["nose"]["count"] == 0


def _verma_session(run_dir, seed, overrides):
    from app import config as cfgmod

    write_synthetic_run(run_dir, seed=seed)
    root = pathlib.Path(__file__).resolve().parents[1]
    cfg = cfgmod.load(root / "presets" / "verma_small.toml", overrides)
    (run_dir / "config.toml").write_text(cfgmod.dump(cfg))
    return run_dir


def test_fbed_analyze_pools_verma_sessions(tmp_path, capsys):
    """Two sessions (the second going on from the first's packed state: another duration, inlet at full speed from
    0, analysed from 0.02 s): their frames pool. Bubbles per plane add up, the pressure drop over the weight is the
    frame-weighted mean, the velocities are the plugs' 0.55 m/s."""
    from app.cli import main

    a = _verma_session(tmp_path / "a", 7, ["output.average_from=0.3"])
    b = _verma_session(tmp_path / "b", 8, ["output.average_from=0.02", "run.duration=3.0", "particles.count=0",
                                            "particles.bed_height=0.0", 'particles.initial_state="state.h5"',
                                            "boundary.bottom.schedule=[[0.0,1.0]]"])
    (tmp_path / "b" / "state.h5").write_bytes(b"")
    alone = [verma._read_run(d / verma.RUN_FILE, 1.0, t) for d, t in ((a, 0.3), (b, 0.02))]
    one = [{"planes": verma._plane_bubbles(r, bb.THRESHOLD, bb.FACTOR),
            "dp_over_weight": verma._dp_over_weight(r, SYN["W"], r["t_cut"])} for r in alone]
    out = tmp_path / "pooled"
    assert main(["analyze", str(a), str(b), "--out", str(out)]) == 0, capsys.readouterr().err
    pooled = json.loads((out / "pooled.json").read_text())
    nf = [int(round((1.6 - 0.3) / SYN["dt"])) + 1, int(round((1.6 - 0.02) / SYN["dt"])) + 1]
    assert pooled["frames"]["planes"] == nf
    assert any(n.startswith("particles.initial_state") for n in pooled["session_differences"])
    with open(out / verma.ANALYSIS_DIR / verma.TABLE_CSV) as fh:
        rows = {r["quantity"]: r for r in csv.DictReader(fh)}
    for key in ("rise_velocity_at_0.05m_m_s", "rise_velocity_at_0.10m_m_s"):
        assert float(rows[key]["fbed"]) == pytest.approx(SYN["v"], rel=REL)
    for key in ("De_at_H_0.05m_mm", "De_at_H_0.10m_mm"):
        assert float(rows[key]["fbed"]) == pytest.approx(1e3 * SYN["D"], rel=REL)
    assert pooled["bubbles_per_plane"] == {n: sum(r["planes"][n]["count"] for r in one) for n in one[0]["planes"]}
    dpw = [r["dp_over_weight"] for r in one]
    assert pooled["figures"]["verma_mean_dP_over_bed_weight_per_area"] == pytest.approx(
        (nf[0] * dpw[0] + nf[1] * dpw[1]) / sum(nf), rel=1e-6)
    # the synthetic pressure drop is one periodic signal in both: the runs agree
    agree = pooled["runs_dp_over_weight"]
    assert [r["frames"] for r in agree["rows"]] == nf and agree["p"] > 0.01
    assert agree["rows"][0]["mean"] == pytest.approx(dpw[0], rel=1e-9)

"""The MRI post-processing of the poppy-seed bed study, on a series of slab images.

Owns: the source study's pipeline (seed 002, its Section 3.3) applied to images of the solid
fraction on the 10 mm vertical slab through the bed's axis, either the synthetic MRI
(run.h5 ``/mri``: the grains' volume binned onto the MRI's pixels, ``app.probes_mri``) or the
gas grid's own solid fraction on the same slab (run.h5 ``/slab``, ``app.probes``), which is
what the study post-processed. Plain numpy/scipy/matplotlib, no Taichi.

The steps, each a function below:
- binarisation at solid-fraction thresholds 0.15 ... 0.40: solid where alpha_s >= threshold;
- bubbles: connected gas regions (8-connected, holes filled: the outer contours of the study's
  ``RETR_EXTERNAL``) of at least 4 mm^2, without those that reach the image's top row (the
  freeboard), the bed surface row or the bottom row (the inlet); equivalent diameter
  2 sqrt(A / pi) with A the pixel area, aspect ratio width / height of the bounding rectangle,
  centroid;
- tracking: each bubble is matched to the nearest centroid of the next frame within a maximum
  displacement (greedy, nearest pairs first, one partner each); a track needs at least two frames
  and its velocity is the least-squares slope of its centroid against time;
- bed height: the centre of the top-most row whose particle occupancy (solid pixels over the
  vessel's pixels in that row) exceeds 10%, from the floor; expansion ratio over the static
  height (130 mm);
- statistics: mean, maximum and standard deviation with 95% bootstrap intervals (10,000
  resamples with replacement, percentile intervals, as the study) and two-sample KS tests between
  neighbouring thresholds; beside the study's interval, one over blocks of consecutive frames (``_blocks``:
  the frames are correlated, so resampling them one by one gives intervals too narrow);
- the threshold per metric from the study's criteria only (CV < 30%, interval width < 30% of the
  mean, KS p > 0.01 against the neighbouring thresholds, gradient quality > 0.3, bubble velocity
  within 5-80 cm/s), never from data: ``choose_threshold`` says how ties are broken;
- radial solid-fraction profiles (continuous alpha_s, eq. 26) over the whole bed (below each
  frame's bed height) and below the static height; diameter against height; velocity per bubble
  size class; the spectrum of the void fraction of the slab below the static height.

Units: images in m (pixel sizes, origin), times in s; tables in mm and m/s as their headers say.
The statistics (bootstrap, gradient quality, threshold choice) live in ``mri_stats``, the tables in
``mri_report`` and the figures in ``mri_figures``; they are reachable from here as before (``mri.bootstrap``,
``mri.write``, ...).
"""
from __future__ import annotations

import json
import math
import pathlib

import numpy as np
from scipy import ndimage, signal, stats

from .mri_stats import (CI_MAX, CV_MAX, GRADIENT_MIN, KS_MIN, N_BOOT, THRESHOLDS, V_RANGE,  # noqa: F401
                        block_bootstrap, block_frames, bootstrap, choose_threshold, gradient_quality, halves,
                        sessions_agree, spans)
from .mri_report import COMPARE_KEYS, SOURCES, _steady_line, compare, write  # noqa: F401

MIN_AREA = 4.0e-6         # m^2: smallest bubble (the study's 4 mm^2)
OCCUPANCY = 0.10          # a row with more solid pixels than this fraction is inside the bed
STATIC_HEIGHT = 0.130     # m: the static bed of the study
SIZE_CLASSES = (0.0, 0.010, 0.020, 0.030, 0.040, 0.060, 1.0)  # m: bubble-diameter classes for the velocities
HEIGHT_BIN = 0.020        # m: bins of bubble centroid height for diameter against height
EIGHT = np.ones((3, 3), bool)


# ---------------------------------------------------------------- one frame
def binarise(alpha: np.ndarray, threshold: float) -> np.ndarray:
    """Eq. 14: True (solid-rich) where alpha_s >= threshold."""
    return np.asarray(alpha) >= threshold


def bed_height(solid: np.ndarray, dz: float, mask: np.ndarray | None = None) -> float:
    """Height [m above the image's bottom edge] of the centre of the top-most row whose particle occupancy
    exceeds OCCUPANCY; 0 when no row does. ``solid`` is (nx, nz), z the second axis."""
    m = np.ones(solid.shape, bool) if mask is None else mask
    n = m.sum(0)
    occ = (solid & m).sum(0) / np.maximum(n, 1)
    rows = np.nonzero((occ > OCCUPANCY) & (n > 0))[0]
    return float((rows[-1] + 0.5) * dz) if rows.size else 0.0


def bubbles(solid: np.ndarray, dx: float, dz: float, mask: np.ndarray | None = None,
            surface: float | None = None, min_area: float = MIN_AREA) -> list[dict]:
    """The bubbles of one binary frame: dicts of area [m^2], diameter [m], aspect (w/h), width, height,
    x, z (centroid, m from the image's lower-left corner)."""
    m = np.ones(solid.shape, bool) if mask is None else mask
    gas = ~solid & m
    labels, n = ndimage.label(gas, structure=EIGHT)
    if n == 0:
        return []
    nz = solid.shape[1]
    top_row = nz - 1 if surface is None else min(nz - 1, int(math.floor(surface / dz)))
    out = []
    for k, sl in enumerate(ndimage.find_objects(labels), start=1):
        if sl is None:
            continue
        reg = ndimage.binary_fill_holes(labels[sl] == k)
        z0, z1 = sl[1].start, sl[1].stop - 1
        if z0 == 0 or z1 >= top_row or z1 == nz - 1:
            continue  # the inlet row, the bed surface or the freeboard
        area = float(reg.sum()) * dx * dz
        if area < min_area:
            continue
        ii, kk = np.nonzero(reg)
        w, h = (sl[0].stop - sl[0].start) * dx, (z1 - z0 + 1) * dz
        out.append(dict(area=area, diameter=2.0 * math.sqrt(area / math.pi), aspect=w / h, width=w, height=h,
                        x=float((ii.mean() + sl[0].start + 0.5) * dx), z=float((kk.mean() + z0 + 0.5) * dz)))
    return out


# ---------------------------------------------------------------- tracking
def track(frames: list[list[dict]], times: np.ndarray, max_disp: float, breaks=()) -> list[dict]:
    """Nearest-centroid tracks over consecutive frames (greedy: the nearest pairs are linked first, each bubble
    at most once); no track links across a frame in ``breaks`` (the first frame of another run, pooled). Returns
    tracks of >= 2 frames: dicts with frames, times, x, z, diameters, and the least-squares velocities vx, vz,
    speed [m/s]."""
    open_tracks: dict[int, dict] = {}
    done = []
    breaks = set(int(b) for b in breaks)
    for f, bs in enumerate(frames):
        if f in breaks:
            done += list(open_tracks.values())
            open_tracks = {}
        new_open = {}
        prev = list(open_tracks.items())
        if prev and bs:
            px = np.array([[t["x"][-1], t["z"][-1]] for _, t in prev])
            cx = np.array([[b["x"], b["z"]] for b in bs])
            d = np.hypot(px[:, None, 0] - cx[None, :, 0], px[:, None, 1] - cx[None, :, 1])
            pairs = sorted(zip(*np.nonzero(d <= max_disp)), key=lambda ij: d[ij])
            used_p, used_c = set(), set()
            for i, j in pairs:
                if i in used_p or j in used_c:
                    continue
                used_p.add(i)
                used_c.add(j)
                t = prev[i][1]
                b = bs[j]
                t["frames"].append(f)
                t["x"].append(b["x"])
                t["z"].append(b["z"])
                t["diameter"].append(b["diameter"])
                new_open[j] = t
            for i, (_, t) in enumerate(prev):
                if i not in used_p:
                    done.append(t)
        else:
            done += [t for _, t in prev]
        for j, b in enumerate(bs):
            if j not in new_open:
                new_open[j] = dict(frames=[f], x=[b["x"]], z=[b["z"]], diameter=[b["diameter"]])
        open_tracks = new_open
    done += list(open_tracks.values())
    out = []
    for t in done:
        if len(t["frames"]) < 2:
            continue
        tt = np.asarray(times)[t["frames"]]
        vx = float(np.polyfit(tt, t["x"], 1)[0])
        vz = float(np.polyfit(tt, t["z"], 1)[0])
        out.append(dict(t, times=tt, vx=vx, vz=vz, speed=math.hypot(vx, vz),
                        mean_diameter=float(np.mean(t["diameter"]))))
    return out


def max_displacement(frame_dt: float, dx: float, dz: float, v_max: float = V_RANGE[1]) -> float:
    """Largest centroid step between frames [m]: the fastest expected bubble (0.8 m/s) over one frame interval,
    plus a pixel diagonal for the centroid's jitter as the bubble's outline changes pixels."""
    return v_max * frame_dt + math.hypot(dx, dz)


# ---------------------------------------------------------------- the image series
def solid_images(void: np.ndarray) -> np.ndarray:
    return 1.0 - np.asarray(void, float)


def radial_profiles(alpha: np.ndarray, heights: np.ndarray, dz: float, static_height: float,
                    mask: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Eq. 26 per image column: the time-mean solid fraction over the rows below each frame's bed height
    (whole bed) and over the rows below the static height. alpha (nt, nx, nz), heights (nt,) [m]."""
    nt, nx, nz = alpha.shape
    zc = (np.arange(nz) + 0.5) * dz
    m = np.ones((nx, nz), bool) if mask is None else mask
    whole = (zc[None, :] <= heights[:, None] + 1e-9 * dz)[:, None, :] & m[None]
    static = np.broadcast_to((zc < static_height)[None, None, :] & m[None], alpha.shape)
    with np.errstate(invalid="ignore"):
        pw = (alpha * whole).sum((0, 2)) / whole.sum((0, 2))
        ps = (alpha * static).sum((0, 2)) / static.sum((0, 2))
    return pw, ps


def spectrum(series: np.ndarray, dt: float, segments=None) -> tuple[np.ndarray, np.ndarray, float]:
    """(frequencies [Hz], power, the dominant frequency [Hz]) of a time series: the periodogram of the series
    minus its linear trend with a Hann window; the peak (above the lowest bin) refined by a parabola through
    the log power of its neighbours. A series pooled from several runs (``segments``: their first frames): each
    run's periodogram on the longest run's frequencies (zero-padded), averaged weighted by its frames."""
    x = np.asarray(series, float)
    sp = spans(x.size, segments)
    if len(sp) == 1:
        f, p = signal.periodogram(x, fs=1.0 / dt, window="hann", detrend="linear")
    else:
        n = max(e - a for a, e in sp)
        parts = [(e - a) * signal.periodogram(x[a:e], fs=1.0 / dt, window="hann", detrend="linear", nfft=n)[1]
                 for a, e in sp if e - a > 1]
        f, p = np.fft.rfftfreq(n, dt), np.sum(parts, 0) / sum(e - a for a, e in sp if e - a > 1)
    if p.size < 3:
        return f, p, math.nan
    k = 1 + int(np.argmax(p[1:]))
    if 1 <= k < p.size - 1 and np.all(p[k - 1:k + 2] > 0):
        a, b, c = np.log(p[k - 1:k + 2])
        den = a - 2 * b + c
        shift = 0.5 * (a - c) / den if den != 0 else 0.0
        return f, p, float(f[k] + shift * (f[1] - f[0]))
    return f, p, float(f[k])


def analyse(void: np.ndarray, times: np.ndarray, dx: float, dz: float, mask: np.ndarray | None = None,
            static_height: float = STATIC_HEIGHT, thresholds=THRESHOLDS, n_boot: int = N_BOOT,
            axis: float | None = None, segments=None) -> dict:
    """The whole pipeline on one image series of void fraction (nt, nx, nz) (z the second image axis, from the
    floor; x from the image's left edge; ``axis`` [m from that edge] is the vessel's axis, default the image's
    centre). Returns per-threshold statistics, the chosen threshold per metric,
    and the final metrics at it (see the module doc). ``segments``: the first frames of the runs a series pools
    (:func:`summarize_pooled`): no track links two runs, no block spans two, the spectrum is the runs' mean, and
    ``sessions`` says whether the runs' bed heights agree."""
    alpha = solid_images(void)
    times = np.asarray(times, float)
    nt, nx, nz = alpha.shape
    sp = spans(nt, segments)
    steps = np.concatenate([np.diff(times[a:e]) for a, e in sp])
    frame_dt = float(np.median(steps)) if steps.size else 1.0
    max_disp = max_displacement(frame_dt, dx, dz)
    per = {thr: _at_threshold(alpha, thr, times, dx, dz, mask, max_disp, [a for a, _ in sp]) for thr in thresholds}
    table, chosen = _threshold_table(per, thresholds, n_boot)
    # the final metrics, each at its own threshold
    hb = per[chosen["bed_height"]]["height"]
    dthr = chosen["bubble_diameter"]
    vthr = chosen["bubble_velocity"]
    pw, ps = radial_profiles(alpha, hb, dz, static_height, mask)
    xc = (np.arange(nx) + 0.5) * dx - (0.5 * nx * dx if axis is None else axis)
    zc = (np.arange(nz) + 0.5) * dz
    below = zc < static_height
    m = np.ones((nx, nz), bool) if mask is None else mask
    mid = np.where(m[None] & below[None, None, :], 1.0 - alpha, 0.0).sum((1, 2)) / max(1, (m & below[None]).sum())
    f, p, f_peak = spectrum(mid, frame_dt, segments)
    db = [b for bs in per[dthr]["frames"] for b in bs]
    blk = block_frames(hb, segments)  # the frames are correlated: intervals also over blocks of frames

    def blocks(groups):
        return block_bootstrap(groups, blk, n_boot, segments=segments)

    hstat = bootstrap(hb, n_boot) | blocks([[h] for h in hb])
    athr = chosen["aspect_ratio"]
    return dict(table=table, chosen=chosen, frame_dt=frame_dt, max_disp=max_disp, block_frames=blk,
                height_halves=halves(hb, blk), segments=[a for a, _ in sp],
                sessions=sessions_agree(hb, segments, blk) if len(sp) > 1 else None,
                height=hb, height_stats=hstat, expansion_ratio=hstat["mean"] / static_height,
                expansion_ratio_max=hstat["max"] / static_height,
                diameter_stats=bootstrap(per[dthr]["diameter"], n_boot) | blocks(
                    [[b["diameter"] for b in bs] for bs in per[dthr]["frames"]]),
                aspect_stats=bootstrap(per[athr]["aspect"], n_boot) | blocks(
                    [[b["aspect"] for b in bs] for bs in per[athr]["frames"]]),
                velocity_stats=bootstrap(per[vthr]["velocity"], n_boot) | blocks(_by_start(per[vthr]["tracks"], nt)),
                x=xc, radial_whole=pw, radial_static=ps, diameter_height=diameter_vs_height(db, nz * dz),
                velocity_classes=velocity_classes(per[vthr]["tracks"], n_boot, nt, blk, segments),
                mid_void=mid, freq=f, power=p, f_peak=f_peak,
                f_resolution=1.0 / (max(e - a for a, e in sp) * frame_dt), static_height=static_height,
                bubbles_at_diameter_threshold=db, times=times)


METRICS = {"bed_height": "height", "bubble_diameter": "diameter", "aspect_ratio": "aspect",
           "bubble_velocity": "velocity"}  # metric name: its key in a threshold's results


def _at_threshold(alpha: np.ndarray, thr: float, times: np.ndarray, dx: float, dz: float, mask, max_disp: float,
                  breaks=()):
    """One threshold over the series: bed heights, bubbles per frame, tracks (none across ``breaks``), and the
    per-metric samples."""
    solid = binarise(alpha, thr)
    h = np.array([bed_height(solid[t], dz, mask) for t in range(len(alpha))])
    frames = [bubbles(solid[t], dx, dz, mask, surface=h[t]) for t in range(len(alpha))]
    tracks = track(frames, times, max_disp, breaks)
    return dict(height=h, frames=frames, tracks=tracks,
                diameter=np.array([b["diameter"] for bs in frames for b in bs]),
                aspect=np.array([b["aspect"] for bs in frames for b in bs]),
                velocity=np.array([t["vz"] for t in tracks]))


def _threshold_table(per: dict, thresholds, n_boot: int) -> tuple[list[dict], dict]:
    """Per metric and threshold: bootstrap statistics, the interval's width, the KS p-value against the
    neighbouring thresholds (the smaller), the gradient quality, the failed criteria; and the threshold chosen
    per metric (``choose_threshold``)."""
    table, chosen = [], {}
    for name, key in METRICS.items():
        rows = []
        for i, thr in enumerate(thresholds):
            b = bootstrap(per[thr][key], n_boot, seed=i)
            ks = []
            for j in (i - 1, i + 1):
                if 0 <= j < len(thresholds) and b["n"] and per[thresholds[j]][key].size:
                    ks.append(float(stats.ks_2samp(per[thr][key], per[thresholds[j]][key]).pvalue))
            width = 100.0 * (b.get("mean_hi", math.nan) - b.get("mean_lo", math.nan)) / abs(b["mean"]) \
                if b["n"] and b["mean"] else math.nan
            rows.append(dict(metric=name, threshold=thr, **b, ci_width_pct=width,
                             ks_p=min(ks) if ks else math.nan))
        for r, q in zip(rows, gradient_quality([r["mean"] for r in rows], thresholds)):
            r["gradient_quality"] = q
        k, fails = choose_threshold(rows, velocity=(name == "bubble_velocity"))
        for r, f in zip(rows, fails):
            r["fails"] = f
            r["chosen"] = r is rows[k]
        chosen[name] = thresholds[k]
        table += rows
    return table, chosen


def diameter_vs_height(found: list[dict], top: float) -> list[dict]:
    """Bubbles' diameters in bins of HEIGHT_BIN of their centroid height from 0 to ``top`` [m]: n, mean, max, std."""
    edges = np.arange(0.0, top + HEIGHT_BIN, HEIGHT_BIN)
    out = []
    for a, b in zip(edges[:-1], edges[1:]):
        sel = [x["diameter"] for x in found if a <= x["z"] < b]
        if sel:
            out.append(dict(z_lo=a, z_hi=b, n=len(sel), mean=float(np.mean(sel)), max=float(np.max(sel)),
                            std=float(np.std(sel, ddof=1)) if len(sel) > 1 else 0.0))
    return out


def velocity_classes(tracks: list[dict], n_boot: int, frames: int = 0, block: int = 1, segments=None) -> list[dict]:
    """Rise velocity (bootstrap statistics of vz) per bubble-diameter class of SIZE_CLASSES (track mean diameter);
    with ``frames`` (the record's), also the interval over blocks of ``block`` frames (each track under the frame
    it starts in), as for the metrics."""
    out = []
    for a, b in zip(SIZE_CLASSES[:-1], SIZE_CLASSES[1:]):
        mine = [t for t in tracks if a <= t["mean_diameter"] < b]
        if mine:
            row = dict(d_lo=a, d_hi=b, **bootstrap([t["vz"] for t in mine], n_boot))
            if frames:
                row |= block_bootstrap(_by_start(mine, frames), block, n_boot, segments=segments)
            out.append(row)
    return out


def _by_start(tracks: list[dict], frames: int) -> list[list[float]]:
    """Each track's rise velocity under the frame it starts in (``frames`` lists, one a frame: block_bootstrap's
    groups)."""
    out = [[] for _ in range(frames)]
    for t in tracks:
        out[t["frames"][0]].append(t["vz"])
    return out


# ---------------------------------------------------------------- run files, tables, figures
def read_images(run_dir: pathlib.Path, source: str):
    """(void (nt, nx, nz), times, dx, dz, origin (x0, z0), mask) of run.h5 /mri or /slab."""
    import h5py

    with h5py.File(pathlib.Path(run_dir) / "run.h5", "r") as f:
        if source not in f:
            return None
        g = f[source]
        void = g["porosity"][...].astype(float)
        times = g["time"][...]
        if "pixel" in g.attrs:
            dx, dz = (float(v) for v in g.attrs["pixel"])
        else:
            dx = dz = float(g.attrs["h"])
        mask = g.attrs["mask"].astype(bool) if "mask" in g.attrs else None
        return void, times, dx, dz, tuple(float(v) for v in g.attrs["origin"]), mask


def _window(run_dir: pathlib.Path, cfg, source: str):
    """(void, times, dx, dz, origin, mask) of a run's /mri or /slab from output.average_from on (negative: the second
    half; the transient before it is not analysed), the slab's closed cells as gas; None without the record."""
    img = read_images(run_dir, source)
    if img is None:
        return None
    void, times, dx, dz, origin, mask = img
    t0 = cfg.output.average_from if cfg.output.average_from >= 0 else 0.5 * (times[0] + times[-1])
    keep = times >= t0 - 1e-9
    if keep.sum() < 2:
        raise ValueError(f"fewer than 2 /{source} frames after output.average_from = {t0:g} s in {run_dir}")
    floor = cfg.vessel.floor if cfg.vessel.floor is not None else cfg.domain.lo[2]
    if abs(origin[1] - floor) > 1e-9:
        raise ValueError(f"/{source} images start at z = {origin[1]} m, not at the floor {floor} m")
    void = void[keep]
    if source == "slab" and mask is not None:
        void = np.where(mask[None], void, 1.0)
    return void, times[keep], dx, dz, origin, mask


def summarize(run_dir) -> dict:
    """The pipeline on a finished run's /mri and /slab records from output.average_from on (negative: the second
    half); tables and figures under analysis/<source>; returns key figures (SI) prefixed mri_ and slab_ for
    summary.json."""
    from .. import config as cfgmod

    run_dir = pathlib.Path(run_dir)
    cfg = cfgmod.load(run_dir / "config.toml")
    static = cfg.probes.mri_static_height or STATIC_HEIGHT
    figures, found = {}, False
    for source, label in SOURCES:
        img = _window(run_dir, cfg, source)
        if img is None:
            continue
        found = True
        void, times, dx, dz, origin, mask = img
        res = analyse(void, times, dx, dz, mask, static, axis=cfg.vessel.center[0] - origin[0])
        figs = write(res, run_dir / "analysis" / source, f"{cfg.run.name or run_dir.name}: {label}")
        figures.update({f"{source}_{k}": v for k, v in figs.items()})
    if not found:
        raise ValueError("run.h5 holds neither /mri nor /slab: set probes.mri_interval or probes.slab_interval")
    (run_dir / "analysis" / "mri.json").write_text(json.dumps(figures, indent=2) + "\n")
    return figures


def summarize_pooled(run_dirs, out_dir) -> dict:
    """The pipeline on the analysed windows of several runs of one case (``pooling.check_same_case``), pooled as
    realisations of one operating point: the frames of all, each run a segment (``analyse``'s ``segments``), laid
    end to end in time (each run's times shifted by a constant, which leaves its velocities alone). Tables and
    figures under OUT/analysis/<source>, the figures in OUT/analysis/mri.json and OUT/pooled.json with the runs,
    their frames and the session keys that differ."""
    from .. import config as cfgmod
    from .pooling import check_same_case

    run_dirs, out_dir = [pathlib.Path(d) for d in run_dirs], pathlib.Path(out_dir)
    cfgs = [cfgmod.load(d / "config.toml") for d in run_dirs]
    wins = {src: [_window(d, c, src) for d, c in zip(run_dirs, cfgs)] for src, _ in SOURCES}
    wins = {src: w for src, w in wins.items() if any(x is not None for x in w)}
    if not wins:
        raise ValueError("the runs' run.h5 hold neither /mri nor /slab: set probes.mri_interval or "
                         "probes.slab_interval")
    for src, w in wins.items():
        if any(x is None for x in w):
            raise ValueError(f"/{src} is missing in {run_dirs[[x is None for x in w].index(True)]}: pool runs that "
                             "recorded the same images")
    first = next(iter(wins.values()))
    notes = check_same_case(run_dirs, [(float(x[1][0]), float(x[1][-1])) for x in first], cfgs)
    static = cfgs[0].probes.mri_static_height or STATIC_HEIGHT
    figures, frames = {}, {}
    for (src, label) in ((s, lab) for s, lab in SOURCES if s in wins):
        w = wins[src]
        if len({(x[0].shape[1:], x[2], x[3], x[4], None if x[5] is None else x[5].tobytes()) for x in w}) > 1:
            raise ValueError(f"the runs' /{src} images differ in shape, pixel, origin or mask: pool runs of one case")
        dt = float(np.median(np.diff(w[0][1])))
        times, t_next = [], float(w[0][1][0])
        for x in w:
            times.append(x[1] - x[1][0] + t_next)
            t_next = float(times[-1][-1]) + dt
        lengths = [x[0].shape[0] for x in w]
        segments = np.cumsum([0] + lengths[:-1])
        res = analyse(np.concatenate([x[0] for x in w]), np.concatenate(times), w[0][2], w[0][3], w[0][5], static,
                      axis=cfgs[0].vessel.center[0] - w[0][4][0], segments=segments)
        figs = write(res, out_dir / "analysis" / src, f"{len(run_dirs)} runs pooled: {label}")
        figures.update({f"{src}_{k}": v for k, v in figs.items()})
        frames[src] = lengths
    (out_dir / "analysis" / "mri.json").write_text(json.dumps(figures, indent=2) + "\n")
    (out_dir / "pooled.json").write_text(json.dumps(dict(runs=[str(d) for d in run_dirs], frames=frames,
                                                         session_differences=notes, figures=figures), indent=2) + "\n")
    return figures

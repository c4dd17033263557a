"""Verma et al. (2014) post-processing of a run folder: bubble size and rise velocity in
horizontal plane pairs, porosity PDFs, bubble diameter against height, pressure drop.

``analyze(run_dir)`` reads ``run_dir/run.h5`` and ``run_dir/summary.json`` and writes, into
``run_dir/analysis`` by default, ``table.csv``, ``table.md`` and four figures
(``diameter_vs_height.png``, ``porosity_pdf.png``, ``pressure_drop.png``, ``bubbles_3d.png``).

Run file layout (names are the module constants below):

- ``/planes/<name>/time`` (nt,) [s] and ``/planes/<name>/porosity`` (nt, nx, ny); group attrs
  ``z`` [m] (plane height above the distributor), ``h`` [m] (cell size), ``origin`` (x0, y0) [m]
  (corner of cell (0, 0)), ``pair`` (str, e.g. "5cm"), ``level`` ("lower" / "upper").
- ``/planes/mask`` (nx, ny) uint8, optional: 1 inside the vessel.
- ``/porosity3d/time`` (nt,), ``/porosity3d/porosity`` (nt, nx, ny, nz); attrs ``h``, ``origin``
  (x0, y0, z0) (corner of cell (0, 0, 0)); optional ``/porosity3d/mask`` (nx, ny), else
  ``/planes/mask`` when the shapes agree.
- ``/series/time``, ``/series/pressure_drop`` [Pa].
- ``summary.json``: ``bed_weight_per_area`` [Pa].

The recipe (``postprocessing`` in the reference json): porosity > 0.7 after 4x linear sub-grid
interpolation, regions below 2 h^2 dropped, number-average of sqrt(4 A / pi); rise velocity =
pair spacing / lag of the peak of the area-weighted cross-correlation (parabolic sub-sample
peak); PDF bins of 0.04. The analysed window: at the end of a run and in `fbed analyze`, from the run's
``output.average_from`` (negative: the second half of the records), as the MRI analysis; ``analyze`` called alone
discards the first ``t_discard`` seconds (clipped to half the run). Several runs of the case (GPU sessions going on
from each other's packed states) are pooled by ``verma_pool`` through ``analyze_records``.

Because the correlation lag mixes every porosity change between the planes (bubble noses, tails,
the bed surface's rise and fall), ``rise_velocity.csv`` / ``.md`` give each pair's velocity two
other ways beside it: bubble noses and tails timed cell by cell between the planes
(``rise.edge_velocities``) and the centroids of bubbles followed through the 3-D frames
(``bubbles.track_bubbles``).
"""
from __future__ import annotations

import csv
import json
import math
import os
import pathlib

import h5py
import numpy as np

from app.analysis import bubbles as bb
from app.analysis import rise
from app.analysis import verma_figures as vfig
from app.analysis.pooling import spans

# ---- run folder layout ------------------------------------------------------------------------
RUN_FILE = "run.h5"
SUMMARY_FILE = "summary.json"
ANALYSIS_DIR = "analysis"

PLANES = "planes"                  # group of plane groups
PLANES_MASK = "mask"               # dataset /planes/mask (nx, ny) uint8, 1 = inside
TIME = "time"                      # dataset name in every group [s]
POROSITY = "porosity"              # dataset name in plane and 3-D groups
ATTR_Z = "z"                       # plane height [m]
ATTR_H = "h"                       # cell size [m]
ATTR_ORIGIN = "origin"             # corner of cell 0 [m]
ATTR_PAIR = "pair"                 # pair label, e.g. "5cm"
ATTR_LEVEL = "level"               # "lower" or "upper"
LOWER, UPPER = "lower", "upper"

POROSITY3D = "porosity3d"          # group /porosity3d
MASK3D = "mask"                    # optional /porosity3d/mask (nx, ny)

SERIES = "series"                  # group /series
PRESSURE_DROP = "pressure_drop"    # /series/pressure_drop [Pa]

BED_WEIGHT_KEY = "bed_weight_per_area"   # summary.json [Pa]

# ---- outputs ----------------------------------------------------------------------------------
TABLE_CSV = "table.csv"
TABLE_MD = "table.md"
RISE_CSV = "rise_velocity.csv"     # the rise velocity of each pair measured three ways (a check on the table's)
RISE_MD = "rise_velocity.md"
FIGURES = ("diameter_vs_height", "porosity_pdf", "pressure_drop", "bubbles_3d")

REFERENCE_NAME = "verma2014.json"
#: Table rows: (key as in the reference json's comparison_table, label, kind, height [m]).
ROWS = (
    ("De_at_H_0.05m_mm", "De at H = 0.05 m [mm]", "De", 0.05),
    ("De_at_H_0.10m_mm", "De at H = 0.10 m [mm]", "De", 0.10),
    ("rise_velocity_at_0.05m_m_s", "rise velocity at H = 0.05 m [m/s]", "ub", 0.05),
    ("rise_velocity_at_0.10m_m_s", "rise velocity at H = 0.10 m [m/s]", "ub", 0.10),
    ("mean_dP_over_bed_weight_per_area", "mean dP / (bed weight / area) [-]", "dp", None),
)
COLUMNS = ("fbed", "xray", "paper_TFM", "seed_000")
#: A region larger than this fraction of the vessel cross-section is not a bubble but the
#: freeboard (a layer above the bed surface is "bubble" everywhere): dropped.
MAX_AREA_FRACTION = 0.5
PDF_BIN = 0.04

_DEFAULT = object()


def default_reference() -> pathlib.Path | None:
    """``$FBED_REFERENCE/verma2014.json`` or ``<repo>/../shared/reference/verma2014.json``, if present."""
    env = os.environ.get("FBED_REFERENCE")
    cands = [pathlib.Path(env) / REFERENCE_NAME] if env else []
    repo = pathlib.Path(__file__).resolve().parents[2]
    cands.append(repo.parent / "shared" / "reference" / REFERENCE_NAME)
    for c in cands:
        if c.is_file():
            return c
    return None


def _str(v) -> str:
    if isinstance(v, bytes):
        return v.decode()
    if isinstance(v, np.ndarray) and v.shape == ():
        return _str(v[()])
    return str(v)


def _discard_time(times, t_discard: float) -> float:
    """Start of the analysed window: first sample + min(t_discard, half the run)."""
    ts = [np.asarray(t) for t in times if t is not None and len(t)]
    if not ts:
        return 0.0
    t0 = min(float(t[0]) for t in ts)
    t1 = max(float(t[-1]) for t in ts)
    return t0 + min(float(t_discard), 0.5 * (t1 - t0))


def _read_run(path: pathlib.Path, t_discard: float, t_from: float | None = None):
    """Read the run file; porosity arrays are cut at the window's start: ``t_from`` [s] where given (negative: the
    middle of the records), else the discard time."""
    with h5py.File(path, "r") as f:
        planes_raw, mask = {}, None
        if PLANES in f:
            g = f[PLANES]
            if PLANES_MASK in g and isinstance(g[PLANES_MASK], h5py.Dataset):
                mask = np.asarray(g[PLANES_MASK][()]).astype(bool)
            for name, grp in g.items():
                if isinstance(grp, h5py.Group) and POROSITY in grp and TIME in grp:
                    planes_raw[name] = grp
        p3 = f[POROSITY3D] if POROSITY3D in f and POROSITY in f[POROSITY3D] else None
        series_t = np.asarray(f[SERIES][TIME][()], float) if SERIES in f and TIME in f[SERIES] else None
        dp = (np.asarray(f[SERIES][PRESSURE_DROP][()], float)
              if series_t is not None and PRESSURE_DROP in f[SERIES] else None)

        times = [np.asarray(grp[TIME][()], float) for grp in planes_raw.values()]
        if p3 is not None:
            times.append(np.asarray(p3[TIME][()], float))
        times.append(series_t)
        if t_from is None or t_from < 0:  # the discard time, or the middle of the records
            t_cut = _discard_time(times, t_discard if t_from is None else math.inf)
        else:
            t_cut = float(t_from)
            last = max((float(t[-1]) for t in times if t is not None and len(t)), default=-math.inf)
            if t_cut > last:
                raise ValueError(f"the records end at t = {last:.6g} s, before output.average_from = {t_cut:g} s: "
                                 "lower output.average_from or run longer")

        planes = {}
        for name, grp in planes_raw.items():
            t = np.asarray(grp[TIME][()], float)
            keep = np.nonzero(t >= t_cut)[0]
            i0 = int(keep[0]) if keep.size else len(t)
            a = grp.attrs
            planes[name] = {
                "time": t[i0:],
                "porosity": np.asarray(grp[POROSITY][i0:], dtype=np.float32),
                "z": float(a[ATTR_Z]),
                "h": float(a[ATTR_H]),
                "origin": tuple(float(v) for v in np.atleast_1d(a.get(ATTR_ORIGIN, (0.0, 0.0)))),
                "pair": _str(a.get(ATTR_PAIR, name)),
                "level": _str(a.get(ATTR_LEVEL, "")),
            }
        vol = None
        if p3 is not None:
            t = np.asarray(p3[TIME][()], float)
            keep = np.nonzero(t >= t_cut)[0]
            i0 = int(keep[0]) if keep.size else len(t)
            m3 = np.asarray(p3[MASK3D][()]).astype(bool) if MASK3D in p3 else None
            vol = {"time": t[i0:], "porosity": np.asarray(p3[POROSITY][i0:], dtype=np.float32),
                   "h": float(p3.attrs[ATTR_H]),
                   "origin": tuple(float(v) for v in np.atleast_1d(p3.attrs.get(ATTR_ORIGIN, (0.0, 0.0, 0.0)))),
                   "mask": m3}
            # the last full frame, for the 3-D picture, even if the window is empty
            vol["last"] = np.asarray(p3[POROSITY][-1], dtype=np.float32) if len(t) else None
            vol["last_time"] = float(t[-1]) if len(t) else float("nan")
    return {"planes": planes, "mask": mask, "vol": vol, "series_t": series_t, "dp": dp, "t_cut": t_cut}


def _max_area(mask, shape, h):
    inside = int(mask.sum()) if mask is not None else int(np.prod(shape))
    return MAX_AREA_FRACTION * inside * h * h


def _mask_for(mask, shape):
    return mask if mask is not None and mask.shape == tuple(shape) else None


def _reference_columns(ref: dict | None) -> dict:
    """{row key: {column: value}} from the reference json's comparison table."""
    out = {key: {} for key, *_ in ROWS}
    if not ref:
        return out
    tab = ref.get("comparison_table", {})
    cols = tab.get("columns", [])
    for key, *_ in ROWS:
        vals = tab.get(key)
        if vals is None:
            continue
        for name, v in zip(cols, vals):
            col = next((c for c in COLUMNS[1:] if name == c or name.startswith(c)), None)
            if col is not None:
                out[key][col] = float("nan") if v is None else float(v)
    return out


def _nearest(items, H, tol):
    """Item whose 'z' is nearest H, within tol; None if none."""
    best = min(items, key=lambda it: abs(it["z"] - H), default=None)
    return best if best is not None and abs(best["z"] - H) <= tol else None


def analyze(run_dir, out_dir=None, reference=_DEFAULT, t_discard: float = 1.0,
            threshold: float = bb.THRESHOLD, factor: int = bb.FACTOR, t_from: float | None = None) -> dict:
    """Verma et al. (2014) analysis of a run folder; see the module docstring.

    Parameters
    ----------
    run_dir : folder with ``run.h5`` and ``summary.json``.
    out_dir : where to write the table and figures; default ``run_dir/analysis``.
    reference : path of ``verma2014.json``; default ``default_reference()``; None for no
        reference (the table then has only the fbed column and the figures no measured data).
    t_discard : start time discarded [s] (clipped to half the run when the run is shorter).
    t_from : the analysed window's start [s] instead (negative: the middle of the records), e.g. the run's
        output.average_from (``summarize``).

    Returns
    -------
    dict with ``table`` ({row key: {column: value}}), ``figures`` ({name: path of the PNG}),
    ``planes`` (per plane: z, De [m], count), ``pairs`` (per pair: z, spacing, velocity, lag),
    ``profile`` (z, De, count arrays, or None), ``dp_over_weight``, ``t_cut``, ``out_dir``.
    """
    run_dir = pathlib.Path(run_dir)
    out = pathlib.Path(out_dir) if out_dir is not None else run_dir / ANALYSIS_DIR
    weight = float(json.loads((run_dir / SUMMARY_FILE).read_text())[BED_WEIGHT_KEY])
    return analyze_records(_read_run(run_dir / RUN_FILE, t_discard, t_from), weight, out, reference, threshold, factor)


def analyze_records(run: dict, weight: float, out: pathlib.Path, reference=_DEFAULT,
                    threshold: float = bb.THRESHOLD, factor: int = bb.FACTOR) -> dict:
    """``analyze`` on records read (``_read_run``'s dict; with ``segments``, {"planes": [...], "vol": [...]}: the first
    frames of the runs a pooled record holds, ``verma_pool``), the bed's weight per area ``weight`` [Pa]."""
    out.mkdir(parents=True, exist_ok=True)
    if reference is _DEFAULT:
        reference = default_reference()
    ref = json.loads(pathlib.Path(reference).read_text()) if reference is not None else None
    if not run["planes"] and run["vol"] is None:  # a table of dashes beside the X-ray's, said to be "written"
        raise ValueError("run.h5 holds neither /planes nor /porosity3d: the bubble statistics need "
                         "probes.planes with probes.planes_interval, or probes.volume_interval")
    t_cut = run["t_cut"]
    planes = _plane_bubbles(run, threshold, factor)
    pairs = _pair_velocities(run, threshold)
    profile, tracks = _volume_bubbles(run, threshold, factor)
    _add_tracked(pairs, tracks)
    _write_rise_tables(out, pairs)
    dp_w = _dp_over_weight(run, weight, t_cut)
    table = _fill_table(_reference_columns(ref), planes, pairs, profile, run["vol"], dp_w)
    columns = COLUMNS if ref is not None else COLUMNS[:1]
    _write_tables(out, table, columns)

    figures = {
        "diameter_vs_height": vfig.diameter(out, planes, profile, ref),
        "porosity_pdf": vfig.pdf(out, planes, ref, PDF_BIN),
        "pressure_drop": vfig.pressure(out, run["series_t"], run["dp"], weight, t_cut, dp_w),
        "bubbles_3d": vfig.bubbles_3d(out, run, threshold, _mask_for, MAX_AREA_FRACTION),
    }
    for p in planes.values():
        p.pop("values")
    return {"table": table, "figures": figures, "planes": planes, "pairs": pairs, "profile": profile,
            "tracks": tracks, "dp_over_weight": dp_w, "t_cut": t_cut, "out_dir": out}


def _plane_bubbles(run: dict, threshold: float, factor: int) -> dict:
    """Per plane (bottom to top): bubble size and porosity values."""
    planes = {}
    for name, p in sorted(run["planes"].items(), key=lambda kv: kv[1]["z"]):
        eps = p["porosity"]
        m = _mask_for(run["mask"], eps.shape[1:])
        De, n = bb.equivalent_diameter(eps, p["h"], threshold, factor, mask=m,
                                       max_area=_max_area(m, eps.shape[1:], p["h"]))
        vals = eps[:, m] if m is not None else eps.reshape(len(eps), -1)
        planes[name] = {"z": p["z"], "h": p["h"], "pair": p["pair"], "level": p["level"],
                        "De": De, "count": n, "values": vals.ravel()}
    return planes


def _pair_velocities(run: dict, threshold: float) -> dict:
    """Per plane pair: the rise velocity by cross-correlation, and bubble noses and tails timed cell by cell
    between the planes (a check on the correlation)."""
    pairs = {}
    by_pair = {}
    for name, p in run["planes"].items():
        by_pair.setdefault(p["pair"], {})[p["level"]] = p
    for label, d in by_pair.items():
        if LOWER not in d or UPPER not in d:
            continue
        lo, up = d[LOWER], d[UPPER]
        nt = min(len(lo["time"]), len(up["time"]))
        spacing = up["z"] - lo["z"]
        v = lag = float("nan")
        edges = dict.fromkeys(("nose", "tail"), {"velocity": float("nan"), "count": 0})
        if nt >= 4:
            dt = float(np.median(np.diff(lo["time"][:nt])))
            m = _mask_for(run["mask"], lo["porosity"].shape[1:])
            seg = run.get("segments", {}).get("planes")
            v, lag = rise.rise_velocity(lo["porosity"][:nt], up["porosity"][:nt], dt, spacing, mask=m, segments=seg)
            edges = rise.edge_velocities(lo["porosity"][:nt], up["porosity"][:nt], dt, spacing, threshold, mask=m,
                                         segments=seg)
        pairs[label] = {"z": lo["z"], "spacing": spacing, "velocity": v, "lag": lag, **edges}
    return pairs


def _volume_bubbles(run: dict, threshold: float, factor: int):
    """(diameter profile, tracks) from the 3-D frames: the diameter per layer, and bubbles followed from frame
    to frame; (None, None) without 3-D frames."""
    profile = tracks = None
    vol = run["vol"]
    if vol is not None and len(vol["porosity"]):
        eps = vol["porosity"]
        h3 = vol["h"]
        m3 = vol["mask"] if vol["mask"] is not None else _mask_for(run["mask"], eps.shape[1:3])
        z0 = vol["origin"][2] if len(vol["origin"]) > 2 else 0.0
        zc = z0 + (np.arange(eps.shape[3]) + 0.5) * h3
        z, De, cnt = bb.diameter_profile(eps, h3, zc, threshold, factor, mask=m3,
                                         max_area=_max_area(m3, eps.shape[1:3], h3))
        profile = {"z": z, "De": De, "count": cnt}
        parts = [bb.track_bubbles(eps[a:e], vol["time"][a:e], h3, threshold, mask=m3)
                 for a, e in spans(len(eps), run.get("segments", {}).get("vol")) if e - a >= 2]
        if parts:  # each run's frames alone: no bubble is followed from one run into the next
            tracks = {k: np.concatenate([t[k] for t in parts]) for k in parts[0]}
            tracks["z"] = tracks["z"] + z0
    return profile, tracks


def _add_tracked(pairs: dict, tracks) -> None:
    """Each pair's 'tracked' velocity: the centroids of bubbles followed through the 3-D frames within half a
    spacing of the pair."""
    for pr in pairs.values():
        pr["tracked"] = {"velocity": float("nan"), "median": float("nan"), "count": 0}
        if tracks is not None:
            z_lo, z_up = pr["z"], pr["z"] + pr["spacing"]
            band = (tracks["z"] >= z_lo - 0.5 * pr["spacing"]) & (tracks["z"] < z_up + 0.5 * pr["spacing"])
            if band.any():
                v = tracks["velocity"][band]
                pr["tracked"] = {"velocity": float(v.mean()), "median": float(np.median(v)), "count": int(band.sum())}


def _dp_over_weight(run: dict, weight: float, t_cut: float) -> float:
    """Mean pressure drop after t_cut over the bed's weight per area (nan without the series)."""
    if run["dp"] is not None and run["series_t"] is not None:
        sel = run["series_t"] >= t_cut
        if sel.any():
            return float(np.mean(run["dp"][sel]) / weight)
    return float("nan")


def _fill_table(table: dict, planes: dict, pairs: dict, profile, vol, dp_w: float) -> dict:
    """The fbed column of each row: the diameter at the lower plane nearest H (else the 3-D profile's layer),
    the pair's rise velocity, the pressure drop over the weight."""
    plane_list = list(planes.values())
    pair_list = list(pairs.values())
    for key, _label, kind, H in ROWS:
        val = float("nan")
        if kind == "De":
            lower_planes = [p for p in plane_list if p["level"] == LOWER] or plane_list
            p = _nearest(lower_planes, H, tol=max((q["h"] for q in plane_list), default=0.0))
            if p is not None:
                val = 1e3 * p["De"]
            elif profile is not None:
                k = int(np.argmin(np.abs(profile["z"] - H)))
                if abs(profile["z"][k] - H) <= vol["h"]:
                    val = 1e3 * profile["De"][k]
        elif kind == "ub":
            p = _nearest(pair_list, H, tol=max((q["h"] for q in plane_list), default=0.0))
            if p is not None:
                val = p["velocity"]
        else:
            val = dp_w
        table[key] = {"fbed": val, **table[key]}
    return table


# ---- output helpers ---------------------------------------------------------------------------
def _fmt(v) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return ""
    return f"{v:.4g}"


def _write_tables(out: pathlib.Path, table: dict, columns) -> None:
    with open(out / TABLE_CSV, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["quantity", *columns])
        for key, *_ in ROWS:
            w.writerow([key, *(_fmt(table[key].get(c)) for c in columns)])
    lines = ["| quantity | " + " | ".join(columns) + " |",
             "|---|" + "---|" * len(columns)]
    for key, label, *_ in ROWS:
        lines.append(f"| {label} | " + " | ".join(_fmt(table[key].get(c)) or "-" for c in columns) + " |")
    (out / TABLE_MD).write_text("\n".join(lines) + "\n")


def _write_rise_tables(out: pathlib.Path, pairs: dict) -> None:
    """rise_velocity.csv / .md: per plane pair, the paper's correlation velocity beside the nose and
    tail times of flight and the 3-D centroid velocity, with the number of events behind each."""
    cols = (("correlation", "correlation (the paper's)"), ("nose", "noses, time of flight"),
            ("tail", "tails, time of flight"), ("tracked", "3-D centroids"))
    with open(out / RISE_CSV, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["pair", "z_lower_m", *(f"{c}_m_s" for c, _ in cols), *(f"{c}_count" for c, _ in cols[1:])])
        for label, p in sorted(pairs.items(), key=lambda kv: kv[1]["z"]):
            vals = [p["velocity"]] + [p.get(c, {}).get("velocity", float("nan")) for c, _ in cols[1:]]
            w.writerow([label, _fmt(p["z"]), *(_fmt(v) for v in vals),
                        *(p.get(c, {}).get("count", 0) for c, _ in cols[1:])])
    lines = ["| pair | " + " | ".join(f"{lab} [m/s]" for _, lab in cols) + " |", "|---|" + "---|" * len(cols)]
    for label, p in sorted(pairs.items(), key=lambda kv: kv[1]["z"]):
        cells = [_fmt(p["velocity"]) or "-"]
        for c, _ in cols[1:]:
            q = p.get(c, {})
            cells.append(f"{_fmt(q.get('velocity', float('nan'))) or '-'} (n = {q.get('count', 0)})")
        lines.append(f"| {label} (z = {p['z']:.3f} m) | " + " | ".join(cells) + " |")
    (out / RISE_MD).write_text("\n".join(lines) + "\n")


def main(argv=None) -> int:
    import argparse

    ap = argparse.ArgumentParser(description="Verma et al. (2014) analysis of an fbed run folder")
    ap.add_argument("run_dir")
    ap.add_argument("--out", default=None)
    ap.add_argument("--t-discard", type=float, default=1.0)
    ap.add_argument("--reference", default=None, help="path of verma2014.json (default: shared/reference)")
    a = ap.parse_args(argv)
    res = analyze(a.run_dir, a.out, reference=a.reference if a.reference else _DEFAULT, t_discard=a.t_discard)
    print((res["out_dir"] / TABLE_MD).read_text())
    return 0


def summarize(run_dir) -> dict:
    """Run ``analyze`` on a finished run (files in run_dir/analysis) and return the fbed column as
    flat summary.json figures: verma_<row key> (SI; the diameters in m), and ``verma_analysed_from`` [s]: the window
    starts at the run's output.average_from (a session going on from a carried state analyses from 0.02 s; the
    first 1 s was discarded whatever the preset said, before 2026-12-07)."""
    from .. import config as cfgmod

    run_dir = pathlib.Path(run_dir)
    t_from = cfgmod.load(run_dir / "config.toml").output.average_from if (run_dir / "config.toml").exists() else None
    res = analyze(run_dir, t_from=t_from)
    return {"verma_analysed_from": float(res["t_cut"])} | summary_figures(res)


def summary_figures(res: dict) -> dict:
    """The fbed column of an analysis (``analyze_records``' result) as flat summary.json figures."""
    out = {}
    for key, _, kind, _ in ROWS:
        v = res["table"].get(key, {}).get("fbed")
        if v is None or (isinstance(v, float) and not np.isfinite(v)):
            continue
        name = key.replace("_mm", "_m") if kind == "De" else key
        out["verma_" + name] = float(v) * (1e-3 if kind == "De" else 1.0)
    for p in res["pairs"].values():
        for kind in ("nose", "tail", "tracked"):
            v = p.get(kind, {}).get("velocity", float("nan"))
            if np.isfinite(v):
                out[f"verma_{kind}_rise_velocity_at_{p['z']:.2f}m_m_s"] = float(v)
    return out


if __name__ == "__main__":
    raise SystemExit(main())

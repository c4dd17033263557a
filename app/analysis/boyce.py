"""The single-bubble measurements of Boyce et al. (2019), from a run's central-slab records.

Owns: tracking the injected bubble on the central vertical slab (run.h5 ``/slab``, written by
``app.probes``) and the figures Boyce's MRI and the MFIX-Exa benchmark report: the bubble's
equivalent diameter against time, its peak and when it happens, the detachment and eruption
times, the aspect ratio, the rise velocity. Plain numpy/scipy/matplotlib, no Taichi.

On each slab frame (eps, shape (nx, nz)), the bubble phase is eps > 0.7 after 4x linear
refinement (``bubbles.bubble_phase``). Regions that touch the top of the domain are the
freeboard, not bubbles; of the rest, the largest region of at least ``MIN_AREA_CELLS`` cells is
the bubble. Its equivalent diameter is sqrt(4A/pi), A the area in the slab plane (the MRI
measure); its aspect ratio is height over width.

Events (times are from the jet's opening):
- detachment: the first frame after the jet closes in which the bubble's bottom has left the
  distributor (lies more than ``DETACH_CELLS`` cells above the floor);
- eruption: the first frame after detachment in which no bubble is found, when its top had
  reached the bed surface (within ``ERUPT_CELLS`` cells: it merged with the freeboard); when it
  vanished lower in the bed, that time is reported as a collapse instead;
- peak: the largest diameter between the jet's opening and the eruption.
"""
from __future__ import annotations

import csv
import json
import math
import pathlib

import h5py
import numpy as np
from scipy import ndimage

from . import bubbles as bb

MIN_AREA_CELLS = 4.0      # smallest bubble [cells]: below it, packing noise of the deposit
DETACH_CELLS = 1.5        # bottom this far above the floor [cells]: off the distributor
ERUPT_CELLS = 2.0         # top this close to the bed surface [cells] when last seen: it erupted
BAND = (0.040, 0.100)     # Boyce's measured bubble diameters over the injection times [m]


def bed_surface(labels: np.ndarray, top_labels, dx: float) -> float:
    """Height of the bed surface [m from the plane's origin]: the median over the central half of
    the columns of the lowest freeboard sub-cell (the freeboard is the region touching the top)."""
    free = np.isin(labels, list(top_labels)) if top_labels else np.zeros(labels.shape, bool)
    nx = labels.shape[0]
    lows = []
    for i in range(nx // 4, nx - nx // 4):
        col = np.nonzero(free[i])[0]
        if col.size:
            # the freeboard's lowest point in this column that connects to the top through it
            run = col[::-1]
            k = 0
            while k + 1 < run.size and run[k + 1] == run[k] - 1:
                k += 1
            lows.append(run[k])
    return float(np.median(lows) * dx) if lows else float("nan")


def measure(eps2d: np.ndarray, h: float, mask=None, threshold: float = bb.THRESHOLD,
            factor: int = bb.FACTOR) -> tuple[dict | None, float]:
    """(the bubble or None, the bed surface height) in one slab frame (m from the origin corner)."""
    fine = bb.bubble_phase(eps2d, threshold, factor, mask)
    labels, n = ndimage.label(fine)
    dx = h / factor
    top = set(np.unique(labels[:, -1])) - {0}
    surface = bed_surface(labels, top, dx)
    if n == 0:
        return None, surface
    sizes = ndimage.sum(np.ones_like(labels), labels, index=np.arange(1, n + 1))
    for lab in top:
        sizes[lab - 1] = 0
    k = int(np.argmax(sizes))
    if sizes[k] * dx * dx < MIN_AREA_CELLS * h * h:
        return None, surface
    sl = ndimage.find_objects(labels, max_label=k + 1)[k]
    ii, jj = np.nonzero(labels[sl] == k + 1)
    ii, jj = ii + sl[0].start, jj + sl[1].start
    area = float(sizes[k] * dx * dx)
    width = (sl[0].stop - sl[0].start) * dx
    height = (sl[1].stop - sl[1].start) * dx
    return {"area": area, "diameter": math.sqrt(4 * area / math.pi),
            "x": float((ii.mean() + 0.5) * dx), "z": float((jj.mean() + 0.5) * dx),
            "bottom": float(sl[1].start * dx), "top": float(sl[1].stop * dx),
            "width": float(width), "height": float(height), "aspect": float(height / width)}, surface


def track(slab: np.ndarray, times: np.ndarray, h: float, origin, mask=None) -> list[dict]:
    """The bubble in every frame: dicts with time [s], the bed surface and the ``measure`` figures in
    domain coordinates."""
    rows = []
    for t, frame in zip(times, slab):
        b, surface = measure(frame, h, mask)
        row = {"time": float(t), "surface": surface + origin[1]}
        if b is not None:
            b["x"] += origin[0]
            b["z"] += origin[1]
            b["bottom"] += origin[1]
            b["top"] += origin[1]
            row.update(b)
        rows.append(row)
    return rows


def events(rows: list[dict], jet_start: float, jet_duration: float, floor: float, h: float) -> dict:
    """Peak, detachment, eruption and rise velocity from a track (times from the jet's opening)."""
    t = np.array([r["time"] for r in rows])
    found = np.array(["diameter" in r for r in rows])
    d = np.array([r.get("diameter", 0.0) for r in rows])
    out = {"bubble_frames": int(found.sum())}
    after_jet = t >= jet_start + jet_duration - 1e-9
    detach = None
    for k in np.nonzero(after_jet & found)[0]:
        if rows[k]["bottom"] - floor > DETACH_CELLS * h:
            detach = int(k)
            break
    erupt = None
    if detach is not None:
        gone = np.nonzero(~found & (np.arange(len(t)) > detach))[0]
        erupt = int(gone[0]) if gone.size else None
        out["bubble_detach_time"] = float(t[detach] - jet_start)
        if erupt is not None:
            # it erupted if its top had reached the bed surface (within ERUPT_CELLS) when last seen;
            # otherwise it shrank away inside the bed (gas lost to the emulsion): a collapse
            last = rows[erupt - 1]
            near = last["top"] >= rows[erupt - 1]["surface"] - ERUPT_CELLS * h
            key = "bubble_eruption_time" if near else "bubble_collapse_time"
            out[key] = float(t[erupt] - jet_start)
            out["bubble_last_top_below_surface"] = float(last["surface"] - last["top"])
    window = (t >= jet_start - 1e-9) & found
    if erupt is not None:
        window &= np.arange(len(t)) < erupt
    if window.any():
        k = int(np.argmax(np.where(window, d, -1.0)))
        out.update(bubble_peak_diameter=float(d[k]), bubble_peak_time=float(t[k] - jet_start),
                   bubble_aspect_at_peak=float(rows[k]["aspect"]), bubble_peak_height=float(rows[k]["z"]))
    if detach is not None:
        end = erupt if erupt is not None else len(t)
        sel = [k for k in range(detach, end) if found[k]]
        if len(sel) >= 3:
            z = np.array([rows[k]["z"] for k in sel])
            out["bubble_rise_velocity"] = float(np.polyfit(t[sel], z, 1)[0])
    return out


def read_slab(run_dir: pathlib.Path):
    with h5py.File(pathlib.Path(run_dir) / "run.h5", "r") as f:
        if "slab" not in f:
            raise ValueError("run.h5 holds no /slab records: set probes.slab_interval in the preset")
        g = f["slab"]
        return (g["porosity"][...].astype(float), g["time"][...], float(g.attrs["h"]), tuple(g.attrs["origin"]),
                g.attrs["mask"].astype(bool) if "mask" in g.attrs else None)


def jet_of(cfg) -> tuple[float, float]:
    """(jet_start, jet_duration) [s] of the first inlet with a jet."""
    for _, b in cfg.boundary:
        if any(b.jet_velocity):
            return b.jet_start, b.jet_duration
    raise ValueError("the preset has no jet (boundary.<face>.jet_velocity)")


def summarize(run_dir) -> dict:
    """Measure the bubble of a finished run; write analysis/bubble.csv, bubble.json and
    bubble_diameter.png; return the key figures (SI) for summary.json."""
    from .. import config as cfgmod

    run_dir = pathlib.Path(run_dir)
    cfg = cfgmod.load(run_dir / "config.toml")
    jet_start, jet_duration = jet_of(cfg)
    slab, times, h, origin, mask = read_slab(run_dir)
    rows = track(slab, times, h, origin, mask)
    floor = cfg.vessel.floor if cfg.vessel.floor is not None else cfg.domain.lo[2]
    figures = events(rows, jet_start, jet_duration, floor, h)
    out = run_dir / "analysis"
    out.mkdir(exist_ok=True)
    keys = ["time", "diameter", "area", "x", "z", "bottom", "top", "width", "height", "aspect", "surface"]
    with open(out / "bubble.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow([f"{k} [{'s' if k == 'time' else 'm^2' if k == 'area' else '-' if k == 'aspect' else 'm'}]"
                    for k in keys])
        for r in rows:
            w.writerow([f"{r[k]:.6g}" if k in r else "" for k in keys])
    (out / "bubble.json").write_text(json.dumps({**figures, "jet_start": jet_start, "jet_duration": jet_duration,
                                                 "units": "s, m, m/s"}, indent=2) + "\n")
    plot(rows, jet_start, jet_duration, figures, out / "bubble_diameter.png", cfg.run.name or run_dir.name)
    return figures


def plot(rows, jet_start, jet_duration, figures, path, title="") -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = np.array([r["time"] for r in rows]) - jet_start
    d = np.array([r.get("diameter", np.nan) for r in rows])
    z = np.array([r.get("z", np.nan) for r in rows])
    fig, (ax, az) = plt.subplots(1, 2, figsize=(10, 4))
    ax.axvspan(0, 1e3 * jet_duration, color="0.9", label="jet on")
    ax.axhspan(1e3 * BAND[0], 1e3 * BAND[1], color="tab:green", alpha=0.12, label="Boyce et al. MRI range")
    ax.plot(1e3 * t, 1e3 * d, "k.-", label="fbed (central slab)")
    for key, style in (("bubble_detach_time", "b--"), ("bubble_eruption_time", "r--"),
                       ("bubble_collapse_time", "m--")):
        if key in figures:
            ax.axvline(1e3 * figures[key], color=style[0], ls="--", label=key.split("_")[1])
    ax.set(xlabel="time since the jet opened [ms]", ylabel="bubble equivalent diameter [mm]", title=title)
    ax.set_xlim(left=min(0.0, 1e3 * t.min()))
    ax.legend(fontsize=8)
    az.plot(1e3 * t, 1e3 * z, "k.-")
    az.set(xlabel="time since the jet opened [ms]", ylabel="bubble centroid height [mm]")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)

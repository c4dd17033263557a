"""The four figures of the Verma et al. (2014) analysis (``app.analysis.verma``): diameter against height,
porosity PDFs, pressure drop, the bubbles of the last 3-D frame. Matplotlib's object API (no pyplot: no GUI
backend, no global state); each function writes ``<name>.png`` into ``out`` and returns its path."""
from __future__ import annotations

import math
import pathlib

import numpy as np

from app.analysis import bubbles as bb


def _new_figure(figsize=(6.0, 4.5), **kw):
    from matplotlib.figure import Figure  # no pyplot: no GUI backend, no global state

    fig = Figure(figsize=figsize)
    return fig, fig.add_subplot(**kw)


def _save(fig, out: pathlib.Path, name: str) -> pathlib.Path:
    path = out / f"{name}.png"
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    return path


def diameter(out, planes, profile, ref):
    fig, ax = _new_figure()
    hmax = 0.2
    if profile is not None:
        ok = profile["count"] > 0
        ax.plot(profile["z"][ok], 1e3 * profile["De"][ok], "-", color="C0", label="fbed (3-D layers)")
        if ok.any():
            hmax = max(hmax, float(profile["z"][ok].max()))
    pz = [p["z"] for p in planes.values() if p["count"] > 0]
    pd = [1e3 * p["De"] for p in planes.values() if p["count"] > 0]
    if pz:
        ax.plot(pz, pd, "o", color="C0", mfc="none", label="fbed (planes)")
    if ref is not None:
        x = ref.get("xray_bubble_diameter_vs_height")
        if x:
            ax.plot(x["H_m"], 1e3 * np.asarray(x["De_m"]), "s", color="k", label="X-ray (Verma 2014)")
        t = ref.get("tfm_bubble_diameter_vs_height")
        if t:
            ax.plot(t["H_m"], 1e3 * np.asarray(t["De_m"]), "--", color="C2", label="TFM (Verma 2014)")
    H = np.linspace(0.0, hmax, 200)
    ax.plot(H, 1e3 * bb.darton(H), ":", color="C3", label="Darton")
    ax.plot(H, 1e3 * bb.werther(H), "-.", color="C4", label="Werther")
    ax.set_xlabel("height above distributor H [m]")
    ax.set_ylabel("equivalent bubble diameter De [mm]")
    ax.set_xlim(0.0, hmax)
    ax.set_ylim(bottom=0.0)
    ax.legend(fontsize=8)
    return _save(fig, out, "diameter_vs_height")


def pdf(out, planes, ref, pdf_bin):
    fig, ax = _new_figure()
    for name, p in planes.items():
        if p["values"].size:
            c, d = bb.porosity_pdf(p["values"], pdf_bin)
            ax.plot(c, d, drawstyle="steps-mid", label=f"fbed z = {p['z']:.3f} m")
    if ref is not None and "porosity_pdf_peaks" in ref:
        pk = ref["porosity_pdf_peaks"]
        for key, color, ls in (("xray_emulsion", "k", ":"), ("xray_bubble", "k", ":"),
                               ("seed_000_emulsion", "C7", "--"), ("seed_000_bubble", "C7", "--")):
            if key in pk:
                ax.axvline(pk[key], color=color, ls=ls, lw=1)
        ax.plot([], [], "k:", label="X-ray peaks")
        ax.plot([], [], "--", color="C7", label="seed 000 peaks")
    ax.set_xlabel("porosity [-]")
    ax.set_ylabel(f"probability density (bin {pdf_bin})")
    ax.set_xlim(0.0, 1.0)
    ax.legend(fontsize=8)
    return _save(fig, out, "porosity_pdf")


def pressure(out, t, dp, weight, t_cut, dp_w):
    fig, ax = _new_figure(figsize=(7.0, 3.5))
    if t is not None and dp is not None and len(t):
        ax.plot(t, dp / weight, lw=0.8, color="C0", label="fbed")
        ax.axvspan(float(t[0]), t_cut, color="0.9", label="discarded")
        if math.isfinite(dp_w):
            ax.axhline(dp_w, color="C1", label=f"mean {dp_w:.3f}")
    ax.axhline(1.0, color="k", lw=0.8, ls=":", label="bed weight / area")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("dP / (bed weight / area) [-]")
    ax.legend(fontsize=8)
    return _save(fig, out, "pressure_drop")


def bubbles_3d(out, run, threshold, mask_for, max_area_fraction):
    vol = run["vol"]
    if vol is None or vol.get("last") is None:
        # no 3-D frames: the last frame of every plane, thresholded
        fig, ax = _new_figure()
        planes = sorted(run["planes"].values(), key=lambda p: p["z"])
        if planes:
            imgs = [np.asarray(p["porosity"][-1]) > threshold if len(p["porosity"]) else
                    np.zeros(p["porosity"].shape[1:], bool) for p in planes]
            ax.imshow(np.concatenate(imgs, axis=1).T, origin="lower", cmap="Greys")
            ax.set_title("porosity > %.2f in the planes (last frame), bottom to top: left to right" % threshold,
                         fontsize=8)
        else:
            ax.text(0.5, 0.5, "no porosity data", ha="center", va="center")
        return _save(fig, out, "bubbles_3d")
    eps = vol["last"]
    h = vol["h"]
    m = vol["mask"] if vol["mask"] is not None else mask_for(run["mask"], eps.shape[:2])
    inside = np.ones(eps.shape[:2], bool) if m is None else m
    sel = (eps > threshold) & inside[:, :, None]
    # layers where most of the cross-section is above threshold are the freeboard: not shown
    frac = sel.sum(axis=(0, 1)) / max(int(inside.sum()), 1)
    sel &= (frac <= max_area_fraction)[None, None, :]
    i, j, k = np.nonzero(sel)
    if i.size > 20000:
        pick = np.random.default_rng(0).choice(i.size, 20000, replace=False)
        i, j, k = i[pick], j[pick], k[pick]
    o = list(vol["origin"]) + [0.0] * (3 - len(vol["origin"]))
    x, y, z = (o[0] + (i + 0.5) * h, o[1] + (j + 0.5) * h, o[2] + (k + 0.5) * h)
    fig, ax = _new_figure(figsize=(5.5, 6.0), projection="3d")
    ax.scatter(x, y, z, c=z, s=4, cmap="viridis", depthshade=False)
    nx, ny, nz = eps.shape
    ax.set_xlim(o[0], o[0] + nx * h)
    ax.set_ylim(o[1], o[1] + ny * h)
    ax.set_zlim(o[2], o[2] + nz * h)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_zlabel("z [m]")
    ax.set_title(f"cells with porosity > {threshold:.2f}, t = {vol['last_time']:.3f} s", fontsize=9)
    return _save(fig, out, "bubbles_3d")

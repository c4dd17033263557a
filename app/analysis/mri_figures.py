"""The figures of the MRI pipeline (``app.analysis.mri``): one analysed series (``plot``: bed height, bubble
diameters, diameter against height, radial profiles, velocity per size class, spectrum) and a sweep's cases side by
side (``compare``). Matplotlib with the Agg backend; each writes one PNG."""
from __future__ import annotations

import math
import pathlib

import numpy as np


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot(res: dict, out: pathlib.Path, title: str = "") -> None:
    """``out``/mri.png of one series analysed by ``mri.analyse``."""
    plt = _pyplot()
    fig, ax = plt.subplots(2, 3, figsize=(14, 8))
    t = res["times"]
    ax[0, 0].plot(t, 1e3 * res["height"], "k-", lw=0.8)
    ax[0, 0].axhline(1e3 * res["static_height"], color="0.5", ls="--", label="static")
    for a in res.get("segments", [0])[1:]:  # pooled runs: where the next begins (laid end to end in time)
        ax[0, 0].axvline(t[a], color="tab:red", lw=0.6, ls=":")
    pooled = len(res.get("segments", [0])) > 1
    ax[0, 0].set(xlabel="t [s], the runs end to end (red: a run begins)" if pooled else "t [s]",
                 ylabel="bed height [mm]", title=f"bed height (threshold {res['chosen']['bed_height']})")
    ax[0, 0].legend(fontsize=8)
    d = np.array([b["diameter"] for b in res["bubbles_at_diameter_threshold"]])
    if d.size:
        ax[0, 1].hist(1e3 * d, bins=20, color="tab:blue")
    ax[0, 1].set(xlabel="equivalent diameter [mm]", ylabel="bubbles",
                 title=f"bubble diameters (threshold {res['chosen']['bubble_diameter']})")
    dh = res["diameter_height"]
    if dh:
        ax[0, 2].errorbar([1e3 * r["mean"] for r in dh], [0.5e3 * (r["z_lo"] + r["z_hi"]) for r in dh],
                          xerr=[1e3 * r["std"] for r in dh], fmt="o-")
    ax[0, 2].set(xlabel="mean diameter [mm]", ylabel="height [mm]", title="diameter against height")
    x = 1e3 * res["x"]
    ax[1, 0].plot(x, res["radial_whole"], "o-", label="whole bed")
    ax[1, 0].plot(x, res["radial_static"], "s-", label="below static height")
    ax[1, 0].set(xlabel="x [mm]", ylabel="solid fraction", title="radial profile")
    ax[1, 0].legend(fontsize=8)
    vc = res["velocity_classes"]
    if vc:
        ax[1, 1].bar([f"{1e3 * r['d_lo']:.0f}-{1e3 * r['d_hi']:.0f}" for r in vc], [r["mean"] for r in vc],
                     yerr=[[r["mean"] - r.get("mean_lo_blocks", r["mean_lo"]) for r in vc],
                           [r.get("mean_hi_blocks", r["mean_hi"]) - r["mean"] for r in vc]])  # the honest interval
    ax[1, 1].set(xlabel="bubble diameter class [mm]", ylabel="rise velocity [m/s]", title="velocity per size class")
    ax[1, 2].semilogy(res["freq"][1:], res["power"][1:] + 1e-30, "k-")
    ax[1, 2].set(xlabel="f [Hz]", ylabel="power", title=f"void fraction below static height: {res['f_peak']:.3g} Hz")
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(out / "mri.png", dpi=100)
    plt.close(fig)


def compare(table: list[dict], swept: list[str], sources: list[str], path: pathlib.Path) -> None:
    """Bars of each case's key figures (rows of ``mri.compare``'s table), one bar per image source."""
    plt = _pyplot()
    labels = [" ".join(str(r[k]) for k in swept) or r["case"] for r in table]
    panels = [("bed_height_mean", "mean bed height [mm]", 1e3), ("bed_height_max", "max bed height [mm]", 1e3),
              ("bubble_diameter_mean", "mean bubble diameter [mm]", 1e3),
              ("bubble_diameter_max", "max bubble diameter [mm]", 1e3),
              ("bubble_velocity_mean", "mean bubble velocity [m/s]", 1.0), ("void_frequency", "frequency [Hz]", 1.0)]
    fig, axs = plt.subplots(2, 3, figsize=(14, 7))
    xs = np.arange(len(table))
    for ax, (k, lab, s) in zip(axs.flat, panels):
        for off, src in zip((-0.2, 0.2), sources):
            ax.bar(xs + off, [s * float(r.get(f"{src}_{k}", math.nan)) for r in table], 0.4, label=src)
        ax.set_xticks(xs, labels, rotation=20, fontsize=8)
        ax.set_ylabel(lab)
    axs[0, 0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)

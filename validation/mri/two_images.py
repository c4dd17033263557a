"""Why the synthetic MRI and the gas grid's slab give different bubble diameters on a run (README: "the two images").

    python3 validation/mri/two_images.py RUN_DIR            # e.g. a finished presets/mri_small.toml run

Prints markdown:
1. per threshold, each image's bubble count and mean equivalent diameter over the analysed window
   (output.average_from on), the pipeline's own functions (app/analysis/mri.py);
2. the settled bed's solid fraction and its pixel-to-pixel spread in both images (the last recorded frame
   before the inlet's schedule opens): the two images' solid-fraction scale and the grain-count noise;
3. from the run's last particle snapshot, both images rebuilt with one setting changed at a time (MRI pixel
   size; the grid's smoothing width, through fbed's own deposit): the emptiest value inside the bed and the
   bubbles per threshold, so the effect of the averaging scale shows by itself.
Uses the DEM and the coupler on the CPU (Taichi), hence a script, not an analysis.
"""
from __future__ import annotations

import dataclasses
import pathlib
import sys

import h5py
import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[2]))
from app import config as cfgmod  # noqa: E402
from app.analysis import mri  # noqa: E402


def replaced(cfg, **sections):
    for sec, changes in sections.items():
        cfg = dataclasses.replace(cfg, **{sec: dataclasses.replace(getattr(cfg, sec), **changes)})
    return cfg


def per_threshold(run: pathlib.Path, t0: float) -> None:
    print("| threshold | " + " | ".join(f"{s}: bubbles | {s}: mean D [mm]" for s, _ in mri.SOURCES) + " |")
    print("|---|" + "---|---|" * len(mri.SOURCES))
    rows = {thr: [] for thr in mri.THRESHOLDS}
    for src, _ in mri.SOURCES:
        void, times, dx, dz, _, mask = mri.read_images(run, src)
        keep = times >= t0 - 1e-9
        alpha = 1.0 - (np.where(mask[None], void, 1.0) if mask is not None else void)[keep]
        for thr in mri.THRESHOLDS:
            solid = alpha >= thr
            d = [b["diameter"] for s in solid
                 for b in mri.bubbles(s, dx, dz, mask, surface=mri.bed_height(s, dz, mask))]
            rows[thr] += [str(len(d)), f"{1e3 * np.mean(d):.2f}" if d else "-"]
    for thr, r in rows.items():
        print(f"| {thr:.2f} | " + " | ".join(r) + " |")


def inlet_opens(cfg) -> float:
    """Time [s] until which the bottom inlet's schedule holds zero (0 without a schedule)."""
    spec = dict(cfg.boundary).get("z-")
    t = 0.0
    for when, value in (spec.schedule if spec is not None else []):
        if value != 0.0:
            break
        t = when
    return t


def settled_noise(run: pathlib.Path, static: float, t_settled: float) -> None:
    print(f"\n| image (frame before {t_settled:g} s, gas off) | mean solid fraction | std over pixels |\n|---|---|---|")
    for src, _ in mri.SOURCES:
        void, times, dx, dz, _, mask = mri.read_images(run, src)
        a = 1.0 - void[max(0, int(np.searchsorted(times, t_settled, side="right")) - 1)]
        zc = (np.arange(a.shape[1]) + 0.5) * dz
        m = (np.ones(a.shape, bool) if mask is None else mask).copy()
        m[[0, -1], :] = False  # the wall columns
        inner = a[m & ((zc > dz) & (zc < static - dz))[None, :]]
        print(f"| {src} ({1e3 * dx:g} x {1e3 * dz:g} mm) | {inner.mean():.3f} | {inner.std():.3f} |")


def rebuilt(run: pathlib.Path, cfg) -> None:
    from app.probes import Probes
    from app.probes_mri import MriImage
    from app.scene import Scene, build_simulation
    from app.sim import runtime

    runtime.init(arch="cpu", precision="float64", threads=1)
    with h5py.File(run / "run.h5", "r") as f:
        last = max(f["particles"], key=lambda k: float(f["particles"][k]["time"][()]))
        g = f["particles"][last]
        t, p, r = float(g["time"][()]), g["position"][...].astype(float), g["radius"][...].astype(float)
    print(f"\nThe last particle snapshot (t = {t:g} s, {len(p)} grains), rebuilt:\n")
    print("| image | emptiest solid fraction in the bed | " + " | ".join(f"{x:.2f}: n / D [mm]" for x in mri.THRESHOLDS)
          + " |\n|---|---|" + "---|" * len(mri.THRESHOLDS))

    def row(name, alpha, dx, dz, mask):
        cells = []
        for thr in mri.THRESHOLDS:
            s = alpha >= thr
            bs = mri.bubbles(s, dx, dz, mask, surface=mri.bed_height(s, dz, mask))
            cells.append(f"{len(bs)} / " + (f"{1e3 * np.mean([b['diameter'] for b in bs]):.1f}" if bs else "-"))
        zc = (np.arange(alpha.shape[1]) + 0.5) * dz
        h = mri.bed_height(alpha >= 0.30, dz, mask)
        inside = mask & ((zc > dz) & (zc < h - dz))[None, :]
        print(f"| {name} | {alpha[inside].min():.3f} | " + " | ".join(cells) + " |")

    for pix in ((0.001, 0.001), (0.002, 0.004), (0.003, 0.003), (0.004, 0.008)):
        img = MriImage(replaced(cfg, probes=dict(mri_pixel=pix)))
        row(f"MRI, {1e3 * pix[0]:g} x {1e3 * pix[1]:g} mm pixels", 1.0 - img.void(p, r), img.dx, img.dz, img.mask)
    for width in (0.0, cfg.coupling.smoothing_width, 2.0 * cfg.coupling.smoothing_width):
        c = replaced(cfg, coupling=dict(smoothing_width=width))
        sim = build_simulation(Scene(c, initial={"position": p, "radius": r}))
        flow = sim.flow
        sim.coupler.deposit(1e-3)
        pr = Probes(c, flow, flow.fields.active.to_numpy())
        mask = pr.active[:, pr.y_cells, :].any(1)
        row(f"grid slab, smoothing {1e3 * width:g} mm", np.where(mask, 1.0 - pr.slab(), 0.0), pr.h, pr.h, mask)


def main() -> None:
    run = pathlib.Path(sys.argv[1])
    cfg = cfgmod.load(run / "config.toml")
    t0 = cfg.output.average_from
    print(f"# The two slab images of {run}\n\nAnalysed window from {t0:g} s.\n")
    per_threshold(run, t0)
    settled_noise(run, cfg.probes.mri_static_height or mri.STATIC_HEIGHT, inlet_opens(cfg))
    rebuilt(run, cfg)


if __name__ == "__main__":
    main()

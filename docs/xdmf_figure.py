"""docs/xdmf_fluidize.png: a run read through its run.xdmf and particles.xdmf (meshio), drawn with matplotlib.

    python3 -m app run presets/fluidize.toml --set gas.fields_interval=0.025 --out runs/fluidize-xdmf
    python3 docs/xdmf_figure.py runs/fluidize-xdmf 0.4 docs/xdmf_fluidize.png

Left: the gas fraction on the central vertical plane (the cells whose centre is nearest y = 0), closed
cells (open_volume 0) blank; right: the grains within 2.5 mm of that plane, coloured by speed.
"""
import pathlib
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import meshio  # noqa: E402
import numpy as np  # noqa: E402


def nearest_step(reader, t):
    times = [reader.read_data(k)[0] for k in range(reader.num_steps)]
    k = int(np.argmin(np.abs(np.array(times) - t)))
    return k, reader.read_data(k)


def main(run_dir, t, out):
    run_dir = pathlib.Path(run_dir)
    with meshio.xdmf.TimeSeriesReader(run_dir / "run.xdmf") as r:
        points, cells = r.read_points_cells()
        k, (tg, _, cd) = nearest_step(r, t)
    hexes = cells[0].data
    centres = points[hexes].mean(axis=1)
    eps, open_volume = cd["void_fraction"][0], cd["open_volume"][0]
    shape = eps.shape
    centres = centres.reshape(shape + (3,))
    j = int(np.argmin(np.abs(centres[0, :, 0, 1])))
    plane = np.where(open_volume[:, j, :] > 0, eps[:, j, :], np.nan)
    h = centres[1, 0, 0, 0] - centres[0, 0, 0, 0]
    x0, x1 = centres[0, 0, 0, 0] - h / 2, centres[-1, 0, 0, 0] + h / 2
    z0, z1 = centres[0, 0, 0, 2] - h / 2, centres[0, 0, -1, 2] + h / 2
    with meshio.xdmf.TimeSeriesReader(run_dir / "particles.xdmf") as r:
        r.read_points_cells()
        kp, (tp, pd, _) = nearest_step(r, t)
    # the grains' positions of that snapshot: the Geometry of its grid in particles.xdmf, read by h5py (meshio's
    # time-series reader reads the geometry of the first grid only)
    import h5py

    with h5py.File(run_dir / "run.h5", "r") as f:
        pos = f[f"particles/{kp}/position"][...]
    near = np.abs(pos[:, 1]) < 2.5e-3
    speed = np.linalg.norm(pd["velocity"], axis=1)
    zmax = min(z1, max(0.12, float(pos[:, 2].max()) * 1.2))
    fig, axes = plt.subplots(1, 2, figsize=(6.4, 6.0), sharey=True)
    im = axes[0].imshow(plane.T, origin="lower", extent=(x0, x1, z0, z1), vmin=0.35, vmax=1.0, cmap="viridis")
    axes[0].set_title(f"gas fraction, y = 0 (t = {tg:.3g} s)", fontsize=9)
    fig.colorbar(im, ax=axes[0], shrink=0.6)
    sc = axes[1].scatter(pos[near, 0], pos[near, 2], s=6, c=speed[near], cmap="magma", vmin=0, vmax=0.5)
    axes[1].set_title(f"grains |y| < 2.5 mm (t = {tp:.3g} s)", fontsize=9)
    fig.colorbar(sc, ax=axes[1], shrink=0.6, label="speed [m/s]")
    for ax in axes:
        ax.set_xlim(x0, x1)
        ax.set_ylim(0, zmax)
        ax.set_aspect("equal")
        ax.set_xlabel("x [m]")
    axes[0].set_ylabel("z [m]")
    fig.suptitle("presets/fluidize.toml read through run.xdmf / particles.xdmf (meshio)", fontsize=9)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    print(f"wrote {out}")


if __name__ == "__main__":
    main(sys.argv[1], float(sys.argv[2]), sys.argv[3])

"""Does the grid read a false wall channel? The gas fraction the coupling deposits in wall cut cells, against
the geometric gas fraction of the same cells, for a settled packing.

The bed is the accuracy bench's small bed (2,500 glass beads of 3 mm settled in a 44 mm cylinder, 7.5 mm cells:
h = 2.5 d, as Verma's 3.125 mm cells for 1 mm beads are 3.1 d). The truth per cell is a Monte-Carlo count of
points inside the grains (4 million points over the bed); the grid's value is one coupling deposit. Cells are
grouped by open volume fraction; layers 1 up to one cell below the bed surface.

    python validation/verma/wall_void_fraction.py      (about a minute on a CPU core; settles the bed if needed)
"""
import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", ".."))


def main() -> None:
    from scipy.spatial import cKDTree

    from app.bench import bed_cases as bc
    from app.config import load_text
    from app.scene import Scene, build_simulation
    from app.sim import runtime

    runtime.init("cpu", "float64", 1)
    bed_file = bc.settled_bed("small")
    settings = dict(bc.DEFAULTS, precision="float64")
    text = bc.scene_text(bc.SIZES["small"], settings, f'initial_state = "{bed_file}"', u=1.0, plane=0.02)
    cfg = load_text(text, str(bed_file.parent / "wall_check.toml"))
    scene = Scene(cfg, str(bed_file.parent / "wall_check.toml"))  # the settled bed's grains (those in the domain)
    pos, rad = scene.initial["position"], scene.initial["radius"]
    sim = build_simulation(scene)
    sim.coupler.deposit(1e-3)  # one deposit: the grid's gas fraction of the settled bed
    flow = sim.flow
    vf = flow.fields.vol_frac.to_numpy()
    eps = flow.fields.eps.to_numpy()
    active = flow.fields.active.to_numpy().astype(bool)

    h, lo, radius = cfg.gas.cell_size, np.array(cfg.domain.lo), cfg.vessel.radius
    top = float(np.percentile(pos[:, 2], 95))
    rng = np.random.default_rng(0)
    pts = rng.uniform([-radius, -radius, 0.0], [radius, radius, top], (4_000_000, 3))
    pts = pts[np.hypot(pts[:, 0], pts[:, 1]) < radius]
    inside = cKDTree(pos).query(pts)[0] < rad.max()
    flat = np.ravel_multi_index(np.floor((pts - lo) / h).astype(int).T, vf.shape)
    count = np.bincount(flat, minlength=vf.size).reshape(vf.shape)
    solid = np.bincount(flat, weights=inside, minlength=vf.size).reshape(vf.shape)
    true_eps = 1.0 - solid / np.maximum(count, 1)
    layers = np.zeros(vf.shape, bool)
    layers[:, :, 1:int(top / h) - 1] = True
    sel = layers & active & (count > 200)
    print(f"{len(pos)} grains of {2e3 * rad.max():.1f} mm, cells {1e3 * h:.1f} mm, bed top {1e3 * top:.0f} mm")
    print("| cells (open volume fraction) | number | grid eps | geometric eps | grid - geometric |")
    print("|---|---|---|---|---|")
    for name, m in (("interior (1)", vf > 0.999), ("cut, 0.75-1", (vf >= 0.75) & (vf <= 0.999)),
                    ("cut, 0.5-0.75", (vf >= 0.5) & (vf < 0.75)), ("cut, below 0.5", vf < 0.5)):
        m = m & sel
        if m.any():
            g, t = np.average(eps[m], weights=vf[m]), np.average(true_eps[m], weights=vf[m])
            print(f"| {name} | {m.sum()} | {g:.3f} | {t:.3f} | {g - t:+.3f} |")


if __name__ == "__main__":
    main()

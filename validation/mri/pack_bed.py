"""Pack a settled bed for travel: positions and radii only, compressed (a million poppy seeds: about 12 MB).

    python3 validation/mri/pack_bed.py runs/mri_prepare/bed.h5 runs/mri_bed.h5

The output is a valid particles.initial_state (fbed reads grains/position and grains/radius; velocity and
spin start at zero, as in a settled bed). The three radii compress to almost nothing, so the file is the
positions' float32 (12 B a grain) under gzip.
"""
import sys

import h5py
import numpy as np


def main(src: str, dst: str) -> int:
    with h5py.File(src) as f:
        g = f["grains"]
        keep = g["alive"][...].astype(bool) if "alive" in g else np.ones(g["radius"].shape[0], bool)
        x = g["position"][...][keep].astype(np.float32)
        r = g["radius"][...][keep].astype(np.float32)
        t = f.attrs.get("time", 0.0)
    with h5py.File(dst, "w") as f:
        f.attrs["time"] = t
        f.attrs["source"] = src
        gg = f.create_group("grains")
        gg.create_dataset("position", data=x, compression="gzip", compression_opts=6, shuffle=True)
        gg.create_dataset("radius", data=r, compression="gzip", compression_opts=6, shuffle=True)
    print(f"{len(r)} grains from {src} -> {dst}")
    return 0


if __name__ == "__main__":
    sys.exit(main(*sys.argv[1:3]))

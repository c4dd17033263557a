"""A bed file's grains, read and checked: particles.initial_state (app/scene.py) and `fbed pack` (app/pack.py).
Plain numpy and h5py (no Taichi)."""
from __future__ import annotations

import pathlib

import numpy as np

from .config import ConfigError
from .io import store


def load_bed(path: pathlib.Path, key: str = "particles.initial_state") -> dict:
    """The grains alive in an earlier run's bed.h5 or checkpoint.h5: position, velocity, radius and, with friction,
    omega. A damaged or hand-made file (arrays of other lengths, a value not finite, a radius not positive) is
    refused here, naming the first grain, not left to the guard to stop at t = 0 as unstable. ``key``: what the
    error names (the preset key, or `fbed pack`'s BED)."""
    if path.is_dir():  # (HDF5's own message was a dump of its read call's arguments)
        inside = [n for n in ("bed.h5", "checkpoint.h5") if (path / n).is_file()]
        raise ConfigError("is a folder, not a bed file", str(path), key,
                          hint=f"give {path / inside[0]}" if inside else "give the bed.h5 or checkpoint.h5 written "
                          "by an earlier fbed run")
    try:
        grains, _, _ = store.read_checkpoint(path)
        if grains is None:
            raise KeyError("no /grains group")
        out = {k: grains[k] for k in ("position", "velocity", "radius", "omega") if k in grains}
        keep = grains["alive"].astype(bool) if "alive" in grains else np.ones(len(out["position"]), bool)
    except (OSError, KeyError) as err:  # (HDF5's words for a file of another kind: "file signature not found")
        why = err.args[0] if isinstance(err, KeyError) else \
            "not an HDF5 file" if "signature not found" in str(err) else str(err)
        raise ConfigError(f"cannot read grains from it: {why}", str(path), key,
                          hint="give the bed.h5 or checkpoint.h5 written by an earlier fbed run") from None
    n = len(out["position"])
    for k, v in {**out, "alive": keep}.items():
        shape = (n,) if k in ("radius", "alive") else (n, 3)
        bad = None if v.shape == shape else f"/grains/{k} has shape {v.shape}, not {shape}"
        if bad is None:
            wrong = ~np.isfinite(v.reshape(n, -1)).all(axis=1) | ((v <= 0) if k == "radius" else False)
            if wrong.any():
                bad = (f"/grains/{k} is {'not finite' if k != 'radius' else 'not finite and positive'} for "
                       f"{int(wrong.sum())} grain(s) (the first: grain {int(np.flatnonzero(wrong)[0])})")
        if bad:
            raise ConfigError(f"cannot use the grains in it: {bad}", str(path), key,
                              hint="give the bed.h5 or checkpoint.h5 written by an earlier fbed run")
    return {k: v[keep] for k, v in out.items()}

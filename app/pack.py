"""`fbed pack BED OUT`: a bed's live grains written as a packed bed (app/io/bedpack.py), for carrying it."""
from __future__ import annotations

import pathlib
import sys

import numpy as np

from .config import ConfigError
from .io import store


def pack_command(src: str, dst: str, resolution: float) -> int:
    """`fbed pack BED OUT`: the live grains of BED (a bed.h5 or checkpoint.h5, or a packed bed) packed into OUT;
    says what was kept and what left out. Bad input is a ConfigError naming the file or flag."""
    src_p, dst_p = pathlib.Path(src), pathlib.Path(dst)
    if not (resolution > 0 and np.isfinite(resolution)):
        raise ConfigError(f"--resolution must be a positive length in m, got {resolution:g}", "", "--resolution",
                          hint="e.g. --resolution 1e-7 (0.1 um)")
    if not src_p.is_file():
        raise ConfigError("no such file" if not src_p.exists() else "not a file", str(src_p), "BED",
                          hint="give the bed.h5 or checkpoint.h5 written by an earlier fbed run")
    if dst_p.exists() and dst_p.resolve() == src_p.resolve():
        raise ConfigError("OUT is BED itself: packing would replace it", str(dst_p), "OUT", hint="name another file")
    if dst_p.is_dir():
        raise ConfigError("is a folder, not a file", str(dst_p), "OUT",
                          hint=f"name a file in it, e.g. {dst_p / 'bed.h5'}")
    if not dst_p.parent.is_dir():
        raise ConfigError("no such folder", str(dst_p.parent), "OUT", hint="make it first, or name a file in a "
                          "folder that exists")
    try:
        grains, _, meta = store.read_checkpoint(src_p)
        if grains is None or "position" not in grains or "radius" not in grains:
            raise KeyError("no /grains/position and /grains/radius")
    except (OSError, KeyError) as err:
        why = err.args[0] if isinstance(err, KeyError) else \
            "not an HDF5 file" if "signature not found" in str(err) else str(err)
        raise ConfigError(f"cannot read grains from it: {why}", str(src_p), "BED",
                          hint="give the bed.h5 or checkpoint.h5 written by an earlier fbed run") from None
    alive = grains["alive"].astype(bool) if "alive" in grains else np.ones(len(grains["radius"]), bool)
    x = np.asarray(grains["position"])[alive]
    if not np.all(np.isfinite(x)):
        raise ConfigError("a grain's position is not finite", str(src_p), "BED", hint="pack a bed from a good run")
    try:
        info = store.write_packed_bed(dst_p, x, np.asarray(grains["radius"])[alive], float(meta.get("time", 0.0)),
                                      resolution, str(src_p))
    except PermissionError as err:  # (a full disk is the CLI's exit 3, as for every writer)
        raise ConfigError(f"cannot write there ({err.strerror})", str(dst_p), "OUT",
                          hint="name a file in a folder you may write to") from None
    speed = float(np.sqrt((np.asarray(grains["velocity"])[alive] ** 2).sum(1)).max()) if "velocity" in grains \
        and alive.any() else 0.0
    n = max(int(info["grains"]), 1)
    print(f"fbed: packed {info['grains']} grains into {dst_p}: {info['bytes'] / 1e6:.2f} MB, "
          f"{info['bytes'] / n:.2f} B a grain; positions to +-{0.5 * info['resolution']:.3g} m an axis, sizes exact; "
          f"velocities (up to {speed:.3g} m/s), spins and contact history left out", file=sys.stderr)
    return 0

"""`fbed pack BED OUT`: a bed's live grains written as a packed bed (app/io/bedpack.py), for carrying it."""
from __future__ import annotations

import math
import pathlib
import sys

import h5py
import numpy as np

from .beds import load_bed
from .config import ConfigError
from .io import bedpack, store

#: the coarsest --resolution, as a fraction of the smallest grain's diameter: rounded to it, two neighbours come
#: closer by up to sqrt(3) of it (1.7% of a diameter), against 0.03% at the default 1e-7 m for 0.5 mm grains;
#: a restart from a coarser bed starts with overlaps that push the grains apart
COARSEST = 0.01


def pack_command(src: str, dst: str, resolution: float, speed_resolution: float = 0.0) -> int:
    """`fbed pack BED OUT`: the live grains of BED (a bed.h5 or checkpoint.h5, or a packed bed) packed into OUT,
    with their velocities and spins where ``speed_resolution`` [m/s] > 0; says what was kept and what left out.
    Bad input is a ConfigError naming the file or flag."""
    src_p, dst_p = pathlib.Path(src), pathlib.Path(dst)
    if not (resolution > 0 and np.isfinite(resolution)):
        raise ConfigError(f"--resolution must be a positive length in m, got {resolution:g}", "", "--resolution",
                          hint="e.g. --resolution 1e-7 (0.1 um)")
    if not (speed_resolution >= 0 and np.isfinite(speed_resolution)):
        raise ConfigError(f"--speed-resolution must be a speed in m/s, 0 or more, got {speed_resolution:g}", "",
                          "--speed-resolution", hint="e.g. --speed-resolution 1e-3 (1 mm/s), or 0 for a bed at rest")
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
    grains = load_bed(src_p, "BED")  # its live grains, checked: finite positions and velocities, positive radii
    d_min = 2.0 * float(grains["radius"].min()) if len(grains["radius"]) else math.inf
    if resolution > COARSEST * d_min:  # (--resolution 1e9 packed every grain onto one point, and said so calmly)
        raise ConfigError(f"--resolution {resolution:g} m is {resolution / d_min:.3g} of the smallest grain's "
                          f"diameter ({d_min:.3g} m): rounded to it, neighbours could overlap by up to "
                          f"{math.sqrt(3) * resolution / d_min:.2%} of it at the restart", "", "--resolution",
                          hint=f"at most {COARSEST:g} of it, {COARSEST * d_min:.2g} m (the default "
                               f"{bedpack.RESOLUTION:g} m)")
    with h5py.File(src_p, "r") as f:
        t = float(f.attrs.get("time", 0.0))
    v = grains.get("velocity")
    try:
        info = store.write_packed_bed(dst_p, grains["position"], grains["radius"], t, resolution, str(src_p),
                                      v, grains.get("omega"), speed_resolution)
    except PermissionError as err:  # (a full disk is the CLI's exit 3, as for every writer)
        raise ConfigError(f"cannot write there ({err.strerror})", str(dst_p), "OUT",
                          hint="name a file in a folder you may write to") from None
    except ValueError as err:  # a speed beyond 2^52 steps of the resolution
        raise ConfigError(str(err), str(src_p), "--speed-resolution", hint="a coarser --speed-resolution") from None
    speed = float(np.sqrt((v ** 2).sum(1)).max()) if v is not None and len(v) else 0.0
    n = max(int(info["grains"]), 1)
    moving = (f"velocities (up to {speed:.3g} m/s) and spins' surface speeds to +-{0.5 * speed_resolution:.3g} m/s "
              "a component; contact history left out" if speed_resolution > 0 else
              f"velocities (up to {speed:.3g} m/s), spins and contact history left out")
    print(f"fbed: packed {info['grains']} grains into {dst_p}: {info['bytes'] / 1e6:.2f} MB, "
          f"{info['bytes'] / n:.2f} B a grain; positions to +-{0.5 * info['resolution']:.3g} m an axis, sizes exact; "
          f"{moving}", file=sys.stderr)
    return 0

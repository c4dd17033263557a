"""Files a run writes: run.h5 (series and snapshots), checkpoints, bed.h5, summary.json.

Owns: the on-disk layout. Plain h5py/json; callers pass numpy arrays and dicts.

run.h5
  /series/<name>                1-D, one entry per series sample (``time`` in s first)
  /particles/<k>/{time,position,velocity,radius}   snapshot k (k = 0, 1, ...)
  attrs: fbed_version, preset, units (JSON: name -> unit)
checkpoint.h5 / bed.h5
  /grains/<array>               every changing DEM array (see DemSolver.state_arrays)
  attrs: time [s], step, config (the resolved TOML), fbed_version
Every write goes to a temporary file first and is renamed into place, so a crash
mid-write leaves the previous checkpoint intact.
"""
from __future__ import annotations

import json
import math
import os
import pathlib

import h5py
import numpy as np

VERSION = "0.1.0"

SERIES_UNITS = {
    "time": "s", "kinetic_energy": "J", "kinetic_energy_rotational": "J", "max_overlap": "1 (of diameter)",
    "max_speed": "m/s", "grains_alive": "1", "grains_removed": "1", "bed_height": "m", "wall_time": "s",
}


def _atomic_write(path: pathlib.Path, fill) -> None:
    tmp = path.with_name(path.name + ".tmp")
    with h5py.File(tmp, "w") as f:
        fill(f)
    os.replace(tmp, path)


def write_state(path: pathlib.Path, arrays: dict, time: float, step: int, config_text: str, extra: dict | None = None) -> None:
    """A checkpoint (or bed.h5): every array, plus time [s], step and the resolved config."""

    def fill(f):
        g = f.create_group("grains")
        for k, v in arrays.items():
            g.create_dataset(k, data=np.asarray(v))
        f.attrs.update(time=time, step=step, config=config_text, fbed_version=VERSION)
        for k, v in (extra or {}).items():
            f.attrs[k] = v

    _atomic_write(pathlib.Path(path), fill)


def read_state(path: pathlib.Path) -> tuple[dict, dict]:
    with h5py.File(path, "r") as f:
        arrays = {k: f["grains"][k][...] for k in f["grains"]}
        meta = dict(f.attrs)
    return arrays, meta


class RunFile:
    """Appends series rows and particle snapshots to run.h5, flushing after each write."""

    def __init__(self, path: pathlib.Path, preset: str, resume_time: float | None = None):
        self.path = pathlib.Path(path)
        mode = "a" if resume_time is not None and self.path.exists() else "w"
        self.f = h5py.File(self.path, mode)
        self.f.attrs.update(fbed_version=VERSION, preset=preset, units=json.dumps(SERIES_UNITS))
        self.series = self.f.require_group("series")
        self.particles = self.f.require_group("particles")
        if resume_time is not None:
            self._truncate_after(resume_time)

    def _truncate_after(self, t: float) -> None:
        """Drop what a run wrote after its last checkpoint (it will be written again)."""
        if "time" in self.series:
            times = self.series["time"][...]
            keep = int(np.searchsorted(times, t + 1e-12, side="right"))
            for name in self.series:
                self.series[name].resize((keep,))
        for k in list(self.particles):
            if float(self.particles[k]["time"][()]) > t + 1e-12:
                del self.particles[k]

    def append(self, row: dict) -> None:
        """One sample of every series in ``row``; a series first seen now is NaN for earlier samples."""
        n = self.series["time"].shape[0] if "time" in self.series else 0
        for name, value in row.items():
            if name not in self.series:
                self.series.create_dataset(name, shape=(n,), maxshape=(None,), dtype="f8", chunks=(4096,),
                                           fillvalue=math.nan)
            ds = self.series[name]
            ds.resize((n + 1,))
            ds[n] = float(value)
        self.f.flush()

    def snapshot(self, time: float, position, velocity, radius) -> int:
        k = len(self.particles)
        g = self.particles.create_group(str(k))
        g["time"] = time
        g.create_dataset("position", data=np.asarray(position, np.float32), compression="gzip", compression_opts=1)
        g.create_dataset("velocity", data=np.asarray(velocity, np.float32), compression="gzip", compression_opts=1)
        g.create_dataset("radius", data=np.asarray(radius, np.float32), compression="gzip", compression_opts=1)
        self.f.flush()
        return k

    def close(self) -> None:
        if self.f:
            self.f.close()
            self.f = None


def write_json(path: pathlib.Path, data: dict) -> None:
    tmp = pathlib.Path(str(path) + ".tmp")
    tmp.write_text(json.dumps(data, indent=2, default=float) + "\n")
    os.replace(tmp, path)


def read_series(path: pathlib.Path) -> dict:
    with h5py.File(path, "r") as f:
        return {k: f["series"][k][...] for k in f["series"]}

"""Files a run writes: run.h5 (series and snapshots), checkpoints, bed.h5, summary.json.

Owns: the on-disk layout. Plain h5py/json; callers pass numpy arrays and dicts.

run.h5
  /series/<name>                1-D, one entry per series sample (``time`` in s first)
  /particles/<k>/{time,position,velocity,radius}   snapshot k (k = 0, 1, ...)
  attrs: fbed_version, preset, units (JSON: name -> unit)
  /fields/<k>/{time,gas_velocity,pressure,void_fraction}  gas snapshot k: cell-centred
                                interstitial velocity (nx,ny,nz,3) [m/s], pressure [Pa], gas fraction [-]
checkpoint.h5 / bed.h5
  /grains/<array>               every changing DEM array (see DemSolver.state_arrays)
  /gas/<array>                  the gas solver's whole state (see FlowSolver.state_arrays)
  attrs: time [s], step, config (the resolved TOML), fbed_version
Every write goes to a temporary file first and is renamed into place, so a crash
mid-write leaves the previous checkpoint intact.
"""
from __future__ import annotations

import json
import math
import os
import pathlib
import time as wallclock

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


def write_checkpoint(path: pathlib.Path, grains: dict | None, gas: dict | None, time: float, step: int,
                     config_text: str) -> None:
    """A checkpoint (or bed.h5): every array of the grains and/or the gas, time [s], step, resolved config."""

    def fill(f):
        for group, arrays in (("grains", grains), ("gas", gas)):
            if arrays is None:
                continue
            g = f.create_group(group)
            for k, v in arrays.items():
                g.create_dataset(k, data=np.asarray(v))
        f.attrs.update(time=time, step=step, config=config_text, fbed_version=VERSION)

    _atomic_write(pathlib.Path(path), fill)


def read_checkpoint(path: pathlib.Path) -> tuple[dict | None, dict | None, dict]:
    """(grain arrays or None, gas arrays or None, attributes) of a checkpoint."""
    with h5py.File(path, "r") as f:
        grains = {k: f["grains"][k][...] for k in f["grains"]} if "grains" in f else None
        gas = {k: f["gas"][k][...] for k in f["gas"]} if "gas" in f else None
        meta = dict(f.attrs)
    return grains, gas, meta


def read_state(path: pathlib.Path) -> tuple[dict, dict]:
    """Grain arrays and attributes of a checkpoint or bed.h5."""
    grains, _, meta = read_checkpoint(path)
    return grains, meta


FRAME_GROUPS = ("slab", "planes", "porosity3d", "mri")  # groups of appendable frames (probes)


# Series rows and probe frames are held in memory and written in batches: an HDF5 resize, write and flush per
# row cost ~5 ms (measured on this CPU: 16 series), a few percent of a million-grain GPU step. What is held is
# written when SERIES_BATCH rows or FRAME_BYTES of frames are pending, FLUSH_WALL seconds have passed, before
# every checkpoint (so a resumed run finds every row up to its checkpoint) and at close.
SERIES_BATCH = 256       # rows
FRAME_BYTES = 32 << 20   # bytes of pending probe frames
FLUSH_WALL = 10.0        # s of wall time


class RunFile:
    """Appends series rows, probe frames and snapshots to run.h5 (series and frames batched, see above)."""

    def __init__(self, path: pathlib.Path, preset: str, resume_time: float | None = None):
        self.path = pathlib.Path(path)
        mode = "a" if resume_time is not None and self.path.exists() else "w"
        self.f = h5py.File(self.path, mode)
        self.f.attrs.update(fbed_version=VERSION, preset=preset, units=json.dumps(SERIES_UNITS))
        self.series = self.f.require_group("series")
        self.particles = self.f.require_group("particles")
        self._rows: list[dict] = []
        self._frames: dict[str, list] = {}
        self._frame_bytes = 0
        self._written = wallclock.perf_counter()
        if resume_time is not None:
            self._truncate_after(resume_time)

    def _truncate_after(self, t: float) -> None:
        """Drop what a run wrote after its last checkpoint (it will be written again)."""
        if "time" in self.series:
            times = self.series["time"][...]
            keep = int(np.searchsorted(times, t + 1e-12, side="right"))
            for name in self.series:
                self.series[name].resize((keep,))
        for name in FRAME_GROUPS:  # appendable frame records (probes)
            for g in self._frame_groups(name):
                times = g["time"][...]
                keep = int(np.searchsorted(times, t + 1e-12, side="right"))
                for ds in g.values():
                    if isinstance(ds, h5py.Dataset) and ds.maxshape and ds.maxshape[0] is None:
                        ds.resize((keep,) + ds.shape[1:])
        for group in (self.particles, self.f.get("fields")):
            if group is None:
                continue
            for k in list(group):
                if float(group[k]["time"][()]) > t + 1e-12:
                    del group[k]

    def append(self, row: dict) -> None:
        """One sample of every series in ``row``; a series first seen now is NaN for earlier samples."""
        self._rows.append({k: float(v) for k, v in row.items()})
        self._maybe_flush()

    def _maybe_flush(self) -> None:
        if (len(self._rows) >= SERIES_BATCH or self._frame_bytes >= FRAME_BYTES
                or wallclock.perf_counter() - self._written >= FLUSH_WALL):
            self.flush()

    def flush(self) -> None:
        """Write what is held (series rows, probe frames) and flush the file."""
        if self._rows:
            rows, self._rows = self._rows, []
            n = self.series["time"].shape[0] if "time" in self.series else 0
            names = list(dict.fromkeys([*self.series, *(k for r in rows for k in r)]))
            for name in names:
                if name not in self.series:
                    self.series.create_dataset(name, shape=(n,), maxshape=(None,), dtype="f8", chunks=(4096,),
                                               fillvalue=math.nan)
                ds = self.series[name]
                ds.resize((n + len(rows),))
                ds[n:] = np.array([r.get(name, math.nan) for r in rows])
        frames, self._frames, self._frame_bytes = self._frames, {}, 0
        for group, items in frames.items():
            self._write_frames(group, items)
        self.f.flush()
        self._written = wallclock.perf_counter()

    def snapshot(self, time: float, position, velocity, radius) -> int:
        k = len(self.particles)
        g = self.particles.create_group(str(k))
        g["time"] = time
        g.create_dataset("position", data=np.asarray(position, np.float32), compression="gzip", compression_opts=1)
        g.create_dataset("velocity", data=np.asarray(velocity, np.float32), compression="gzip", compression_opts=1)
        g.create_dataset("radius", data=np.asarray(radius, np.float32), compression="gzip", compression_opts=1)
        self.f.flush()
        return k

    def gas_fields(self, time: float, gas_velocity, pressure, void_fraction) -> int:
        fields = self.f.require_group("fields")
        k = len(fields)
        g = fields.create_group(str(k))
        g["time"] = time
        for name, arr in (("gas_velocity", gas_velocity), ("pressure", pressure), ("void_fraction", void_fraction)):
            g.create_dataset(name, data=np.asarray(arr, np.float32), compression="gzip", compression_opts=1)
        self.f.flush()
        return k

    def _frame_groups(self, name: str):
        g = self.f.get(name)
        if g is None:
            return []
        if "time" in g:
            return [g]
        return [sub for sub in g.values() if isinstance(sub, h5py.Group) and "time" in sub]

    def frame(self, group: str, time: float, data, attrs: dict | None = None, dtype="f4") -> None:
        """Append one frame (an array) to ``group``'s ``time`` and ``porosity`` datasets (created on first use,
        with ``attrs``)."""
        data = np.array(data, dtype)  # a copy: the caller's array may change before the batch is written
        self._frames.setdefault(group, []).append((time, data, attrs))
        self._frame_bytes += data.nbytes
        self._maybe_flush()

    def _write_frames(self, group: str, items: list) -> None:
        data = items[0][1]
        g = self.f.require_group(group)
        if "time" not in g:
            g.create_dataset("time", shape=(0,), maxshape=(None,), dtype="f8", chunks=(1024,))
            g.create_dataset("porosity", shape=(0,) + data.shape, maxshape=(None,) + data.shape, dtype=data.dtype,
                             chunks=(max(1, min(64, (1 << 20) // max(1, data.nbytes))),) + data.shape,
                             compression="gzip" if data.size > 4096 else None,
                             compression_opts=1 if data.size > 4096 else None)
            for k, v in (items[0][2] or {}).items():
                g.attrs[k] = v
        n, k = g["time"].shape[0], len(items)
        g["time"].resize((n + k,))
        g["time"][n:] = [t for t, _, _ in items]
        g["porosity"].resize((n + k,) + data.shape)
        g["porosity"][n:] = np.stack([d for _, d, _ in items])

    def put(self, name: str, data) -> None:
        """A fixed dataset (written once, e.g. a mask)."""
        if name in self.f:
            del self.f[name]
        self.f.create_dataset(name, data=data)

    def close(self) -> None:
        if self.f:
            self.flush()
            self.f.close()
            self.f = None


def write_json(path: pathlib.Path, data: dict) -> None:
    tmp = pathlib.Path(str(path) + ".tmp")
    tmp.write_text(json.dumps(data, indent=2, default=float) + "\n")
    os.replace(tmp, path)


def read_series(path: pathlib.Path) -> dict:
    with h5py.File(path, "r") as f:
        return {k: f["series"][k][...] for k in f["series"]}

"""A run's analysis records in one file small enough to come back from a GPU session, and the run folder again.

A device call returns at most 8 files of 16 MiB (../shared/device/README.md), and `benchmarks/device_run.sh` packs
its runs without their run.h5 (a million-grain run's is far larger). But pooling a case's sessions
(`fbed analyze RUN RUN ... --out DIR`) reads each session's image records: /mri and /slab (the MRI analysis), /planes
and /series (Verma's; its 3-D frames, 47 MB a simulated second, stay behind). So each session keeps those groups,
its config.toml and its summary.json in one HDF5 file:

    python3 benchmarks/run_records.py pack runs/mri_koch_hill $OUT/mri_records_koch_hill.h5 --groups mri slab
    python3 benchmarks/run_records.py pack runs/verma $OUT/verma_records.h5 --groups planes series --quantize
    python3 benchmarks/run_records.py unpack mri_records_koch_hill.h5 runs/koch_hill-1     # back here

Lossless by default (float32 as recorded, byte-shuffled and deflated: about 0.4 of the raw size for the MRI images).
``--quantize`` stores every porosity dataset as uint16 steps of 1/65535 (within 7.7e-6 of the recorded value; the
analyses threshold at 0.15-0.40 and 0.7), about half the lossless size: three seconds of the Verma planes are
24.6 MB raw, about 17 MB lossless and over the 16 MiB a file may be. A file over ``--max-mb`` is not kept (exit 1).
`unpack` writes DIR/run.h5 (the groups, as float32), DIR/config.toml and DIR/summary.json, a folder `fbed analyze`
reads as the run's.
"""
from __future__ import annotations

import argparse
import pathlib
import sys

import h5py
import numpy as np

STEP = 1.0 / 65535.0  # quantized porosity: value = code * STEP
TEXTS = ("config.toml", "summary.json")


def _copy(src: h5py.Group, dst: h5py.Group, quantize: bool) -> None:
    dst.attrs.update(dict(src.attrs))
    for name, obj in src.items():
        if isinstance(obj, h5py.Group):
            _copy(obj, dst.create_group(name), quantize)
            continue
        data = obj[()]
        if quantize and name == "porosity" and data.dtype.kind == "f":
            d = dst.create_dataset(name, data=np.round(np.clip(data, 0.0, 1.0) / STEP).astype(np.uint16),
                                   compression="gzip", compression_opts=9, shuffle=True)
            d.attrs["quantized_step"] = STEP
        elif np.ndim(data) >= 1 and np.size(data) > 1:
            dst.create_dataset(name, data=data, compression="gzip", compression_opts=9, shuffle=True)
        else:
            dst.create_dataset(name, data=data)
        dst[name].attrs.update(dict(obj.attrs))


def pack(run_dir: pathlib.Path, out: pathlib.Path, groups: list[str], quantize: bool = False,
         max_mb: float = 15.5) -> int:
    """Write ``groups`` of run_dir/run.h5 with the run's texts into ``out``; its size in bytes (0: not kept)."""
    with h5py.File(run_dir / "run.h5", "r") as f:
        missing = [g for g in groups if g not in f]
        if missing:
            raise SystemExit(f"run_records: {run_dir}/run.h5 has no /{missing[0]} (it has {', '.join(sorted(f))})")
        with h5py.File(out, "w") as o:
            for g in groups:
                _copy(f[g], o.create_group(g), quantize)
            for t in TEXTS:
                if (run_dir / t).exists():
                    o.attrs[t] = (run_dir / t).read_text()
    size = out.stat().st_size
    if size > max_mb * 2 ** 20:
        out.unlink()
        print(f"run_records: {out.name} would be {size / 2 ** 20:.1f} MiB, over {max_mb:g}: not kept; keep fewer "
              f"groups{'' if quantize else ' or --quantize'}", file=sys.stderr)
        return 0
    return size


def unpack(records: pathlib.Path, run_dir: pathlib.Path) -> None:
    """The run folder again: run_dir/run.h5 (porosity as float32), config.toml, summary.json."""
    run_dir.mkdir(parents=True, exist_ok=True)
    with h5py.File(records, "r") as f, h5py.File(run_dir / "run.h5", "w") as o:
        for g in f:
            _restore(f[g], o.create_group(g))
        for t in TEXTS:
            if t in f.attrs:
                (run_dir / t).write_text(f.attrs[t])


def _restore(src: h5py.Group, dst: h5py.Group) -> None:
    dst.attrs.update(dict(src.attrs))
    for name, obj in src.items():
        if isinstance(obj, h5py.Group):
            _restore(obj, dst.create_group(name))
            continue
        attrs = dict(obj.attrs)
        step = attrs.pop("quantized_step", None)
        data = obj[()] if step is None else (obj[()] * step).astype(np.float32)
        dst.create_dataset(name, data=data, **({"compression": "gzip", "compression_opts": 1}
                                               if np.size(data) > 4096 else {}))
        dst[name].attrs.update(attrs)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="action", required=True)
    p = sub.add_parser("pack", help="RUN_DIR's groups and texts into OUT")
    p.add_argument("run_dir", type=pathlib.Path)
    p.add_argument("out", type=pathlib.Path)
    p.add_argument("--groups", nargs="+", required=True, help="run.h5 groups: mri slab, or planes series")
    p.add_argument("--quantize", action="store_true", help="porosity as uint16 steps of 1/65535")
    p.add_argument("--max-mb", type=float, default=15.5, help="largest file kept [MiB]")
    u = sub.add_parser("unpack", help="a records file back into a run folder")
    u.add_argument("records", type=pathlib.Path)
    u.add_argument("run_dir", type=pathlib.Path)
    a = ap.parse_args(argv)
    if a.action == "unpack":
        unpack(a.records, a.run_dir)
        print(f"run_records: {a.run_dir} (run.h5, config.toml, summary.json)")
        return 0
    size = pack(a.run_dir, a.out, a.groups, a.quantize, a.max_mb)
    if size:
        print(f"run_records: {a.out} {size / 2 ** 20:.2f} MiB ({', '.join(a.groups)})")
    return 0 if size else 1


if __name__ == "__main__":
    raise SystemExit(main())

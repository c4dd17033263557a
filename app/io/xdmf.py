"""XDMF 3 indexes of a run's HDF5 files, so ParaView (and any XDMF reader) opens them without a copy.

Owns: run.xdmf, particles.xdmf, checkpoint.xdmf and bed.xdmf, small XML files beside the HDF5 files they
point into (by relative path: the folder can be moved whole).

run.xdmf
  with gas: a temporal collection "gas": every /fields/<k> snapshot of run.h5 on the gas grid
  (/grid/points, /grid/hexahedra: the cells as hexahedra, so unstructured readers take them too), with
  cell data void_fraction [-], pressure [Pa], gas_velocity [m/s] (interstitial, cell centre) and the
  vessel's open_volume fraction [-] (0 inside the wall: threshold it above 0 to see the vessel);
  with grains: a temporal collection "grains": every /particles/<k> snapshot as a point cloud, with point
  data velocity [m/s], radius [m] and id (the grain's index, the same in every snapshot).
  The grains come first and the gas last (readers that take one collection, such as meshio's
  TimeSeriesReader, take the last).
particles.xdmf
  the grains' collection alone (written when the run has gas too).
checkpoint.xdmf, bed.xdmf
  the grains of that state as one point cloud (velocity, radius, id, alive); the gas state in a
  checkpoint is the solver's staggered arrays, not indexed.
"""
from __future__ import annotations

import os
import pathlib
from xml.sax.saxutils import escape, quoteattr

import h5py
import numpy as np

_TYPES = {"f": "Float", "i": "Int", "u": "UInt"}


def _item(ds: h5py.Dataset, fname: str) -> str:
    kind = _TYPES[ds.dtype.kind]
    dims = " ".join(str(n) for n in ds.shape) or "1"
    return (f'<DataItem Dimensions="{dims}" NumberType="{kind}" Precision="{ds.dtype.itemsize}" '
            f'Format="HDF">{escape(fname)}:{ds.name}</DataItem>')


def _attribute(name: str, ds: h5py.Dataset, fname: str, center: str) -> str:
    vector = ds.ndim == (4 if center == "Cell" else 2) and ds.shape[-1] == 3  # cell arrays are (nx, ny, nz[, 3])
    kind = "Vector" if vector else "Scalar"
    return (f'<Attribute Name={quoteattr(name)} AttributeType="{kind}" Center="{center}">'
            f'{_item(ds, fname)}</Attribute>')


def _cloud(name: str, time: float | None, group: h5py.Group, ids: h5py.Dataset, fname: str,
           extra=("velocity", "radius", "alive")) -> str:
    pos = group["position"]
    n = pos.shape[0]
    parts = [f'<Grid Name={quoteattr(name)} GridType="Uniform">']
    if time is not None:
        parts.append(f'<Time Value="{time!r}"/>')
    parts.append(f'<Topology TopologyType="Polyvertex" NumberOfElements="{n}" NodesPerElement="1">'
                 f'{_item(ids, fname)}</Topology>')
    parts.append(f'<Geometry GeometryType="XYZ">{_item(pos, fname)}</Geometry>')
    for k in extra:
        if k in group:
            parts.append(_attribute(k, group[k], fname, "Node"))
    parts.append(_attribute("id", ids, fname, "Node"))
    parts.append("</Grid>")
    return "".join(parts)


def _by_index(group: h5py.Group) -> list[h5py.Group]:
    return [group[k] for k in sorted(group, key=int)] if group is not None else []


def _grains_collection(f: h5py.File, fname: str) -> str | None:
    snaps = _by_index(f.get("particles"))
    if not snaps or "particle_id" not in f:
        return None
    grids = [_cloud(f"grains {i}", float(g["time"][()]), g, f["particle_id"], fname, ("velocity", "radius"))
             for i, g in enumerate(snaps)]
    return '<Grid Name="grains" GridType="Collection" CollectionType="Temporal">' + "\n".join(grids) + "</Grid>"


def _gas_collection(f: h5py.File, fname: str) -> str | None:
    snaps = _by_index(f.get("fields"))
    if not snaps or "grid" not in f:
        return None
    grid = f["grid"]
    hexes, points = grid["hexahedra"], grid["points"]
    topo = (f'<Topology TopologyType="Hexahedron" NumberOfElements="{hexes.shape[0]}">{_item(hexes, fname)}'
            f'</Topology><Geometry GeometryType="XYZ">{_item(points, fname)}</Geometry>')
    grids = []
    for i, g in enumerate(snaps):
        attrs = [_attribute(k, g[k], fname, "Cell") for k in ("void_fraction", "pressure", "gas_velocity") if k in g]
        attrs.append(_attribute("open_volume", grid["open_volume"], fname, "Cell"))
        grids.append(f'<Grid Name="gas {i}" GridType="Uniform"><Time Value="{float(g["time"][()])!r}"/>{topo}'
                     + "".join(attrs) + "</Grid>")
    return '<Grid Name="gas" GridType="Collection" CollectionType="Temporal">' + "\n".join(grids) + "</Grid>"


def _document(grids: list[str]) -> str:
    return ('<?xml version="1.0" ?>\n<Xdmf Version="3.0" xmlns:xi="http://www.w3.org/2001/XInclude">\n<Domain>\n'
            + "\n".join(grids) + "\n</Domain>\n</Xdmf>\n")


def _write(path: pathlib.Path, text: str) -> None:
    from .store import write_text

    write_text(path, text)


def write_run(run_h5: pathlib.Path, f: h5py.File | None = None) -> list[pathlib.Path]:
    """run.xdmf (and particles.xdmf when there is gas too) beside ``run_h5``; returns the files written.
    ``f``: run.h5 already open (a run writing it), else it is opened to read."""
    run_h5 = pathlib.Path(run_h5)
    fname = run_h5.name
    if f is not None:
        grains, gas = _grains_collection(f, fname), _gas_collection(f, fname)
    else:
        with h5py.File(run_h5, "r") as f:
            grains, gas = _grains_collection(f, fname), _gas_collection(f, fname)
    written = []
    grids = [g for g in (grains, gas) if g]
    if grids:
        _write(run_h5.with_suffix(".xdmf"), _document(grids))
        written.append(run_h5.with_suffix(".xdmf"))
    if grains and gas:
        path = run_h5.with_name("particles.xdmf")
        _write(path, _document([grains]))
        written.append(path)
    return written


def write_state(state_h5: pathlib.Path) -> pathlib.Path | None:
    """checkpoint.xdmf / bed.xdmf: the grains of a checkpoint or bed.h5 as one point cloud."""
    state_h5 = pathlib.Path(state_h5)
    with h5py.File(state_h5, "r") as f:
        if "grains" not in f or "particle_id" not in f:
            return None
        # one state, no time series: its time goes into the grid's name (a Time element would make it a series)
        text = _document([_cloud(f"{state_h5.stem} t = {float(f.attrs['time']):.6g} s", None, f["grains"],
                                 f["particle_id"], state_h5.name)])
    path = state_h5.with_suffix(".xdmf")
    _write(path, text)
    return path


def write_all(out_dir: pathlib.Path) -> list[pathlib.Path]:
    """Every index of a run folder (stale ones of files no longer there removed)."""
    out_dir = pathlib.Path(out_dir)
    written = []
    if (out_dir / "run.h5").exists():
        written += write_run(out_dir / "run.h5")
    for name in ("checkpoint", "bed"):
        if (out_dir / f"{name}.h5").exists():
            p = write_state(out_dir / f"{name}.h5")
            if p:
                written.append(p)
    for name in ("run.xdmf", "particles.xdmf", "checkpoint.xdmf", "bed.xdmf"):
        if out_dir / name not in written and (out_dir / name).exists():
            os.unlink(out_dir / name)
    return written

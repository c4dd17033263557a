"""Moved to :mod:`app.sim.gas.grid` (this name is kept for old imports)."""
from .gas.grid import AXES, CutCells, MacGrid, cut_cells  # noqa: F401

"""Moved to :mod:`app.sim.gas.linsolve` (this name is kept for old imports)."""
from .gas.linsolve import MGPCG, SolveInfo, plan_levels  # noqa: F401

"""Moved to :mod:`app.sim.gas` (the gas solver package); this name is kept for old imports."""
from .gas import *  # noqa: F401,F403
from .gas import __all__  # noqa: F401

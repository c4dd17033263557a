"""The DEM: soft-sphere grains, their contacts with each other and with the walls.

- ``contact.py``   the contact law (normal, tangential, rolling), written once for pairs and walls
- ``neighbors.py`` the Verlet half list: the device-side rebuild decision, cell list and build
- ``step.py``      the substep (one kernel launch) and ``DemSolver``
- ``grains.py``    per-grain constants (radius, mass) and the partner scatter

Public API: ``DemSolver``, ``NeighborOverflow``, ``bytes_per_grain``; ``grain_radius`` and
``grain_mass`` for kernels of other solvers that read the grains (coupling, rendering)."""
from ..fields import bytes_per_grain
from .grains import grain_mass, grain_radius
from .step import DemSolver, NeighborOverflow

__all__ = ["DemSolver", "NeighborOverflow", "bytes_per_grain", "grain_mass", "grain_radius"]

"""The DEM: soft-sphere grains, their contacts with each other and with the walls.

- ``contact.py``   the contact law (normal, tangential, rolling), written once for pairs and walls
- ``neighbors.py`` the Verlet half list: the device-side rebuild decision, cell list and build
- ``sort.py``      the grains re-ordered by cell (every per-grain array), the list kept valid
- ``scan.py``      the counting sort's scan of the cells' block sums (one thread, or one block on CUDA)
- ``slab.py``      the grains' volume in a vertical slab binned on pixels (the synthetic MRI's frame)
- ``step.py``      the substep (one kernel launch) and the diagnostics kernel
- ``solver.py``    ``DemSolver``: the bundles, grains in and out by id, advance and checks
- ``grains.py``    per-grain constants (radius, mass) and the partner scatter

Public API: ``DemSolver``, ``NeighborOverflow``, ``bytes_per_grain``; ``grain_radius``,
``grain_mass`` and ``grain_id`` for kernels of other solvers that read the grains (coupling,
rendering): grains sit in memory in cell order, re-sorted now and then, so a kernel that keys
anything on a grain across steps uses ``grain_id``."""
from ..fields import bytes_per_grain
from .grains import grain_id, grain_mass, grain_radius
from .solver import DemSolver, NeighborOverflow

__all__ = ["DemSolver", "NeighborOverflow", "bytes_per_grain", "grain_id", "grain_mass", "grain_radius"]

"""Field bundles: the Taichi memory a scene allocates, grouped by how often it changes.

Owns: allocation only. Each bundle is a ``@ti.data_oriented`` holder of fields that
kernels receive as ``ti.template()`` arguments; nothing here computes physics.

- ``GrainModel``  fixed per grain: radius, mass (allocated only for polydisperse grains;
  monodisperse kernels use compile-time constants instead), and the grain id held by each
  memory slot when grains are re-ordered by cell (``DemModel.sort_interval``).
- ``GrainState``  changes every substep: position, velocity, angular velocity (only with
  friction), force and torque accumulators, alive flag.
- ``ContactHistory``  the springs of the contacts a grain owns: H history slots per grain
  (tangential with friction, rolling for the elastic-plastic model only), and one per wall.
- ``NeighborList``  Verlet half list (the smaller grain owns a pair) indexed [slot, grain], laid out
  slot-major on a GPU (threads of consecutive grains read consecutive memory) and grain-major on a
  CPU (``rows_field``); with history, each
  neighbour slot names the history slot of its contact (255: not touching) and a bit mask
  marks the grain's history slots in use. So a contact finds its springs without a search,
  springs never move at a rebuild (only the slot numbers travel with their partners), and
  only touching pairs hold springs: H = 12 (the kissing number: a grain touches at most
  12 grains at least its size unless they overlap by several per cent) against K
  neighbour slots. Plus the cell list used to build it (counting sort).

Memory per grain, float32, K neighbour slots, H history slots, W walls (see ``bytes_per_grain``):
state 12*4 + 1 (x, v, x_ref, force, alive), with friction +24 (omega, torque), polydisperse +8,
coupled +28, sorted +4 (grain id); neighbour list 4*K + 8 (partners, count, cell-sorted id); with history K + 4
(slot numbers, mask) and 12*(H + W) per spring kind, plus 4 bytes per cell of the cell list (and per block of its
scan, ``DemModel.scan_block`` cells).
"""

import dataclasses
import math

import taichi as ti

from .geometry import SampledWallField


@dataclasses.dataclass(frozen=True)
class DemModel:
    """Compile-time description of a DEM scene (kernels specialise on it with ti.static)."""

    n: int                      # grain slots
    slots: int                  # neighbour slots per grain (half list)
    polydisperse: bool
    radius: float               # [m] (monodisperse)
    mass: float                 # [kg] (monodisperse)
    density: float              # [kg/m^3]
    hertz: bool                 # hertz_mindlin (else linear spring-dashpot)
    friction: bool              # tangential forces and history
    rolling: int                # 0 none, 1 constant torque, 2 elastic-plastic spring-dashpot
    # grain-grain constants
    e_star: float
    g_star: float
    kn: float
    kt: float
    damping: float
    mu: float
    mu_roll: float
    # grain-wall constants
    w_e_star: float
    w_g_star: float
    w_damping: float
    w_mu: float
    w_mu_roll: float
    walls: tuple                # geometry wall dataclasses
    gravity: tuple
    dt: float                   # [s]
    skin: float                 # [m]
    lo: tuple                   # domain [m]
    hi: tuple
    cell: tuple                 # [m] cell-list cell size per axis (>= largest cut-off)
    cells: tuple                # cell counts per axis
    periodic: tuple = (False, False, False)  # axes whose faces are periodic: grains leave by one face and enter by
    #                             the other, contacts and the list reach across (minimum image); >= 3 cells there
    sealed: tuple = (False,) * 6  # faces x-, x+, y-, y+, z-, z+ the walls close (geometry.sealed_faces): a grain that
    #                             leaves the domain there has passed through a wall, which the solver reports
    coupled: bool = False       # gas drag: per-grain drag coefficient, gas velocity and explicit force
    serial: bool = False        # one CPU thread: serial loops, atomics demoted to plain adds
    history_slots: int = 12     # springs per grain (contacts it owns); see ContactHistory
    roll_damping: float = 0.0   # eta_r of the elastic-plastic rolling model, grain-grain
    w_roll_damping: float = 0.0  # and grain-wall
    # memory order follows space: grains are re-ordered by cell at the start of the first
    # ``DemSolver.advance`` after ``set_grains`` and of the first after ``sort_interval`` list builds (0:
    # never), in scenes of at least ``sort_min_grains`` grains (fewer fit in a CPU core's L2 cache: ~300 B
    # each). Measured at 125k grains (CPU, one thread): a sort costs ~3 substeps, a build ~5, and a substep
    # on a scrambled bed ~2.9x one on a sorted bed; every 10 builds the sorts add ~6% to the builds' cost
    sort_interval: int = 10
    sort_min_grains: int = 4096
    # a build's cell counts are zeroed after it by the substep's loop over grains (each grain a share of the cells:
    # no zeroing loop before the count, a launch every substep on CUDA) where that share is at most this many cells
    # (a settled bed in its column: ~2; the poppy column ~3); else, or with 0, by a loop of their own before the count
    zero_share: int = 4
    # the cell list's scan (``dem/scan.py``, which picks these for the device: ``scan.layout``): cells in blocks of
    # ``scan_block``, the blocks' sums scanned by one thread (``scan_threads`` 0, the CPU) or by one block of
    # ``scan_threads`` threads at barriers (CUDA; that block also scans the diagnostics' height histogram, step.measure);
    # ``scan_emulate``: one CPU thread takes those threads' shares (tests)
    scan_block: int = 1024
    scan_threads: int = 0
    scan_emulate: bool = False

    @property
    def has_history(self) -> bool:
        return self.friction or self.rolling == ROLL_EPSD

    @property
    def bins_zeroed_after(self) -> bool:
        """A build's cell counts are left for the next loop over grains to zero (see ``zero_share``)."""
        return self.n > 0 and self.zero_share > 0 and self.n_cells <= self.zero_share * self.n

    @property
    def sorts(self) -> bool:
        """Grains are re-ordered in memory (a grain-id array is kept, ownership ties go by id)."""
        return self.sort_interval > 0 and self.n >= self.sort_min_grains

    @property
    def seals(self) -> bool:
        """Some face is sealed by the walls (kernels check the grains removed there only then)."""
        return any(self.sealed)

    @property
    def wraps(self) -> bool:
        """Some axis is periodic (kernels call the periodic image functions only then)."""
        return any(self.periodic)

    @property
    def n_cells(self) -> int:
        return self.cells[0] * self.cells[1] * self.cells[2]

    @property
    def scan_blocks(self) -> int:
        """Blocks of ``scan_block`` cells in the cell list."""
        return (self.n_cells + self.scan_block - 1) // self.scan_block


ROLL_NONE, ROLL_CONSTANT, ROLL_EPSD = 0, 1, 2
NO_SPRING = 255
HISTORY_SLOTS = 12


@ti.data_oriented
class GrainModel:
    def __init__(self, m: DemModel):
        if m.polydisperse:
            self.radius = ti.field(float, m.n)
            self.mass = ti.field(float, m.n)
        if m.sorts:
            self.grain_id = ti.field(ti.i32, m.n)  # the id of the grain in each memory slot


@ti.data_oriented
class GrainState:
    def __init__(self, m: DemModel):
        vec = ti.types.vector(3, float)
        self.x = vec.field(shape=m.n)
        self.v = vec.field(shape=m.n)
        self.force = vec.field(shape=m.n)
        self.alive = ti.field(ti.u8, m.n)
        if m.friction:
            self.omega = vec.field(shape=m.n)
            self.torque = vec.field(shape=m.n)
        if m.coupled:
            # set once per fluid step by the coupling: drag coefficient K [kg/s] (the grain feels
            # K (gas_velocity - v), integrated implicitly), gas velocity at the grain [m/s], and the
            # explicit gas force [N] (-V grad p in Model A, buoyancy in Model B)
            self.drag_coeff = ti.field(float, m.n)
            self.gas_velocity = vec.field(shape=m.n)
            self.external_force = vec.field(shape=m.n)


def rows_field(dtype, rows: int, n: int, vector: bool = False):
    """A (rows, n) field indexed [row, grain]. Laid out slot-major on a GPU (threads of consecutive grains
    read consecutive memory), grain-major on a CPU (a thread walks one grain's row: one cache line, not
    one line per slot). Indexing, to_numpy and from_numpy are the same either way."""
    f = ti.Vector.field(3, dtype) if vector else ti.field(dtype)
    if ti.lang.impl.current_cfg().arch == ti.cpu:
        ti.root.dense(ti.j, n).dense(ti.i, rows).place(f)
    else:
        ti.root.dense(ti.ij, (rows, n)).place(f)
    return f


@ti.data_oriented
class ContactHistory:
    def __init__(self, m: DemModel):
        vec = ti.types.vector(3, float)
        if m.friction:
            self.tangential = rows_field(float, m.history_slots, m.n, vector=True)
            if m.walls:
                self.wall_tangential = rows_field(float, len(m.walls), m.n, vector=True)
        if m.rolling == ROLL_EPSD:
            self.rolling = rows_field(float, m.history_slots, m.n, vector=True)
            if m.walls:
                self.wall_rolling = rows_field(float, len(m.walls), m.n, vector=True)


@ti.data_oriented
class NeighborList:
    def __init__(self, m: DemModel):
        self.partner = rows_field(ti.i32, m.slots, m.n)
        if m.has_history:
            self.spring_slot = rows_field(ti.u8, m.slots, m.n)  # history slot of the contact, NO_SPRING if none
            self.springs_used = ti.field(ti.u32, m.n)  # bit h: history slot h holds a contact
        self.count = ti.field(ti.i32, m.n)
        self.x_ref = ti.types.vector(3, float).field(shape=m.n)
        nc = m.n_cells
        self.cell_start = ti.field(ti.i32, nc + 1)
        self.sorted = ti.field(ti.i32, m.n)
        self.block_sum = ti.field(ti.i32, m.scan_blocks + 1)
        if m.scan_threads:
            self.scan_tmp = ti.field(ti.i32, 2 * m.scan_threads)  # the block scan's two buffers
        # [rebuild flag, overflow (largest row asked for), grains removed, builds, history slots short, dead grains
        # placed by a sort, grains out through a wall (DemModel.sealed)]: the rebuild decision lives here on the
        # device; the host reads the counters once per DemSolver.advance
        self.counters = ti.field(ti.i32, 7)

    @property
    def builds(self) -> int:
        """Rebuilds so far (a device read: not for the hot loop)."""
        return int(self.counters[3])


class WallData:
    """Device data of walls that need it (sampled SDFs), indexed like ``DemModel.walls``."""

    def __init__(self, m: DemModel):
        self.sampled = tuple(SampledWallField(w) if w.kind == 2 else _NoData() for w in m.walls)


class _NoData:
    """Placeholder for walls whose shape is analytic (kernels never read it)."""


def slots_bound(radius_min: float, skin: float) -> int:
    """Neighbour slots per grain of the half list in which the smaller grain of a pair owns it (ties: the
    lower index): a row holds only partners at least its grain's size, within r_i + r_j + skin, so its
    length is bounded by the monodisperse one at the smallest radius, 12 ((2 r_min + skin) / (2 r_min))^2
    (the kissing number of equal spheres scaled to the skin shell), whatever the size ratio. An
    overflow is detected at the build and stops the run (dem.max_neighbors overrides)."""
    q = (2 * radius_min + skin) / (2 * radius_min)
    return int(min(256, math.ceil(12 * q * q)))


def bytes_per_grain(m: DemModel, precision_bytes: int = 4) -> float:
    """Device memory per grain slot [bytes], cell list included."""
    f = precision_bytes
    b = 3 * 3 * f + 3 * f + 1  # x, v, x_ref, force, alive
    if m.polydisperse:
        b += 2 * f
    if m.friction:
        b += 2 * 3 * f + 3 * f * (m.history_slots + len(m.walls))
    if m.rolling == ROLL_EPSD:
        b += 3 * f * (m.history_slots + len(m.walls))
    if m.has_history:
        b += m.slots + 4  # history slot per neighbour slot, mask
    if m.coupled:
        b += 7 * f
    b += 4 * m.slots + 4 + 4  # partner slots, count, cell-sorted id
    if m.sorts:
        b += 4  # grain id per memory slot (the sort's scratch is the force accumulator, zero between substeps)
    b += 4 * (m.n_cells + m.scan_blocks + 1 + 2 * m.scan_threads) / max(1, m.n)  # counts, block sums, scan buffers
    return b

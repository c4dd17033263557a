"""``DemSolver``: holds one scene's DEM bundles and runs the substep kernel of ``step.py``; grains in and out
by grain id (``set_grains``, ``read``, ``state_arrays``), whatever their memory order. No I/O, no printing."""
import dataclasses

import numpy as np
import taichi as ti

from ...config.derived import grain_mass
from ..fields import NO_SPRING, ROLL_EPSD, ContactHistory, DemModel, GrainModel, GrainState, NeighborList, WallData
from .. import runtime
from . import scan
from .neighbors import BUILDS, OVERFLOW, REBUILD, REMOVED, SPRING_OVERFLOW
from .sort import sort_by_cell
from .cells import TAG_OPS, grain_cells
from .slab import slab_volumes
from .step import DIAG_COLUMNS, dem_build, dem_substep, dem_substeps, measure


class NeighborOverflow(RuntimeError):
    pass


class DemSolver:
    """Holds one scene's DEM fields and advances them; no I/O, no printing.

    Bundles: ``model`` (compile-time DemModel, also ``m``), ``fixed`` (per-grain radius and mass,
    polydisperse only), ``state``, ``history`` (contact springs), ``nlist`` (the half list and its
    counters; ``nlist.builds`` reads the rebuild count from the device), ``walls``."""

    def __init__(self, model: DemModel):
        if model.sorts and model.n >= 2 ** 24 and ti.lang.impl.current_cfg().default_fp == ti.f32:
            model = dataclasses.replace(model, sort_interval=0)  # the sort's scratch holds slots in float32
        model = scan.layout(model, runtime.on_cuda())  # the cell list's scan: one block of threads on CUDA
        self.m = self.model = model
        self.fixed = GrainModel(model)
        self.state = GrainState(model)
        self.history = ContactHistory(model)
        self.nlist = NeighborList(model)
        self.walls = WallData(model)
        self._diag = ti.field(float, 7 + len(model.walls))
        self._hist = ti.field(ti.i32, 1024)
        self._diag_row = None  # diagnostics()' one-row ring
        self._slab_out = None  # slab_volumes()' image
        self._tracked = None  # track()'s arrays: (place, cells, octant, flags)
        self.substeps_done = 0
        self._ids = None  # host copy of fixed.grain_id (dropped at every sort)
        self._builds_seen = self._builds_at_sort = 0
        self._sort_due = False

    # -- state in and out -------------------------------------------------------------
    # Outside the DEM every per-grain array is in grain-id order (the order ``set_grains`` was given);
    # inside, grain i of memory slot p is ``fixed.grain_id[p]`` once grains are sorted (``model.sorts``).
    def _f(self, a):
        """numpy array in the kernels' float type (float32 or float64)."""
        return np.ascontiguousarray(a, dtype=np.float64 if self.state.v.dtype == ti.f64 else np.float32)

    def _read_counters(self) -> np.ndarray:
        """The one host read of the device counters [rebuild flag, overflow, removed, builds, springs short, -,
        grains out through a wall]."""
        return self.nlist.counters.to_numpy()

    def _order(self):
        """The grain id held by each memory slot (None: memory order is id order)."""
        if not self.m.sorts:
            return None
        if self._ids is None:
            self._ids = self.fixed.grain_id.to_numpy()
        return self._ids

    def _by_id(self, values: np.ndarray, axis: int = 0) -> np.ndarray:
        """Memory order -> id order along the grain axis."""
        order = self._order()
        if order is None:
            return values
        out = np.empty_like(values)
        index = [slice(None)] * values.ndim
        index[axis] = order
        out[tuple(index)] = values
        return out

    @staticmethod
    def _to_memory(values, order, axis: int = 0):
        """Id order -> memory order along the grain axis (``order``: the id of each memory slot)."""
        return values if order is None else np.take(values, order, axis=axis)

    def _wrapped(self, position):
        """Positions brought into [lo, hi) along the periodic axes (as ``integrate`` keeps them); those inside
        keep their bits (a checkpoint resumes exactly)."""
        if not self.m.wraps:
            return position
        x = np.array(position, dtype=float, copy=True)
        for a, p in enumerate(self.m.periodic):
            if p and x.ndim == 2:
                lo, hi = self.m.lo[a], self.m.hi[a]
                out = (x[:, a] < lo) | (x[:, a] >= hi)
                x[out, a] = lo + np.mod(x[out, a] - lo, hi - lo)
        return x

    def set_grains(self, position, velocity=None, radius=None, omega=None, alive=None):
        """Place the grains (arrays in grain-id order); every contact spring restarts from zero."""
        self._upload(None, position, velocity, radius, omega, alive)

    def _upload(self, order, position, velocity=None, radius=None, omega=None, alive=None):
        """``set_grains`` with the grains laid out in memory as ``order`` says (None: id order)."""
        n = self.m.n
        position = self._f(self._wrapped(position))
        if position.shape != (n, 3):
            raise ValueError(f"positions must be ({n}, 3), got {position.shape}")
        mem = lambda a: self._to_memory(a, order)  # noqa: E731
        self.state.x.from_numpy(mem(position))
        self.state.v.from_numpy(mem(self._f(np.zeros((n, 3)) if velocity is None else velocity)))
        self.state.force.fill(0)
        self.state.alive.from_numpy(mem(np.ones(n, np.uint8) if alive is None else np.asarray(alive, np.uint8)))
        if not self.m.polydisperse and radius is not None:
            r = np.asarray(radius, float)
            if r.size and np.any(np.abs(r - self.m.radius) > 1e-6 * self.m.radius):  # float32 storage
                raise ValueError(f"this DEM is single-size (radius {self.m.radius:g} m) but grains of radius "
                                 f"{r.min():g} to {r.max():g} m were given: build it from a polydisperse scene")
        if self.m.polydisperse:
            # the mass from the radius as stored: a checkpoint holds that one, so a resumed run has the same masses
            # (from float64 radii, float32 runs' masses differed in the last bit after a resume, and the runs parted)
            r = self._f(radius)
            self.fixed.radius.from_numpy(mem(r))
            self.fixed.mass.from_numpy(mem(self._f(grain_mass(r.astype(float), self.m.density))))
        if self.m.sorts:
            ids = np.arange(n, dtype=np.int32) if order is None else np.asarray(order, np.int32)
            self.fixed.grain_id.from_numpy(ids)
            self._ids = ids
        if self.m.friction:
            self.state.omega.from_numpy(mem(self._f(np.zeros((n, 3)) if omega is None else omega)))
            self.state.torque.fill(0)
            self.history.tangential.fill(0)
            if self.m.walls:
                self.history.wall_tangential.fill(0)
        if self.m.rolling == ROLL_EPSD:
            self.history.rolling.fill(0)
            if self.m.walls:
                self.history.wall_rolling.fill(0)
        if self.m.coupled:
            self.state.external_force.fill(0)
            self.state.drag_coeff.fill(0)
            self.state.gas_velocity.fill(0)
        self.nlist.count.fill(0)
        if self.m.has_history:
            self.nlist.spring_slot.fill(NO_SPRING)
            self.nlist.springs_used.fill(0)
        builds = int(self.nlist.counters[BUILDS])
        self.nlist.counters.from_numpy(np.array([1, 0, 0, builds, 0, 0, 0], np.int32))  # rebuild at the next substep
        self._builds_seen = self._builds_at_sort = builds
        self._sort_due = self.m.sorts  # new grains: order them at the next advance

    _READABLE = {"position": ("state", "x"), "velocity": ("state", "v"), "omega": ("state", "omega"),
                 "alive": ("state", "alive"), "force": ("state", "force"), "drag_coeff": ("state", "drag_coeff"),
                 "gas_velocity": ("state", "gas_velocity"), "external_force": ("state", "external_force")}

    def read(self, name: str) -> np.ndarray:
        """One per-grain quantity as a numpy array indexed by grain id (the order ``set_grains`` was given):
        position [m], velocity [m/s], omega [rad/s], alive, force [N], drag_coeff [kg/s], gas_velocity [m/s],
        external_force [N], radius [m], mass [kg]. The only way code outside the DEM reads grains, so the
        DEM may keep them in any memory order."""
        if name == "radius":
            return self.radii()
        if name == "mass":
            return self.masses()
        if name not in self._READABLE:
            raise KeyError(f"no per-grain quantity {name!r}; one of {sorted(self._READABLE) + ['mass', 'radius']}")
        bundle, field = self._READABLE[name]
        values = getattr(getattr(self, bundle), field, None)
        if values is None:
            raise KeyError(f"{name!r} is not held by this scene's DEM (no friction, or not coupled)")
        return self._by_id(values.to_numpy())

    def radii(self) -> np.ndarray:
        if self.m.polydisperse:
            return self._by_id(self.fixed.radius.to_numpy())
        return np.full(self.m.n, self.m.radius)

    def slab_volumes(self, y_center: float, half_width: float, origin: tuple, pixel: tuple,
                     shape: tuple) -> np.ndarray:
        """The alive grains' volume [m^3] within the vertical slab |y - y_center| < half_width [m], binned by
        centre onto ``shape`` = (nx, nz) pixels of ``pixel`` = (dx, dz) [m] from ``origin`` = (x0, z0) [m]: an
        (nx, nz) float64 array, computed on the device (``slab.slab_volumes``), one small array read back."""
        shape = tuple(int(v) for v in shape)
        if self._slab_out is None or self._slab_out.shape != shape:
            self._slab_out = ti.ndarray(ti.f64, shape=shape)
        slab_volumes(self.m, self.fixed, self.state, float(y_center), float(half_width), float(origin[0]),
                     float(origin[1]), float(pixel[0]), float(pixel[1]), self._slab_out)
        return self._slab_out.to_numpy()

    def track(self, ids) -> None:
        """Follow the grains ``ids`` (grain ids, in the order :meth:`tracked_cells` returns them)."""
        ids = np.asarray(ids, np.int64)
        place = np.full(self.m.n, -1, np.int32)
        place[ids] = np.arange(ids.size, dtype=np.int32)
        m = max(int(ids.size), 1)
        arrays = (ti.ndarray(ti.i32, shape=self.m.n), ti.ndarray(ti.i32, shape=m), ti.ndarray(ti.u8, shape=m),
                  ti.ndarray(ti.u8, shape=m))
        arrays[0].from_numpy(place)
        self._tracked = (int(ids.size),) + arrays

    def tracked_cells(self, origin, h: float, shape, tag: tuple) -> tuple:
        """The tracked grains' cells on the grid of ``shape`` cells of ``h`` [m] from ``origin`` [m] (flat
        indices, clipped to the grid), each one's octant within its cell (bits x, y, z: 4, 2, 1), whether it is
        alive and whether its centre satisfies ``tag`` = (axis, op, value [m]) (op one of <, <=, >, >=):
        (cells int32, octant uint8, alive bool, tagged bool), computed on the device (``cells.grain_cells``)."""
        if self._tracked is None:
            raise RuntimeError("tracked_cells: call track(ids) first")
        n, place, cells, octant, flags = self._tracked
        grain_cells(self.m, self.fixed, self.state, place, float(origin[0]), float(origin[1]), float(origin[2]),
                    0.5 * float(h), int(shape[0]), int(shape[1]), int(shape[2]), int(tag[0]), TAG_OPS[tag[1]],
                    float(tag[2]), cells, octant, flags)
        f = flags.to_numpy()[:n]
        return cells.to_numpy()[:n], octant.to_numpy()[:n], (f & 2) > 0, (f & 1) > 0

    def masses(self) -> np.ndarray:
        if self.m.polydisperse:
            return self._by_id(self.fixed.mass.to_numpy())
        return np.full(self.m.n, self.m.mass)

    def state_arrays(self) -> dict:
        """Every changing field (and the neighbour list) as numpy arrays in grain-id order, partners named
        by id, with the memory order (``grain_order``) and the sort's schedule: a full checkpoint."""
        state, history, nlist = self.state, self.history, self.nlist
        counters = self._read_counters()
        by_id, rows = self._by_id, (lambda f: self._by_id(f.to_numpy(), axis=1))
        partner = nlist.partner.to_numpy()
        order = self._order()
        if order is not None:
            partner = np.where(partner >= 0, order[np.clip(partner, 0, None)], partner).astype(partner.dtype)
        out = {"position": by_id(state.x.to_numpy()), "velocity": by_id(state.v.to_numpy()),
               "alive": by_id(state.alive.to_numpy()), "radius": self.radii(), "nl_partner": by_id(partner, axis=1),
               "nl_count": by_id(nlist.count.to_numpy()), "nl_x_ref": by_id(nlist.x_ref.to_numpy()),
               "removed": np.array(counters[REMOVED]), "substeps_done": np.array(self.substeps_done),
               "need_build": np.array(int(counters[REBUILD]))}
        if order is not None:
            out.update(grain_order=order.copy(), sort_due=np.array(int(self._sort_due)),
                       sort_builds=np.array(int(counters[BUILDS]) - self._builds_at_sort))
        if self.m.has_history:
            out.update(nl_spring_slot=rows(nlist.spring_slot), nl_springs_used=by_id(nlist.springs_used.to_numpy()))
        if self.m.friction:
            out.update(omega=by_id(state.omega.to_numpy()), torque=by_id(state.torque.to_numpy()),
                       tangential=rows(history.tangential))
            if self.m.walls:
                out.update(wall_tangential=rows(history.wall_tangential))
        if self.m.rolling == ROLL_EPSD:
            out.update(rolling=rows(history.rolling))
            if self.m.walls:
                out.update(wall_rolling=rows(history.wall_rolling))
        out["force"] = by_id(state.force.to_numpy())
        if self.m.coupled:
            out.update(external_force=by_id(state.external_force.to_numpy()),
                       drag_coeff=by_id(state.drag_coeff.to_numpy()), gas_velocity=by_id(state.gas_velocity.to_numpy()))
        return out

    def load_state_arrays(self, arrays: dict) -> None:
        """Restore exactly what ``state_arrays`` returned (same scene model required), memory order included,
        so a resumed run repeats the uninterrupted one bit for bit."""
        state, history, nlist = self.state, self.history, self.nlist
        order = None
        if self.m.sorts:
            order = np.asarray(arrays.get("grain_order", np.arange(self.m.n)), np.int32)
            if order.shape != (self.m.n,):
                raise ValueError(f"grain_order must be ({self.m.n},), got {order.shape}")
        mem = lambda a, axis=0: self._to_memory(np.asarray(a), order, axis)  # noqa: E731
        self._upload(order, arrays["position"], arrays["velocity"], arrays["radius"], arrays.get("omega"),
                     arrays["alive"])
        state.force.from_numpy(mem(self._f(arrays["force"])))
        partner = np.asarray(arrays["nl_partner"], np.int32)
        if order is not None:
            slot = np.empty_like(order)
            slot[order] = np.arange(self.m.n, dtype=np.int32)
            partner = np.where(partner >= 0, slot[np.clip(partner, 0, None)], partner).astype(np.int32)
        nlist.partner.from_numpy(mem(partner, 1))
        nlist.count.from_numpy(mem(arrays["nl_count"]))
        nlist.x_ref.from_numpy(mem(self._f(arrays["nl_x_ref"])))
        self.substeps_done = int(arrays["substeps_done"])
        builds = int(nlist.counters[BUILDS])
        # a state written before the springs had their own slots (no nl_spring_slot) restarts its pair
        # springs from zero at a fresh build; the wall springs, per wall then as now, are kept
        current = not self.m.has_history or "nl_spring_slot" in arrays
        need_build = int(arrays["need_build"]) if current else 1
        nlist.counters.from_numpy(np.array([need_build, 0, int(arrays["removed"]), builds, 0, 0, 0], np.int32))
        if self.m.sorts and "grain_order" in arrays:
            self._sort_due = bool(int(arrays["sort_due"]))
            self._builds_at_sort = builds - int(arrays["sort_builds"])
        if self.m.has_history and current:
            nlist.spring_slot.from_numpy(mem(np.asarray(arrays["nl_spring_slot"], np.uint8), 1))
            nlist.springs_used.from_numpy(mem(np.asarray(arrays["nl_springs_used"], np.uint32)))
        elif self.m.has_history:
            nlist.count.fill(0)
        if self.m.friction:
            state.torque.from_numpy(mem(self._f(arrays["torque"])))
            if current:
                history.tangential.from_numpy(mem(self._f(arrays["tangential"]), 1))
            if self.m.walls:
                history.wall_tangential.from_numpy(mem(self._f(arrays["wall_tangential"]), 1))
        if self.m.rolling == ROLL_EPSD:
            if current:
                history.rolling.from_numpy(mem(self._f(arrays["rolling"]), 1))
            if self.m.walls:
                history.wall_rolling.from_numpy(mem(self._f(arrays["wall_rolling"]), 1))
        if self.m.coupled and "drag_coeff" in arrays:
            state.external_force.from_numpy(mem(self._f(arrays["external_force"])))
            state.drag_coeff.from_numpy(mem(self._f(arrays["drag_coeff"])))
            state.gas_velocity.from_numpy(mem(self._f(arrays["gas_velocity"])))

    # -- stepping ---------------------------------------------------------------------
    def rebuild(self) -> None:
        """Ask for a rebuild at the next substep (the build itself runs on the device)."""
        self.nlist.counters[REBUILD] = 1

    def sort(self) -> None:
        """Re-order the grains in memory by cell now (queued; the neighbour list is carried over, not rebuilt)."""
        if self.m.sorts:
            sort_by_cell(self.m, self.fixed, self.state, self.history, self.nlist)
            self._ids = None
            self._sort_due = False
            self._builds_at_sort = self._builds_seen

    def prepare(self) -> None:
        """Do now what the next ``advance`` would start with: the sort by cell when one is due, then the list
        build when one is flagged (after ``set_grains``, say), so a timed ``advance`` leaves out its set-up,
        as a LIGGGHTS run's timed loop leaves out the list its set-up builds. The substeps that follow are
        the same, to the bit. Queued; reads nothing."""
        if self._sort_due:
            self.sort()
        dem_build(self.m, self.fixed, self.state, self.history, self.nlist)

    def substep(self) -> None:
        """Queue one substep; reads nothing back (see ``advance`` for the checks)."""
        dem_substep(self.m, self.fixed, self.state, self.history, self.nlist, self.walls)
        self.substeps_done += 1

    def advance(self, substeps: int) -> None:
        """Queue ``substeps`` substeps, then read the counters once: NeighborOverflow if a rebuild ran out
        of slots (the substeps after it missed pairs: the run must stop). Grains are first re-ordered by
        cell when a sort is due (``model.sort_interval`` builds since the last one, decided at the last
        read of the counters; no read here). On one CPU thread the substeps are one launch."""
        if self._sort_due:
            self.sort()
        if self.m.serial and substeps > 0:  # one CPU thread: all of them in one launch
            dem_substeps(self.m, self.fixed, self.state, self.history, self.nlist, self.walls, substeps)
            self.substeps_done += substeps
        else:
            for _ in range(substeps):
                self.substep()
        self.check()

    def check(self) -> None:
        counters = self._read_counters()
        self._builds_seen = int(counters[BUILDS])
        if self.m.sorts and self._builds_seen - self._builds_at_sort >= self.m.sort_interval:
            self._sort_due = True
        over = int(counters[OVERFLOW])
        if counters[SPRING_OVERFLOW]:
            raise NeighborOverflow(f"a grain touches more than {self.m.history_slots} grains at least its size (they "
                                   "overlap by several per cent): stiffen the contacts (contact.youngs_modulus) or "
                                   "set dem.max_neighbors, which gives every neighbour slot its own springs")
        if over:
            raise NeighborOverflow(f"a grain has at least {over} neighbours within the skin but the list holds "
                                   f"{self.m.slots}: raise dem.max_neighbors (now {self.m.slots}) or lower dem.skin")

    def record_diagnostics(self, ring, row: int, col: int = 0) -> None:
        """This step's diagnostics (``step.DIAG_COLUMNS``) into ``ring[row, col:]``, a float64 ti.ndarray, on the
        device: nothing is read back (``diagnostics_of`` turns a copied row into figures)."""
        measure(self.m, self.fixed, self.state, self.history, self.nlist, self.walls, self._diag, self._hist, ring,
                row, col)

    @property
    def diag_columns(self) -> tuple:
        """The columns ``record_diagnostics`` writes: ``step.DIAG_COLUMNS``, then each wall's vertical force on
        the grains [N] (``wall_force_z_<wall name>``)."""
        return DIAG_COLUMNS + tuple(f"wall_force_z_{w.name}" for w in self.m.walls)

    def diagnostics_of(self, values: np.ndarray) -> dict:
        """Kinetic energy [J], max overlap / diameter, max speed [m/s], grains alive and removed (and of those the
        ones out through a wall), non-finite values, touching grain pairs, the bed height (95th percentile of grain
        heights) [m] and each wall's
        vertical force on the grains [N], from one recorded row (``values``: its ``diag_columns``, host numpy)."""
        d = self._f(values[:4])  # the kernels' float type: the energies sum as they were reduced
        alive, bad, contacts, removed, b, below, in_bin = (int(v) for v in values[4:11])
        z95 = float("nan")
        if alive > 0:
            frac = (0.95 * alive - below) / max(in_bin, 1)
            width = (self.m.hi[2] - self.m.lo[2]) / self._hist.shape[0]
            z95 = self.m.lo[2] + (b + frac) * width
        out = {"kinetic_energy": float(d[0] + d[1]), "kinetic_energy_rotational": float(d[1]),
               "max_overlap": float(max(d[2], 0.0)), "max_speed": float(d[3]), "grains_alive": alive,
               "grains_removed": removed, "non_finite": bad, "contacts": contacts, "bed_height": z95,
               "grains_through_walls": int(values[11])}
        n = len(DIAG_COLUMNS)
        out.update({name: float(v) for name, v in zip(self.diag_columns[n:], values[n:])})
        return out

    def diagnostics(self) -> dict:
        """This step's ``diagnostics_of``, recorded and read at once (one host read)."""
        if self._diag_row is None:
            self._diag_row = ti.ndarray(ti.f64, shape=(1, len(self.diag_columns)))
        self.record_diagnostics(self._diag_row, 0)
        return self.diagnostics_of(self._diag_row.to_numpy()[0])

"""What the gas solver gives back: readers of its state, diagnostics, and its checkpoint arrays.

:class:`SolverOutputs` is the half of :class:`~app.sim.gas.solver.FlowSolver` that reads (numpy copies,
off the hot loop) and restores state; the checkpoint arrays keep the names they had in
``app.sim.flow``, so old checkpoints load.
"""
import numpy as np
import taichi as ti

from ..launch import kernel
from .config import ALIASES, FACES, INLET, MOVING
from .fields import _k_end_layer_pressures, _k_gas_extremes, _load
from .projection import k_outputs


@kernel
def _k_add_face_flux(aperture: ti.types.ndarray(), eps_f: ti.types.ndarray(), vel: ti.types.ndarray(),
                     w: float, acc: ti.types.ndarray()):
    """acc[f] += w * aperture * face gas fraction (the step's) * velocity, on every face (the rCFD probe's sums)."""
    for f in range(acc.shape[0]):
        acc[f] += w * aperture[f] * eps_f[f] * vel[f]


#: what ``record_diagnostics`` writes into a row of the diagnostics ring, in this order: the largest |u|^2 over the
#: cells [m^2/s^2], the cells with a non-finite velocity or pressure, then the sums of ``end_layer_pressures``
GAS_DIAG_COLUMNS = ("max_speed_squared", "non_finite", "p_first", "p_second", "p_second_last", "p_last",
                    "open_first", "open_last")


@kernel
def _k_ring_row(src: ti.types.ndarray(), n: ti.i32, ring: ti.types.ndarray(), row: ti.i32, col: ti.i32):
    for k in range(n):
        ring[row, col + k] = ti.cast(src[k], ti.f64)


class SolverOutputs:
    """Readers and checkpoints of a :class:`~app.sim.gas.solver.FlowSolver` (a mixin: it uses its bundles)."""

    def face_velocity(self, axis: int) -> np.ndarray:
        """Face velocities [m/s] of component ``axis`` (0, 1, 2), shape face_shape(axis)."""
        a = int(axis)
        n = int(np.prod(self._fshapes[a]))
        return self._get(self._st["vel"], n, self._face_off[a]).reshape(self._fshapes[a])

    def face_velocities(self):
        """(u, v, w) face velocities [m/s] (interstitial), each of shape face_shape(axis)."""
        return tuple(self.face_velocity(a) for a in range(3))

    def add_face_flux(self, dt: float) -> None:
        """Add dt x every face's gas volume flux [m^3] (aperture x face gas fraction x velocity x h^2, with the
        face gas fraction the step used) to a sum kept on the device; nothing is read back (face_flux_sum is)."""
        if self._flux_sum is None:
            self._flux_sum = ti.ndarray(ti.f64, shape=(self._nf,))
            self._flux_sum.fill(0.0)
        _k_add_face_flux(self._aperture, self._st["eps_f"], self._st["vel"], float(dt) * self.h ** 2, self._flux_sum)

    def face_flux_sum(self, clear: bool = True) -> tuple:
        """The sums of add_face_flux since they were last cleared [m^3], one array per axis (face_shape(axis)),
        then clears them unless ``clear`` is False (zeros when nothing was added)."""
        if self._flux_sum is None:
            return tuple(np.zeros(s) for s in self._fshapes)
        flat = self._flux_sum.to_numpy()
        if clear:
            self._flux_sum.fill(0.0)
        off = self._face_off
        return tuple(flat[off[a]:off[a] + int(np.prod(self._fshapes[a]))].reshape(self._fshapes[a]) for a in range(3))

    def load_face_flux_sum(self, sums) -> None:
        """Set the sums of add_face_flux [m^3] to ``sums`` (face_flux_sum's form: a resumed run's, as saved)."""
        flat = np.zeros(self._nf)
        for a in range(3):
            n = int(np.prod(self._fshapes[a]))
            flat[self._face_off[a]:self._face_off[a] + n] = np.asarray(sums[a], np.float64).reshape(n)
        if self._flux_sum is None:
            self._flux_sum = ti.ndarray(ti.f64, shape=(self._nf,))
        self._flux_sum.from_numpy(flat)

    def void_fraction(self) -> np.ndarray:
        """Gas volume fraction eps [-] on the cells (nx, ny, nz), as the coupling last wrote it (the
        solver reads it clamped to [1e-3, 1]). With :meth:`face_velocities`, the volume flux through a
        face is aperture * eps_face * u * h^2 (eps_face the mean of its two cells)."""
        return self.fields.eps.to_numpy()

    def cell_velocity(self) -> np.ndarray:
        """Interstitial gas velocity at cell centres (nx, ny, nz, 3) [m/s] (0 in inactive cells)."""
        return self.fields.u_gas.to_numpy()

    def pressure(self) -> np.ndarray:
        """Pressure [Pa] at cell centres (nx, ny, nz)."""
        return self.fields.p.to_numpy()

    def pressure_gradient(self) -> np.ndarray:
        return self.fields.grad_p.to_numpy()

    def gas_extremes(self) -> tuple[float, int]:
        """(largest gas speed at cell centres [m/s], number of cells with a non-finite velocity or pressure),
        reduced on the device."""
        _k_gas_extremes(self.fields.u_gas, self.fields.p, self._reduced)
        return self._extremes_of(self._reduced.to_numpy())

    @staticmethod
    def _extremes_of(r) -> tuple[float, int]:
        return float(np.sqrt(max(r[0], 0.0))), int(r[1])

    def end_layer_pressures(self) -> tuple[float, float, float, float]:
        """Open-area means of the pressure [Pa] in the first, second, second-to-last and last cell layers
        (weighted by the open fraction of the bottom layer for the first two, of the top layer for the others)."""
        if self.shape[2] < 2:
            raise ValueError("flow: end-layer pressures need at least two cell layers")
        _k_end_layer_pressures(self.fields.p, self.fields.vol_frac, self._reduced)
        return self._end_layers_of(self._reduced.to_numpy())

    @staticmethod
    def _end_layers_of(r) -> tuple[float, float, float, float]:
        wb, wt = max(r[4], 1e-300), max(r[5], 1e-300)
        return float(r[0] / wb), float(r[1] / wb), float(r[2] / wt), float(r[3] / wt)

    def record_diagnostics(self, ring, row: int, col: int = 0) -> None:
        """The step's extremes and end-layer pressure sums (GAS_DIAG_COLUMNS) into ``ring[row, col:]``, a float64
        ti.ndarray, on the device: nothing is read back (``diagnostics_of`` turns a copied row into figures)."""
        _k_gas_extremes(self.fields.u_gas, self.fields.p, self._reduced)
        _k_ring_row(self._reduced, 2, ring, row, col)
        if self.shape[2] >= 2:
            _k_end_layer_pressures(self.fields.p, self.fields.vol_frac, self._reduced)
            _k_ring_row(self._reduced, 6, ring, row, col + 2)

    def diagnostics_of(self, values: np.ndarray) -> dict:
        """``gas_max_speed`` [m/s], ``gas_non_finite`` and (two layers or more) ``end_layer_pressures`` [Pa] from
        one recorded row (``values``: its GAS_DIAG_COLUMNS), as ``gas_extremes`` and ``end_layer_pressures``."""
        r = np.asarray(values, np.float64 if self._reduced.dtype == ti.f64 else np.float32)  # the kernels' float
        speed, bad = self._extremes_of(r[:2])
        out = {"gas_max_speed": speed, "gas_non_finite": bad}
        if self.shape[2] >= 2:
            out["end_layer_pressures"] = self._end_layers_of(r[2:8])
        return out

    @property
    def cfl(self) -> float:
        return self.last.cfl if self.last else 0.0

    @property
    def pressure_iterations(self) -> int:
        return self.last.pressure_iterations if self.last else 0

    def divergence(self) -> np.ndarray:
        """Per-cell continuity residual theta*deps/dt + div(eps u) [1/s] of the current velocity,
        with the eps and d(eps)/dt the last step used (those at construction before any step)."""
        self._div = tuple(float(x) for x in k_outputs(self.g, self.inp, self.st, self.cl))
        return self._div_cell.to_numpy().astype(np.float64)

    def divergence_residual(self) -> float:
        """max|continuity residual| / S of the current velocity, S = the larger gross face-flux
        rate of a cell of the current field and of the last predicted field (module doc).
        After every step this is <= tol when the pressure solve converged."""
        self.divergence()
        dmax, smax = self._div
        s = max(smax, self._s_pred)
        return dmax / s if s > 0 else 0.0

    def boundary_flux(self, face: str) -> float:
        """Volumetric gas flow out of the domain through ``face`` [m^3/s] (sum a eps u h^2; negative = in)."""
        f = ALIASES.get(face, face)
        fi = FACES.index(f)
        a, side = fi // 2, fi % 2
        vel = self.face_velocity(a)
        ap = self.cut.apertures[a]
        eps = self.fields.eps.to_numpy()
        idx = 0 if side == 0 else self.shape[a]
        cell = 0 if side == 0 else self.shape[a] - 1
        q = np.take(ap * vel, idx, axis=a) * np.take(eps, cell, axis=a)
        sign = -1.0 if side == 0 else 1.0
        return sign * float(q.sum()) * self.h ** 2

    # ------------------------------------------------------------------ checkpoints
    def state_arrays(self) -> dict:
        """Every array needed to continue the run bit-for-bit (numpy copies): face velocities
        ``u``, ``v``, ``w`` [m/s]; ``pressure`` [Pa]; the coupling inputs ``eps``, ``deps_dt``,
        ``beta``, ``solid_velocity``, ``explicit_source``; the last step's ``acceleration`` and
        ``predictor_increment`` (flat face arrays, used by the second-order advection and the
        viscous initial iterate); ``inlet_<face>`` profiles (n1, n2, 3); ``time``, ``steps`` and
        ``pressure_initialised`` as 0-d arrays."""
        fl = self.fields
        out = {"u": self.face_velocity(0), "v": self.face_velocity(1), "w": self.face_velocity(2),
               "pressure": fl.p.to_numpy().astype(np.float64),
               "eps": fl.eps.to_numpy(), "deps_dt": fl.deps_dt.to_numpy(), "beta": fl.beta.to_numpy(),
               "solid_velocity": fl.us.to_numpy(), "explicit_source": fl.f_exp.to_numpy(),
               "acceleration": self._get(self._st["accel"], self._nf),
               "predictor_increment": self._get(self._st["dpred"], self._nf),
               "time": np.asarray(self.time, np.float64), "steps": np.asarray(self.steps, np.int64),
               "pressure_initialised": np.asarray(not self._p_init_pending)}
        for fi, face in enumerate(FACES):
            if self._kinds[fi] in (INLET, MOVING):
                dims = self._bcv_dims[fi]
                blk = self._get(self._bcv, 3 * dims[0] * dims[1], self._bcv_off[fi]).reshape((3,) + dims)
                out["inlet_" + face] = np.moveaxis(blk, 0, -1).copy()
        return out

    def load_state_arrays(self, arrays: dict) -> None:
        """Restore a state written by :meth:`state_arrays` (same set-up); ValueError if it does not fit."""
        def get(name, shape):
            if name not in arrays:
                raise ValueError(f"flow: gas state lacks {name!r}")
            a = np.asarray(arrays[name], np.float64)
            if a.shape != tuple(shape):
                raise ValueError(f"flow: gas state {name!r} has shape {a.shape}, this set-up needs {tuple(shape)}")
            return a

        sh, sh3 = self.shape, self.shape + (3,)
        self.set_eps(get("eps", sh))
        self.set_deps_dt(get("deps_dt", sh))
        self.set_beta(get("beta", sh))
        self.set_solid_velocity(get("solid_velocity", sh3))
        self.set_explicit_source(get("explicit_source", sh3))
        self.set_face_velocity(*(get(n, self._fshapes[a]) for a, n in enumerate("uvw")))
        _load(self.fields.p, get("pressure", sh))
        self._put(self._st["accel"], get("acceleration", (self._nf,)))
        self._put(self._st["dpred"], get("predictor_increment", (self._nf,)))
        for fi, face in enumerate(FACES):
            if self._kinds[fi] in (INLET, MOVING):
                vec = get("inlet_" + face, self._bcv_dims[fi] + (3,))
                self._set_bcv(fi, vec)
                self._bc_speeds[fi] = float(np.max(np.linalg.norm(vec, axis=-1)))
        self.time = float(get("time", ()))
        self.steps = int(get("steps", ()))
        self._p_init_pending = not bool(get("pressure_initialised", ()))
        # refresh the face coefficients and the cell outputs (u_gas, grad_p) from the restored state
        self._face_coefficients()
        self.divergence()

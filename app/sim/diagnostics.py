"""The diagnostics ring: each recorded step's diagnostics written on the device, read back in blocks.

Owns: one float64 device array of ``rows`` x (the DEM's, the gas's and the coupler's columns), and turning a
copied block back into one figures dict per step. ``record(row, host)`` launches each solver's diagnostics
kernel into row ``row`` (``DemSolver.record_diagnostics``, ``FlowSolver.record_diagnostics``; the coupler's
clipped-cell count is copied by the kernel here) and reads nothing back; ``read(n)`` copies the block in one
host read. So a series row per step costs the host no wait: the Simulation reads the block every ``rows``
steps, or sooner when a writer or the guard needs the current figures (``Simulation.flush_diagnostics``).
"""

import numpy as np
import taichi as ti

from .launch import kernel
from .gas.outputs import GAS_DIAG_COLUMNS


@kernel
def _k_store_count(count: ti.template(), ring: ti.types.ndarray(), row: ti.i32, col: ti.i32):
    ring[row, col] = ti.cast(count[None], ti.f64)


class DiagnosticsRing:
    def __init__(self, dem, flow, coupler, rows: int):
        self.dem, self.flow, self.coupler, self.rows = dem, flow, coupler, int(rows)
        self.gas_col = len(dem.diag_columns) if dem is not None else 0
        self.clip_col = self.gas_col + (len(GAS_DIAG_COLUMNS) if flow is not None else 0)
        cols = self.clip_col + (1 if coupler is not None else 0)
        self.ring = ti.ndarray(ti.f64, shape=(self.rows, max(cols, 1)))
        self.ring.fill(0.0)

    def record(self, row: int) -> None:
        """The current step's diagnostics into row ``row`` (0 <= row < rows), on the device."""
        if self.dem is not None:
            self.dem.record_diagnostics(self.ring, row, 0)
        if self.flow is not None:
            self.flow.record_diagnostics(self.ring, row, self.gas_col)
        if self.coupler is not None:
            _k_store_count(self.coupler.cf.clipped, self.ring, row, self.clip_col)

    def read(self, n: int) -> list[dict]:
        """Rows 0..n-1 as figures dicts (the DEM's ``diagnostics_of``, the gas's, ``clipped_cells``): one host read."""
        block = self.ring.to_numpy()[:n] if n else np.zeros((0, 1))
        out = []
        for values in block:
            d = self.dem.diagnostics_of(values[:self.gas_col]) if self.dem is not None else {}
            if self.flow is not None:
                d.update(self.flow.diagnostics_of(values[self.gas_col:self.clip_col]))
            if self.coupler is not None:
                d["clipped_cells"] = int(values[self.clip_col])
            out.append(d)
        return out

"""Gas-only scenes shared by tests (CPU, float64 from conftest)."""
import numpy as np

from app.sim import gas


def jet_solver() -> gas.FlowSolver:
    """A 50 m/s jet through a 2x2-cell inlet profile on 6 mm cells (CFL ~ 8 at dt = 1e-3 s), pressure
    outlet on top, pressure solve to 1e-8."""
    cfg = gas.FlowConfig(shape=(16, 16, 32), h=0.006, rho=1.2, mu=1.8e-5, gravity=(0, 0, -9.81), tol=1e-8,
                          bcs={"bottom": gas.velocity_inlet((0, 0, 0)), "top": gas.pressure_outlet()})
    s = gas.FlowSolver(cfg)
    prof = np.zeros((16, 16))
    prof[7:9, 7:9] = 50.0
    s.set_inlet_profile("bottom", prof)
    return s

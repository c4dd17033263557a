"""Verification of the coupled step against exact limits: a frozen packed bed (Ergun) and
one grain settling in still gas (Schiller-Naumann terminal velocity)."""
import math

import numpy as np
import pytest
from scipy.optimize import brentq

from app.sim.coupling import Coupler
from app.sim.dem import DemSolver
from app.sim.gas import FlowSolver

from dem_helpers import make

pytestmark = pytest.mark.verification

MU, RHO_G = 1.8e-5, 1.2


def ergun_gradient(U, eps, d):
    phi = 1 - eps
    return 150 * MU * U * phi ** 2 / (eps ** 3 * d ** 2) + 1.75 * RHO_G * U ** 2 * phi / (eps ** 3 * d)


@pytest.mark.parametrize("form", ["shared", "gas"])
def test_frozen_packed_bed_pressure_drop_is_ergun(form):
    """Grains frozen on a cubic lattice (eps = 1 - pi/6) fill a 12 mm square box 20 lattice layers
    deep; the gas blows through at three velocities below U_mf. The pressure drop across the bed
    (gas hydrostatics removed) must match Ergun within 5%: the deposit smears the bed's top and
    bottom over about one cell (h = 2 mm against a 40 mm bed), the rest is exact."""
    d, h, width = 2e-3, 2e-3, 0.012
    nx, layers = 6, 20
    xs = (np.arange(nx) + 0.5) * d - width / 2
    z0 = 0.02
    zs = z0 + (np.arange(layers) + 0.5) * d
    X, Y, Z = np.meshgrid(xs, xs, zs, indexing="ij")
    pos = np.column_stack([X.ravel(), Y.ravel(), Z.ravel()])
    n = len(pos)
    eps = 1 - math.pi / 6
    results = []
    for U in (0.05, 0.1, 0.2):
        scene, _ = make(
            domain={"lo": [-width / 2, -width / 2, 0.0], "hi": [width / 2, width / 2, 0.08], "gravity": [0.0, 0.0, -9.81]},
            vessel={"shape": "box"}, particles={"diameter": d, "density": 2500.0, "count": n},
            gas={"cell_size": h, "pressure_form": form, "viscosity": MU, "density": RHO_G},
            coupling={"drag": "gidaspow", "eps_min": 0.3},
            boundary={"bottom": {"kind": "velocity_inlet", "velocity": [0.0, 0.0, U]}, "top": "pressure_outlet",
                      "x-": "free_slip", "x+": "free_slip", "y-": "free_slip", "y+": "free_slip"})
        dem = DemSolver(scene.model)
        dem.set_grains(pos, None, np.full(n, d / 2))
        flow = FlowSolver(scene.flow)
        cp = Coupler(scene.coupling, dem, flow)
        dt = 1e-3
        for _ in range(150):
            cp.step(dt)
            flow.step(dt)
        p = flow.pressure()
        dz = (p.shape[2] - 1) * h
        dp = p[:, :, 0].mean() - p[:, :, -1].mean() - RHO_G * 9.81 * dz
        expected = ergun_gradient(U, eps, d) * layers * d
        results.append(dp / expected)
    print(f"{form}: dp / Ergun = {np.round(results, 4)}")
    assert np.allclose(results, 1.0, atol=0.05), results


def test_single_grain_reaches_schiller_naumann_terminal_velocity():
    """A 0.1 mm glass grain falls through still air (8 mm gas cells, so the gas it drags along is
    ~1% of its speed); after ~6 relaxation times its speed is within 2% of the terminal velocity
    from (m - rho_g V) g = C_D (pi d^2 / 8) rho_g v^2, C_D = 24/Re (1 + 0.15 Re^0.687)."""
    d, rho_p, h = 1e-4, 2500.0, 8e-3
    scene, _ = make(
        domain={"lo": [-0.02, -0.02, 0.0], "hi": [0.02, 0.02, 0.32], "gravity": [0.0, 0.0, -9.81]},
        vessel={"shape": "box"}, particles={"diameter": d, "density": rho_p, "count": 1},
        contact={"youngs_modulus": 1e3, "friction": 0.0},  # never touches anything: softest contacts, longest step
        run={"step": 2e-3},
        gas={"cell_size": h, "viscosity": MU, "density": RHO_G, "pressure_form": "shared"},
        coupling={"drag": "schiller_naumann"},
        boundary={"top": "pressure_outlet"})
    dem = DemSolver(scene.model)
    dem.set_grains([[0.004, 0.004, 0.3]], None, [d / 2])
    flow = FlowSolver(scene.flow)
    cp = Coupler(scene.coupling, dem, flow)
    vol = math.pi * d ** 3 / 6
    m = rho_p * vol

    def residual(v):
        re = RHO_G * d * v / MU
        cd = 24 / re * (1 + 0.15 * re ** 0.687)
        return (m - RHO_G * vol) * 9.81 - cd * math.pi * d ** 2 / 8 * RHO_G * v * v

    vt = brentq(residual, 1e-4, 10)
    dt = 2e-3  # the grain's relaxation time v_t/g ~ 0.06 s is 30 steps
    for _ in range(200):
        cp.step(dt)
        flow.step(dt)
        dem.advance(scene.derived.substeps)
    v = -dem.read("velocity")[0, 2]
    print(f"terminal velocity {v:.4f} m/s, Schiller-Naumann {vt:.4f} m/s")
    assert v == pytest.approx(vt, rel=0.02)

"""The gas step does not wait on the device: one value (the step record) read back per step.

Counted with a test double around every read point (tests/kernel_counter.py): each launch of a
kernel that returns a value, each to_numpy() and each Python-scope element read of a field or
ndarray, over every kernel of app.sim.
"""
import dataclasses
import sys

import numpy as np

from app.sim import gas
from app.sim.geometry import CylinderWall

from kernel_counter import KernelCounter
import pytest

pytestmark = pytest.mark.verification

H, DT = 0.006, 1e-3


def _bed_scene(shape=(16, 16, 24)):
    """The flow_throughput scene, small: cylinder vessel (cut cells), a bed of eps 0.45-0.5 and
    beta 1.5e4-1.95e4 in the lower 40%, 0.5 m/s inflow, pressure outlet, Model A, MacCormack."""
    nx, ny, nz = shape
    cyl = CylinderWall(center=(nx * H / 2, ny * H / 2), radius=(min(nx, ny) / 2 - 1) * H)
    cfg = gas.FlowConfig(shape=shape, h=H, rho=1.2, mu=1.8e-5, gravity=(0.0, 0.0, -9.81), walls=(cyl,),
                          pressure_form="shared", convection="maccormack", tol=1e-6,
                          bcs={"bottom": gas.velocity_inlet((0.0, 0.0, 0.5)), "top": gas.pressure_outlet(0.0)})
    s = gas.FlowSolver(cfg)
    rng = np.random.default_rng(3)
    eps = np.ones(shape)
    beta = np.zeros(shape)
    bed = np.zeros(shape, bool)
    bed[:, :, : int(0.4 * nz)] = True
    eps[bed] = 0.45 + 0.05 * rng.random(bed.sum())
    beta[bed] = 1.5e4 * (1.0 + 0.3 * rng.random(bed.sum()))
    s.set_eps(eps)
    s.set_beta(beta)
    return s, eps


def _sim_modules():
    return [m for n, m in sorted(sys.modules.items()) if n.startswith("app.sim") and m is not None]


def test_one_gas_step_reads_one_value_back():
    s, eps = _bed_scene()
    for _ in range(3):  # the first step also finds a consistent pressure; the budget settles
        s.step(DT)
    reads = []
    with KernelCounter(_sim_modules()) as kc:
        for _ in range(4):
            kc.reset()
            info = s.step(DT)
            reads.append(kc.reads)
            assert info.converged and info.divergence <= s.config.tol, info
            assert info.pressure_iterations >= 2 and info.viscous_sweeps >= 1, info  # real work was done
            assert kc.launches > 20, kc.by_kernel
        # the double sees reads: a pressure copy to the host is one
        kc.reset()
        s.pressure()
        assert kc.reads == 1, kc.reads_by
    assert max(reads) <= 1, reads
    assert s.divergence_residual() <= s.config.tol
    # the accessors a recording probe reads: the void fraction as set, face velocities of the face shapes
    np.testing.assert_array_equal(s.void_fraction(), eps)
    assert [u.shape for u in s.face_velocities()] == [s.grid.face_shape(a) for a in range(3)]


def _viscous_bed(**changes):
    """A viscous bed (mu = 1e-2 Pa s: 10-13 sweeps a step) on 8 x 8 x 12 cells, the bed in the lower 5 layers."""
    s, _ = _bed_scene((8, 8, 12))
    s = gas.FlowSolver(dataclasses.replace(s.config, mu=1e-2, **changes))
    s.set_eps(np.where(np.arange(12) < 5, 0.45, 1.0)[None, None, :] * np.ones((8, 8, 12)))
    s.set_beta(np.where(np.arange(12) < 5, 1.5e4, 0.0)[None, None, :] * np.ones((8, 8, 12)))
    return s


def _viscous_steps(s, n):
    """n steps: their StepInfos, the k_visc_more launches of each, and the final velocities and pressure."""
    infos, more = [], []
    with KernelCounter(_sim_modules()) as kc:
        for _ in range(n):
            kc.reset()
            infos.append(s.step(DT))
            more.append(sum(c for k, c in kc.by_kernel.items() if k.endswith("k_visc_more")))
    return infos, more, [u.copy() for u in s.face_velocities()] + [s.pressure().copy()]


def test_viscous_launches_follow_the_last_step_and_a_shortfall_changes_nothing():
    """The viscous sweeps stop themselves on the device; the host launches the later chunks only as far as the
    last step's count and a margin (FlowSolver.VISCOUS_MARGIN), not to gas.max_viscous_sweeps. When a step's
    sweeps outrun that, its projection is void, found at the step's one read, and redone after the remaining
    launches: the step is then the one every launch would have given, to the bit. A viscous bed (mu = 1e-2 Pa s:
    10-13 sweeps a step, 3 chunks) run with every launch, with the margin, and with a margin so short that every
    step outruns it: the same velocities, pressures and step figures; the margin launches fewer chunks (counted)."""
    def run(margin):
        s = _viscous_bed()
        s.VISCOUS_MARGIN = margin
        infos, more, state = _viscous_steps(s, 4)
        return infos, more, state, s.viscous_retries

    every, budget, short = run(None), run(2), run(-20)
    assert all(8 < i.viscous_sweeps < 40 for i in every[0]), every[0]  # several chunks, below the cap
    assert every[3] == 0 and short[3] >= 3, (every[3], short[3])  # each step after the first outran the short one
    for other in (budget, short):
        assert other[0] == every[0]  # the same StepInfo: sweeps, iterations, residuals to the bit
        for a, b in zip(other[2], every[2]):
            assert np.array_equal(a, b)
    assert sum(budget[1][1:]) < sum(every[1][1:]), (budget[1], every[1])


def test_a_huge_viscous_sweep_cap_launches_what_the_sweeps_need():
    """gas.max_viscous_sweeps = 1e9 (the schema allows it): the first step had launched every chunk up to the cap,
    2.5e8 empty kernels, and the run never ended (found by running every schema key at its edges). Now the first
    step launches FlowSolver.FIRST_LAUNCHES chunks and, when its sweeps outrun them, doubles them: the viscous bed
    (10-13 sweeps a step) takes the steps it takes under the default cap of 40, to the bit, with as many launches."""
    capped, huge = (_viscous_steps(_viscous_bed(max_viscous_sweeps=cap), 3) for cap in (40, 10 ** 9))
    assert all(8 < i.viscous_sweeps < 40 for i in capped[0]), capped[0]
    assert huge[0] == capped[0]
    for a, b in zip(huge[2], capped[2]):
        assert np.array_equal(a, b)
    # the first step runs the solver twice (a throw-away step sets the initial pressure); later steps launch as
    # many chunks as under the default cap
    assert huge[1][0] <= 2 * gas.FlowSolver.FIRST_LAUNCHES and huge[1][1:] == capped[1][1:], (huge[1], capped[1])

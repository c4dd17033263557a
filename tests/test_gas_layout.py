"""The gas package's structure (issue 18): modules of at most 400 lines, kernels over named bundles
(argpacks) rather than one flat arena, and kernels that compile once for any grid size."""
import pathlib
import re

import numpy as np
import pytest
import taichi as ti
from taichi.lang.argpack import ArgPackType

from app.sim import gas
from app.sim.gas import advection, boundary, coarse, layout, multigrid, pcg, predictor, projection, vcycle

pytestmark = pytest.mark.unit

GAS = pathlib.Path(gas.__file__).parent
MODULES = (advection, boundary, coarse, layout, multigrid, pcg, predictor, projection, vcycle)
# host <-> array transfers and small reductions: plain ndarrays are their whole point
TRANSFER = {"k_write", "k_read", "k_copy", "k_set_faces", "k_get_faces", "k_cells_in", "k_cells_out"}


def test_no_gas_module_over_400_lines():
    sizes = {p.name: len(p.read_text().splitlines()) for p in GAS.glob("*.py")}
    assert len(sizes) >= 10, sizes  # grid, layout, boundary, advection, predictor, projection, solver ...
    assert max(sizes.values()) <= 400, sizes


def _kernels():
    for m in MODULES:
        for name, k in vars(m).items():
            if getattr(k, "_is_wrapped_kernel", False) and k.__module__ == m.__name__:
                yield m.__name__ + "." + name, name, k


def test_no_atomic_into_one_array_element():
    """Every max and sum of the gas over cells or faces accumulates in a kernel-scope variable, which Taichi 1.7.4
    reduces per thread (then one atomic per warp on CUDA), never with ``ti.atomic_*`` into one element of an array
    (``gsc[SC_...]``, ``ctrl[S_...]``, ``out[0]``): that is one atomic per cell on one address, and a float max on
    CUDA a compare-and-swap loop per cell (benchmarks/reduction_cost.py: 4-40x on the CPU already). Read from the
    source: on the tree before this check it finds the 17 such atomics the gas had. An augmented assignment into an
    element inside a loop (``ctrl[S_X] += ...``) is the same atomic, which this text search cannot tell from the
    one-thread updates of the solve's control and does not look for."""
    one_element = re.compile(r"atomic_(?:add|sub|max|min)\(\s*[\w.]+\[\s*[A-Z_0-9]+\s*\]")
    hits = [f"{p.name}:{i}: {line.strip()}" for p in sorted(GAS.glob("*.py"))
            for i, line in enumerate(p.read_text().splitlines(), 1) if one_element.search(line)]
    assert not hits, hits


def test_solver_kernels_take_bundles_not_an_arena():
    """Every kernel of the step takes argpacks (named arrays) and scalars, no bare array."""
    seen = 0
    for full, name, k in _kernels():
        if name in TRANSFER:
            continue
        seen += 1
        for arg in k._primal.arguments:
            ann = arg.annotation
            if arg.name == "serial":  # the one compile-time flag: loops nested in one serial loop (one CPU thread)
                assert isinstance(ann, ti.types.template), (full, arg.name, ann)
                continue
            assert not isinstance(ann, ti.types.ndarray_type.NdarrayType), (full, arg.name)
            assert isinstance(ann, ArgPackType) or ann in (ti.i32, float, ti.f32, ti.f64), (full, arg.name, ann)
        assert any(isinstance(a.annotation, ArgPackType) for a in k._primal.arguments), full
    assert seen >= 15


def test_step_kernels_compile_once_for_two_grids():
    """Solvers of two grid sizes (and boundary kinds) run the same compiled step kernels: the second grid compiles
    no new instance of any (counted after the first grid's step, so instances other tests of the worker compiled,
    e.g. the parallel form's, do not count)."""
    kernels = (advection.k_advect, advection.k_advect_finish, boundary.k_bc_prep, predictor.k_visc,
               predictor.k_face_coef, projection.k_build, projection.k_correct, projection.k_record, vcycle.k_down,
               vcycle.k_up, vcycle.k_iter_down, vcycle.k_down_coarse, vcycle.k_up_from)
    counts = None
    for shape, bcs in (((6, 6, 8), {"bottom": gas.velocity_inlet((0, 0, 0.2)), "top": gas.pressure_outlet()}),
                       ((8, 4, 10), {})):
        s = gas.FlowSolver(gas.FlowConfig(shape=shape, h=0.01, bcs=bcs))
        s.set_eps(np.full(shape, 0.8))
        info = s.step(1e-3)
        assert info.converged, info
        now = [len(k._primal.compiled_kernels) for k in kernels]
        assert min(now) >= 1
        if counts is not None:
            assert now == counts, [k._primal.func.__name__ for k, a, b in zip(kernels, now, counts) if a != b]
        counts = now
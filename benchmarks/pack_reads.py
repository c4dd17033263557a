"""Which members of its argument packs each gas kernel reads, recorded while Taichi compiles it.

Taichi 1.7.4 sets every ndarray member of a pack at every launch (~3 us each on the host: launch_cost.py
--per-array), so a kernel launched often should take a ``launch.narrowed`` view with only what it reads. This
script hooks ``ArgPack.__getitem__`` during compilation (offline cache off, so every kernel is compiled here) and
runs the gas over the scenes that reach its compiled variants: the flow_throughput bed (serial form), the test
scenes (cut cells, jet inlet, periodic, singular), and three convection / pressure-form pairs, in both the serial
and the parallel form. It prints, per kernel and pack type, the members read and the members not read.

    python benchmarks/pack_reads.py
"""
from __future__ import annotations

import collections
import pathlib
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]
for p in (ROOT, ROOT / "benchmarks", ROOT / "tests"):
    sys.path.insert(0, str(p))


def main() -> int:
    import numpy as np
    import taichi as ti
    from taichi.lang import argpack as ap
    from taichi.lang import kernel_impl

    compiling = [None]
    reads = collections.defaultdict(set)
    get, materialize = ap.ArgPack.__getitem__, kernel_impl.Kernel.materialize

    def recorded_get(self, key):
        if compiling[0] is not None:
            reads[(compiling[0], id(getattr(self, "_ArgPack__dtype", None)))].add(key)
        return get(self, key)

    def recorded_materialize(self, key=None, args=None, arg_features=None):
        compiling[0] = self.func.__name__
        try:
            return materialize(self, key, args, arg_features)
        finally:
            compiling[0] = None

    ap.ArgPack.__getitem__ = recorded_get
    kernel_impl.Kernel.materialize = recorded_materialize
    ti.init(ti.cpu, offline_cache=False, cpu_max_num_threads=1, log_level=ti.ERROR, default_fp=ti.f32)

    import test_gas_serial as scenes
    from flow_throughput import DT, scene, shuffle_bed

    from app.sim import gas
    from app.sim.gas import layout, multigrid, pcg, predictor, projection, vcycle

    s, bed, eps, rng = scene((8, 8, 16), 1e-6)  # the serial form (one thread)
    for _ in range(3):
        eps = shuffle_bed(s, bed, eps, rng)
        s.step(DT)
    for serial in (True, False):
        for make in (scenes._bed_scene, scenes._periodic_scene):
            s = make(serial)
            for _ in range(3):
                s.step(DT)
        for conv, form in (("semi_lagrangian", "gas"), ("none", "shared"), ("maccormack", "gas")):
            cfg = gas.FlowConfig(shape=(6, 6, 12), h=0.006, gravity=(0.0, 0.0, -9.81), tol=1e-8, convection=conv,
                                 pressure_form=form, trace_forces=True,
                                 bcs={"bottom": gas.velocity_inlet((0.0, 0.0, 0.3)), "top": gas.pressure_outlet(0.0)})
            s = gas.FlowSolver(cfg, serial=serial)
            s.set_eps(0.6 + 0.4 * np.random.default_rng(1).random(cfg.shape))
            for _ in range(3):
                s.step(DT)
    types = {}
    for mod in (layout, multigrid, pcg, predictor, projection, vcycle):
        for name, obj in vars(mod).items():
            if isinstance(obj, ap.ArgPackType):
                types.setdefault(id(obj.dtype), (name, list(obj.members)))
    print("| kernel | pack type | members read | not read |\n|---|---|---|---|")
    for (kernel, dtype), keys in sorted(reads.items()):
        name, members = types.get(dtype, ("?", sorted(keys)))
        print(f"| {kernel} | {name} | {len(keys)}/{len(members)} | {', '.join(m for m in members if m not in keys)} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""The grains' volume within a vertical slab, binned onto pixels, on the device: the synthetic MRI's image
(``app/probes_mri.py``) without copying a million grains to the host each frame.

The slab is |y - y_c| < h; each grain gives the exact part of its sphere between the slab's faces, all of it to
the pixel (i, k) holding its centre, i = floor((x - x0) / dx), k = floor((z - z0) / dz); grains off the pixel grid
give nothing. The part of a sphere of radius r centred dy from the mid-plane inside the slab is, with
t1 = max(-r, -h - dy) and t2 = min(r, h - dy), the integral of the circle areas pi (r^2 - t^2) from t1 to t2:
pi (r^2 (t2 - t1) - (t2^3 - t1^3) / 3) where t2 > t1, else zero (``probes_mri.slab_volume`` is the same formula in
numpy). Computed and summed in float64 whatever the run's precision, so the image is numpy's to rounding (the sums
are taken in another order). The host path it replaces (a copy of the positions, radii and flags, then numpy) took
52 ms a frame for 1e6 grains against this kernel's 6.3 ms, both on one idle CPU thread (benchmarks/mri_frame_cost.py,
2026-12-06, AMD EPYC): ~40 s of a 3.1 s poppy-seed run at a frame every 4 ms.
"""
import math

import taichi as ti

from ..launch import kernel
from .grains import grain_radius


@kernel
def slab_volumes(model: ti.template(), sizes: ti.template(), state: ti.template(), yc: ti.f64, half: ti.f64,
                 x0: ti.f64, z0: ti.f64, dx: ti.f64, dz: ti.f64, out: ti.types.ndarray(dtype=ti.f64, ndim=2)):
    """``out[i, k]`` [m^3]: the volume of the alive grains centred in pixel (i, k) that lies in the slab
    |y - yc| < half [m]; pixels of dx x dz [m] from (x0, z0) [m] (x and z)."""
    for i, k in ti.ndrange(out.shape[0], out.shape[1]):
        out[i, k] = 0.0
    pi = ti.f64(math.pi)  # a bare Python float in a kernel takes the run's precision: float32 rounds pi by 2.8e-8
    for g in range(model.n):
        if state.alive[g]:
            x = ti.cast(state.x[g], ti.f64)
            r = ti.cast(grain_radius(model, sizes, g), ti.f64)
            dy = x[1] - yc
            t1 = ti.max(-r, -half - dy)
            t2 = ti.min(r, half - dy)
            if t2 > t1:
                i = ti.cast(ti.floor((x[0] - x0) / dx), ti.i32)
                k = ti.cast(ti.floor((x[2] - z0) / dz), ti.i32)
                if 0 <= i < out.shape[0] and 0 <= k < out.shape[1]:
                    ti.atomic_add(out[i, k], pi * (r * r * (t2 - t1) - (t2 * t2 * t2 - t1 * t1 * t1) / 3.0))

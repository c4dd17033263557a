"""Inlet schedules: how each velocity inlet blows over time (distributor stages, ramps, a jet).

Owns: the time law of the inlets and the live controls on it (a gas-velocity factor and a
jet switch, used by `fbed view` and by scripts). Plain Python and numpy: it hands a
per-cell velocity profile to the gas solver's ``set_inlet_profile`` before each step.

For a face with a jet, the face cells whose centres lie within ``jet_radius`` of
``jet_center`` blow at ``jet_velocity`` (times the jet's trapezoid in time: opens at
``jet_start``, linear ramps of ``jet_ramp``, closes after ``jet_duration``); the other cells
blow at the inlet velocity times the schedule's fraction. While the jet is closed, its
cells blow like the rest of the distributor.
"""
from __future__ import annotations

import numpy as np

FACE_AXES = {"x": 0, "y": 1, "z": 2}


def fraction_at(spec, t: float) -> float:
    """The inlet's velocity fraction at time t [s]: schedule table, or start + ramp."""
    if spec.schedule:
        times = [float(r[0]) for r in spec.schedule]
        fracs = [float(r[1]) for r in spec.schedule]
        return float(np.interp(t, times, fracs))
    if t < spec.start:
        return 0.0
    if spec.ramp <= 0:
        return 1.0
    return min(1.0, (t - spec.start) / spec.ramp)


def jet_fraction(spec, t: float) -> float:
    """How open the jet is at time t [s], 0..1 (a trapezoid)."""
    if not any(spec.jet_velocity) or t < spec.jet_start:
        return 0.0
    s = t - spec.jet_start
    end = spec.jet_duration if spec.jet_duration > 0 else float("inf")
    if s >= end:
        return 0.0
    if spec.jet_ramp <= 0:
        return 1.0
    return max(0.0, min(1.0, s / spec.jet_ramp, (end - s) / spec.jet_ramp))


def jet_cells(face: str, spec, shape, h: float, origin) -> np.ndarray:
    """Boolean (n1, n2) mask of the face cells that belong to the jet."""
    a = FACE_AXES[face[0]]
    others = [k for k in range(3) if k != a]
    c1 = origin[others[0]] + (np.arange(shape[others[0]]) + 0.5) * h
    c2 = origin[others[1]] + (np.arange(shape[others[1]]) + 0.5) * h
    X1, X2 = np.meshgrid(c1, c2, indexing="ij")
    r2 = (X1 - spec.jet_center[0]) ** 2 + (X2 - spec.jet_center[1]) ** 2
    return r2 <= spec.jet_radius ** 2 * (1 + 1e-9)


class InletSchedule:
    """A before-step hook: sets every scheduled inlet's profile for the coming step.

    Live controls (the viewer's keys call them): ``gas_factor`` scales every inlet's
    velocity; ``jet_enabled`` False keeps the jets shut."""

    def __init__(self, boundary, shape, h: float, origin):
        self.faces = []
        for face, spec in boundary:
            if spec.kind != "velocity_inlet":
                continue
            a = FACE_AXES[face[0]]
            dims = tuple(shape[k] for k in range(3) if k != a)
            mask = jet_cells(face, spec, shape, h, origin) if any(spec.jet_velocity) else None
            if mask is not None and not mask.any():
                raise ValueError(f"boundary.{face}: no face cell centre lies within jet_radius = {spec.jet_radius:g} m "
                                 f"of jet_center {tuple(spec.jet_center)}: raise jet_radius (cells are {h:g} m)")
            self.faces.append((face, spec, dims, mask))
        self.gas_factor = 1.0
        self.jet_enabled = True
        self._last: dict = {}

    @property
    def has_jet(self) -> bool:
        return any(mask is not None for _, _, _, mask in self.faces)

    @property
    def jet_area_cells(self) -> int:
        return int(sum(mask.sum() for _, _, _, mask in self.faces if mask is not None))

    def profile(self, face_index: int, t: float) -> np.ndarray:
        """The (n1, n2, 3) superficial velocity [m/s] of an inlet at time t [s]."""
        face, spec, dims, mask = self.faces[face_index]
        prof = np.empty(dims + (3,))
        prof[...] = np.asarray(spec.velocity) * fraction_at(spec, t) * self.gas_factor
        if mask is not None and self.jet_enabled:
            j = jet_fraction(spec, t)
            if j > 0:
                # the jet replaces the distributor in its cells, ramping between the two
                prof[mask] = (1 - j) * prof[mask] + j * np.asarray(spec.jet_velocity)
        return prof

    def state_key(self, face_index: int, t: float) -> tuple:
        _, spec, _, mask = self.faces[face_index]
        j = jet_fraction(spec, t) if mask is not None and self.jet_enabled else 0.0
        return (fraction_at(spec, t), j, self.gas_factor)

    def __call__(self, sim) -> None:
        t = sim.time + sim.step_dt  # the velocity during the coming step
        for k, (face, _, _, _) in enumerate(self.faces):
            key = self.state_key(k, t)
            if self._last.get(face) == key:
                continue
            self._last[face] = key
            sim.flow.set_inlet_profile(face, self.profile(k, t))

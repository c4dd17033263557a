"""Vessel walls as signed distance functions, shared by the grains and the gas.

Owns: the wall primitives (plane, z-aligned cylinder, grid-sampled SDF), their numpy
twins for host-side work (filling, gas cut-cell apertures, tests), and the Taichi
functions the DEM evaluates per grain.

Convention used everywhere in fbed: a wall's *clearance* at a point is the signed
distance from the wall surface, **positive on the open side** (where grains and gas
live) and negative inside the wall material; its *normal* is the unit gradient of the
clearance, pointing into the open side. A vessel is the intersection of the open
sides of its walls, so its clearance is the minimum over walls. Units: metres.

The list of walls is fixed when a scene is built, so kernels unroll it with
``ti.static`` and each wall keeps its own contact history slot.
"""

import dataclasses
from typing import Sequence

import numpy as np
import taichi as ti

PLANE, CYLINDER, SAMPLED = 0, 1, 2


@dataclasses.dataclass(frozen=True)
class PlaneWall:
    """Half-space wall. ``point`` [m] lies on the surface, ``normal`` points into the open side."""

    point: tuple[float, float, float]
    normal: tuple[float, float, float]
    name: str = "plane"
    kind: int = PLANE

    def clearance(self, p: np.ndarray) -> np.ndarray:
        n = np.asarray(self.normal, float)
        n = n / np.linalg.norm(n)
        return (np.asarray(p, float) - np.asarray(self.point, float)) @ n


@dataclasses.dataclass(frozen=True)
class CylinderWall:
    """Inside of a vertical (z-axis) cylinder of ``radius`` [m] centred at ``center`` (x, y) [m]."""

    center: tuple[float, float]
    radius: float
    name: str = "cylinder"
    kind: int = CYLINDER

    def clearance(self, p: np.ndarray) -> np.ndarray:
        p = np.asarray(p, float)
        r = np.hypot(p[..., 0] - self.center[0], p[..., 1] - self.center[1])
        return self.radius - r


@dataclasses.dataclass(frozen=True, eq=False)
class SampledWall:
    """Clearance sampled at the nodes of a uniform grid (origin [m], spacing [m]); trilinear between nodes.

    Any shape (cone, draft tube, distributor plate) comes free this way. Outside the sampled
    box the nearest node value is used.
    """

    values: np.ndarray  # (nx, ny, nz) clearance [m] at nodes
    origin: tuple[float, float, float]
    spacing: float
    name: str = "sampled"
    kind: int = SAMPLED

    def clearance(self, p: np.ndarray) -> np.ndarray:
        from scipy.ndimage import map_coordinates

        p = np.asarray(p, float)
        idx = [(p[..., a] - self.origin[a]) / self.spacing for a in range(3)]
        shape = p.shape[:-1]
        coords = np.stack([np.clip(i, 0, n - 1).ravel() for i, n in zip(idx, self.values.shape)])
        return map_coordinates(self.values, coords, order=1, mode="nearest").reshape(shape)


Wall = PlaneWall | CylinderWall | SampledWall


def vessel_clearance(walls: Sequence[Wall], p: np.ndarray) -> np.ndarray:
    """Clearance of the vessel (min over walls) at points ``p`` of shape (..., 3) [m]."""
    p = np.asarray(p, float)
    out = np.full(p.shape[:-1], np.inf)
    for w in walls:
        out = np.minimum(out, w.clearance(p))
    return out


def box_walls(lo: Sequence[float], hi: Sequence[float], faces: Sequence[str] = ("x-", "x+", "y-", "y+", "z-", "z+")) -> list[PlaneWall]:
    """Planes of an axis-aligned box [m], normals pointing inwards; ``faces`` picks which to close."""
    walls = []
    for axis, a in enumerate("xyz"):
        for sign in "-+":
            face = a + sign
            if face not in faces:
                continue
            n = [0.0, 0.0, 0.0]
            n[axis] = 1.0 if sign == "-" else -1.0
            pt = [0.0, 0.0, 0.0]
            pt[axis] = lo[axis] if sign == "-" else hi[axis]
            walls.append(PlaneWall(tuple(pt), tuple(n), name=face))
    return walls


def sealed_faces(walls: Sequence[Wall], lo: Sequence[float], hi: Sequence[float]) -> tuple[bool, ...]:
    """Which faces of the domain box [lo, hi] (x-, x+, y-, y+, z-, z+) the walls close to grains: a grain can
    leave the domain there only by passing through a wall. A plane normal to an axis closes the face behind it
    where it lies inside the domain (the floor z-, a lid z+, a box's sides); a cylinder inside the domain the four
    side faces; a sampled vessel each face on which its clearance is nowhere positive (outside the vessel all
    over). Tilted planes close none."""
    sealed = [False] * 6
    for w in walls:
        if isinstance(w, SampledWall):
            for face in range(6):
                sealed[face] |= bool(sampled_face_max(w, lo, hi, face) <= 0.0)
        if isinstance(w, PlaneWall):
            n = np.asarray(w.normal, float) / np.linalg.norm(w.normal)
            axis = int(np.argmax(np.abs(n)))
            if abs(n[axis]) > 1 - 1e-12 and lo[axis] <= w.point[axis] <= hi[axis]:
                sealed[2 * axis + (n[axis] < 0)] = True
        elif isinstance(w, CylinderWall):
            inside = all(lo[a] <= w.center[a] - w.radius and w.center[a] + w.radius <= hi[a] for a in range(2))
            if inside:
                sealed[:4] = [True] * 4
    return tuple(sealed)


def sampled_face_max(w: SampledWall, lo: Sequence[float], hi: Sequence[float], face: int) -> float:
    """The largest clearance of ``w`` on face ``face`` (x-, x+, y-, y+, z-, z+) of the box [lo, hi] [m], exactly:
    on a face the trilinear interpolant (constant beyond the sampled box) is bilinear between the nodes' lines,
    so its largest value lies where those lines or the face's edges cross."""
    axis = face // 2
    marks = []
    for a in range(3):
        if a == axis:
            marks.append(np.array([hi[a] if face % 2 else lo[a]], float))
        else:
            nodes = w.origin[a] + w.spacing * np.arange(w.values.shape[a])
            marks.append(np.concatenate([[lo[a], hi[a]], nodes[(nodes > lo[a]) & (nodes < hi[a])]]))
    return float(w.clearance(np.stack(np.meshgrid(*marks, indexing="ij"), axis=-1)).max())


class SampledWallField:
    """Device copy of a SampledWall's node values (created by the scene, read by kernels)."""

    def __init__(self, wall: SampledWall):
        self.field = ti.field(ti.f32, shape=wall.values.shape)
        self.field.from_numpy(wall.values.astype(np.float32))


@ti.func
def _sampled_clearance(f: ti.template(), origin: ti.template(), spacing: ti.template(), p):
    # trilinear interpolation of node values, clamped to the sampled box
    n = ti.static(f.shape)
    q = (p - ti.Vector(origin)) / spacing
    i0 = ti.Vector([0, 0, 0])
    t = ti.Vector([0.0, 0.0, 0.0])
    for a in ti.static(range(3)):
        qa = ti.min(ti.max(q[a], 0.0), n[a] - 1.000001)
        i0[a] = ti.cast(ti.floor(qa), ti.i32)
        t[a] = qa - i0[a]
    c = 0.0
    for dx, dy, dz in ti.static(ti.ndrange(2, 2, 2)):
        w = (t[0] if dx else 1.0 - t[0]) * (t[1] if dy else 1.0 - t[1]) * (t[2] if dz else 1.0 - t[2])
        c += w * f[i0[0] + dx, i0[1] + dy, i0[2] + dz]
    return c


@ti.func
def wall_clearance_normal(wall: ti.template(), sampled: ti.template(), p):
    """Clearance [m] of one wall at point p and its unit normal (into the open side)."""
    d = 0.0
    nrm = ti.Vector([0.0, 0.0, 1.0])
    if ti.static(wall.kind == PLANE):
        n = ti.Vector(wall.normal).normalized()
        d = (p - ti.Vector(wall.point)).dot(n)
        nrm = n
    elif ti.static(wall.kind == CYLINDER):
        rx = p[0] - wall.center[0]
        ry = p[1] - wall.center[1]
        r = ti.sqrt(rx * rx + ry * ry)
        d = wall.radius - r
        if r > 1e-12:
            nrm = ti.Vector([-rx / r, -ry / r, 0.0])
        else:
            nrm = ti.Vector([1.0, 0.0, 0.0])
    else:
        h = ti.static(wall.spacing)
        d = _sampled_clearance(sampled.field, wall.origin, h, p)
        g = ti.Vector([0.0, 0.0, 0.0])
        for a in ti.static(range(3)):
            e = ti.Vector([0.0, 0.0, 0.0])
            e[a] = 0.5 * h
            g[a] = _sampled_clearance(sampled.field, wall.origin, h, p + e) - _sampled_clearance(
                sampled.field, wall.origin, h, p - e
            )
        gn = g.norm()
        if gn > 1e-12:
            nrm = g / gn
    return d, nrm

"""A packed bed: a settled bed's grain positions and sizes in a few bytes a grain (``fbed pack``: app/pack.py).

A bed carried to another machine is mostly positions: float32 is 12 B a grain, which gzip hardly shrinks (958,000
poppy seeds: 10.9 MB, more than fits beside the GPU kit in one device call). Their order does not matter, and their
precision need not be float32's (4 nm at 5 cm). So each position is rounded to a grid of ``resolution`` [m], the
three integer coordinates are interleaved into one 63-bit Morton code (21 bits an axis), the codes of each size
class are sorted, and the gaps between neighbours are Rice-coded: the low ``bits`` of each gap as they are, the rest
(a small number) as a varint under gzip. A gap is about the code space over the grains, so a grain costs about
log2(V / (N q^3)) + 1.44 bits whatever the bed's arrangement (the entropy of such gaps), plus a little: 5.45 B a
grain for a million grains in the poppy bed's 96 mm x 130 mm at 0.1 um, 4.58 at 0.5 um (benchmarks/RESULTS.md).
A coordinate is off by at most half the resolution.

Kept: the positions [m] (to +-resolution/2 an axis) and the radii [m] (exactly: a radius is a class, unless the bed
has more than 65,535 sizes, when each grain's float32 radius is kept). With a ``speed_resolution`` q [m/s] (a
moving bed, carried to go on): each grain's velocity and its spin's surface speed (omega x radius) to +-q/2 a
component, as integers of q zigzagged to unsigned and Rice-coded per component (a component's spread sets its
bits: about log2(2 e s / q) bits for a Laplace-like spread s). Not kept: the contact history (it starts from zero,
as in ``particles.initial_state``), the grains' order; without a speed_resolution, velocities and spins (a bed at
rest).

Layout (an HDF5 file; attrs ``format`` = FORMAT, time [s], resolution [m], origin [m] (3), grains, source):
  /radius (C,) f8      the classes' radii [m], or (grains,) f4 when there are more than MAX_CLASSES
  /count (C,) i8       grains per class, in the order of /radius (absent when radii are per grain)
  /bits (C,) i8        each class's Rice parameter
  /low (bytes,) u1     each class's gaps' low bits, packed (``bits`` a gap, a class starting on a byte)
  /high (bytes,) u1    every gap's high part (gap >> bits) as a varint (LEB128), class after class
  /motion_bits (6,) i8, /motion_low, /motion_high   (with attr speed_resolution [m/s]) the velocity's x, y, z and the
                       spin's surface speed x, y, z, each a Rice-coded column of zigzagged integers, grains in the
                       order of the positions (class by class, by Morton code)
A class's codes are its gaps summed, the first gap from 0. ``store.write_packed_bed`` writes the file, and
``store.read_checkpoint`` reads it as a bed (position and radius, with velocity and omega where kept), so it serves
as ``particles.initial_state``.
"""
from __future__ import annotations

import h5py
import numpy as np

FORMAT = "fbed packed bed 1"
RESOLUTION = 1.0e-7  # m
BITS = 21  # per axis: the 63-bit code
MAX_CLASSES = 65535


def _spread(v: np.ndarray) -> np.ndarray:
    """The 21 low bits of ``v`` (uint64) moved to every third bit (bit i to bit 3 i)."""
    v = v & np.uint64(0x1FFFFF)
    for shift, mask in ((32, 0x1F00000000FFFF), (16, 0x1F0000FF0000FF), (8, 0x100F00F00F00F00F),
                        (4, 0x10C30C30C30C30C3), (2, 0x1249249249249249)):
        v = (v | (v << np.uint64(shift))) & np.uint64(mask)
    return v


def _gather(v: np.ndarray) -> np.ndarray:
    """The inverse of :func:`_spread`: every third bit of ``v`` back into 21 low bits."""
    v = v & np.uint64(0x1249249249249249)
    for shift, mask in ((2, 0x10C30C30C30C30C3), (4, 0x100F00F00F00F00F), (8, 0x1F0000FF0000FF),
                        (16, 0x1F00000000FFFF), (32, 0x1FFFFF)):
        v = (v | (v >> np.uint64(shift))) & np.uint64(mask)
    return v


def morton(q: np.ndarray) -> np.ndarray:
    """Codes of integer coordinates ``q`` (n, 3), each in [0, 2^21): x in bit 3 i + 2, y in 3 i + 1, z in 3 i."""
    q = q.astype(np.uint64)
    return (_spread(q[:, 0]) << np.uint64(2)) | (_spread(q[:, 1]) << np.uint64(1)) | _spread(q[:, 2])


def unmorton(code: np.ndarray) -> np.ndarray:
    return np.stack([_gather(code >> np.uint64(2)), _gather(code >> np.uint64(1)), _gather(code)], axis=1)


def varints(v: np.ndarray) -> np.ndarray:
    """LEB128: each uint64 as 7-bit groups, lowest first, the high bit set on all but a value's last byte."""
    v = v.astype(np.uint64)
    n = np.ones(v.size, np.int64)
    for k in range(1, 10):
        n += v >= np.uint64(1) << np.uint64(7 * k)
    start = np.concatenate([[0], np.cumsum(n)[:-1]])
    which = np.repeat(np.arange(v.size), n)
    k = np.arange(int(n.sum())) - start[which]
    out = ((v[which] >> (np.uint64(7) * k.astype(np.uint64))) & np.uint64(0x7F)).astype(np.uint8)
    out[k < n[which] - 1] |= 0x80
    return out


def unvarints(b: np.ndarray) -> np.ndarray:
    """The inverse of :func:`varints`."""
    if b.size == 0:
        return np.zeros(0, np.uint64)
    last = b < 0x80
    start = np.concatenate([[0], np.nonzero(last)[0][:-1] + 1])
    which = np.cumsum(np.concatenate([[0], last[:-1]]))
    k = (np.arange(b.size) - start[which]).astype(np.uint64)
    return np.add.reduceat((b & 0x7F).astype(np.uint64) << (np.uint64(7) * k), start)


def rice(gaps: np.ndarray, bits: int) -> tuple[np.ndarray, np.ndarray]:
    """Rice code of ``gaps`` (uint64) with ``bits`` low bits: (the low bits packed, ``bits`` a gap, as bytes; the high
    parts, gap >> bits: small numbers, written as varints that gzip shrinks to about two bits each)."""
    low = gaps & np.uint64((1 << bits) - 1)
    k = np.arange(bits, dtype=np.uint64)
    return np.packbits(((low[:, None] >> k[None, :]) & np.uint64(1)).astype(np.uint8).ravel()), gaps >> np.uint64(bits)


def unrice(low: np.ndarray, high: np.ndarray, bits: int, n: int) -> np.ndarray:
    """The inverse of :func:`rice`: ``n`` gaps from their packed low bits and their high parts (uint64)."""
    bitmat = np.unpackbits(low, count=n * bits).reshape(n, bits).astype(np.uint64)
    k = np.arange(bits, dtype=np.uint64)
    return (high << np.uint64(bits)) | (bitmat << k[None, :]).sum(1, dtype=np.uint64)


def rice_bits(gaps: np.ndarray) -> int:
    """The Rice parameter for gaps of a geometric-like spread: log2 of their mean x ln 2, rounded down."""
    return int(np.clip(np.floor(np.log2(max(float(np.mean(gaps)) * np.log(2), 1.0))), 0, 63)) if gaps.size else 0


def rice_groups(groups) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each group of unsigned values Rice-coded with its own parameter: (the low bits, each group starting on a
    byte; every high part as a varint, group after group; the parameters)."""
    low, high, bits = [], [], []
    for g in groups:
        bits.append(rice_bits(g))
        lo_, hi_ = rice(g, bits[-1])
        low.append(lo_)
        high.append(hi_)
    return np.concatenate(low), varints(np.concatenate(high)), np.asarray(bits, np.int64)


def unrice_groups(low: np.ndarray, high: np.ndarray, bits, counts) -> list[np.ndarray]:
    """The inverse of :func:`rice_groups`, given each group's size (``high``: the varint bytes)."""
    high, low, out, at, start = unvarints(np.asarray(high, np.uint8)), np.asarray(low, np.uint8), [], 0, 0
    if high.size != int(np.sum(counts)):
        raise ValueError(f"{high.size} values for groups of {int(np.sum(counts))}")
    for n, b in zip((int(c) for c in counts), (int(b) for b in bits)):
        nbytes = (n * b + 7) // 8
        out.append(unrice(low[at:at + nbytes], high[start:start + n], b, n))
        at, start = at + nbytes, start + n
    return out


def zigzag(q: np.ndarray) -> np.ndarray:
    """Signed integers as unsigned ones, small magnitudes small: 0, -1, 1, -2, 2 ... -> 0, 1, 2, 3, 4 ..."""
    q = np.asarray(q, np.int64)
    return ((q << np.int64(1)) ^ (q >> np.int64(63))).astype(np.uint64)


def unzigzag(z: np.ndarray) -> np.ndarray:
    z = np.asarray(z, np.uint64)
    return (z >> np.uint64(1)).astype(np.int64) ^ -(z & np.uint64(1)).astype(np.int64)


#: the largest speed [m/s] a speed_resolution may code, in units of it (2^52: every such integer a float64)
MAX_SPEED_STEPS = float(1 << 52)


def _pack_motion(motion: np.ndarray, q: float) -> dict:
    """The (n, 6) velocities and spin surface speeds [m/s], to +-q/2, as Rice-coded columns (the layout's motion_*)."""
    steps = np.rint(motion / q)
    if not np.all(np.abs(steps) <= MAX_SPEED_STEPS):
        raise ValueError(f"a speed of {float(np.abs(motion).max()):.3g} m/s is beyond 2^52 steps of {q:g} m/s")
    low, high, bits = rice_groups(zigzag(steps.astype(np.int64)).T)
    return {"motion_low": low, "motion_high": high, "motion_bits": bits}


def _unpack_motion(arrays: dict, n: int, q: float) -> np.ndarray:
    columns = unrice_groups(arrays["motion_low"], arrays["motion_high"], arrays["motion_bits"], [n] * 6)
    return np.stack([unzigzag(c) * q for c in columns], axis=1)


def pack(position: np.ndarray, radius: np.ndarray, resolution: float = RESOLUTION, velocity=None, omega=None,
         speed_resolution: float = 0.0) -> tuple[dict, dict]:
    """(arrays, attrs) of a packed bed (the module's layout). The resolution is raised where the bed is taller or
    wider than 2^21 of it (attrs hold the one used). With ``speed_resolution`` [m/s] > 0, ``velocity`` [m/s] and
    ``omega`` [rad/s] (each (n, 3), or None for zeros) are kept to it."""
    x = np.asarray(position, np.float64)
    if x.ndim != 2 or x.shape[1] != 3 or len(radius) != len(x) or not np.all(np.isfinite(x)):
        raise ValueError(f"positions of shape {x.shape} and {len(radius)} radii: not a bed of finite positions")
    lo = x.min(0) if len(x) else np.zeros(3)
    extent = float((x.max(0) - lo).max()) if len(x) else 0.0
    res = max(float(resolution), extent / ((1 << BITS) - 1))
    q = np.minimum(np.rint((x - lo) / res), (1 << BITS) - 1).astype(np.uint64)
    sizes, cls = np.unique(np.asarray(radius), return_inverse=True)
    per_grain = sizes.size > MAX_CLASSES
    if per_grain:
        sizes, cls = np.asarray(radius, np.float32), np.zeros(len(x), np.int64)
    codes = morton(q)
    order = np.lexsort((codes, cls))
    codes, cls = codes[order], cls[order]
    count = np.bincount(cls, minlength=1 if per_grain else sizes.size).astype(np.int64)
    bounds = np.concatenate([[0], np.cumsum(count)])
    # each class's codes as gaps, the first from 0, Rice-coded
    low, high, bits = rice_groups(np.diff(codes[a:b], prepend=np.uint64(0)) for a, b in zip(bounds[:-1], bounds[1:]))
    arrays = {"low": low, "high": high, "bits": bits, "radius": sizes[order] if per_grain else sizes}
    if not per_grain:
        arrays["count"] = count
    attrs = {"format": FORMAT, "resolution": res, "origin": lo, "grains": len(x)}
    if speed_resolution > 0:
        zero = np.zeros_like(x)
        v = zero if velocity is None else np.asarray(velocity, np.float64)
        spin = zero if omega is None else np.asarray(omega, np.float64) * np.asarray(radius, np.float64)[:, None]
        arrays.update(_pack_motion(np.concatenate([v, spin], axis=1)[order], float(speed_resolution)))
        attrs["speed_resolution"] = float(speed_resolution)
    return arrays, attrs


def unpack(arrays: dict, attrs: dict) -> dict:
    """{"position": (n, 3) f8 [m], "radius": (n,) f8 [m]} of a packed bed, with "velocity" [m/s] and "omega"
    [rad/s] (n, 3) where it kept them."""
    n = int(attrs["grains"])
    if "count" in arrays:
        count = np.asarray(arrays["count"], np.int64)
        radius = np.repeat(np.asarray(arrays["radius"], np.float64), count)
    else:
        radius, count = np.asarray(arrays["radius"], np.float64), np.array([n], np.int64)
    if int(count.sum()) != n:
        raise ValueError(f"classes of {int(count.sum())} grains for {n} grains")
    gaps = unrice_groups(arrays["low"], arrays["high"], arrays["bits"], count)
    codes = np.concatenate([np.cumsum(g, dtype=np.uint64) for g in gaps]) if n else np.zeros(0, np.uint64)
    x = np.asarray(attrs["origin"], np.float64) + unmorton(codes).astype(np.float64) * float(attrs["resolution"])
    out = {"position": x, "radius": radius}
    if "motion_bits" in arrays:
        motion = _unpack_motion(arrays, n, float(attrs["speed_resolution"]))
        out.update(velocity=motion[:, :3], omega=motion[:, 3:] / radius[:, None])
    return out


def is_packed(f: h5py.File) -> bool:
    return f.attrs.get("format") == FORMAT


def read(f: h5py.File) -> tuple[dict, dict]:
    """(grains, attrs) of an open packed bed."""
    attrs = dict(f.attrs)
    return unpack({k: f[k][...] for k in f}, attrs), attrs


def fill(f: h5py.File, arrays: dict, attrs: dict) -> None:
    """Write :func:`pack`'s arrays and attrs into an open, empty file (``store.write_packed_bed`` writes it whole)."""
    for k, v in arrays.items():
        raw = k in ("low", "motion_low") or v.size <= 1024  # low bits are as good as random: gzip gains nothing
        f.create_dataset(k, data=v, **({} if raw else {"compression": "gzip", "compression_opts": 9}))
    f.attrs.update(attrs)

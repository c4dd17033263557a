"""Several runs of one case pooled as realisations of one operating point (`fbed analyze RUN RUN ... --out DIR`).

Owns: the check that the runs are one case. A million-grain law of the MRI study does not fit one GPU session; its
sessions go on from each other's packed end states (``fbed pack --speed-resolution``: the contact history and the
gas start afresh), so they are not one trajectory but realisations of one steady bed, and their analysed windows
can be pooled. Pooled only where the runs share every key that sets the physics, the numerics and the images; the
keys of how a session starts and what else it records may differ (``SESSION``), and the inlet is compared by what
it blows over each run's analysed window, not by its schedule (the first session ramps it, the next start at full
speed). Plain Python, no Taichi.
"""
from __future__ import annotations

import dataclasses
import pathlib

from ..config import ConfigError

#: keys of how a session starts, how long it runs and what else it writes: they may differ between pooled runs
SESSION = ("run.duration", "run.start_from", "run.name", "run.seed", "run.threads", "particles.initial_state",
           "particles.count", "particles.bed_height", "particles.fill_solid_fraction", "particles.fill_spacing",
           "output.", "video.", "guard.", "probes.rcfd_", "probes.planes", "probes.planes_interval",
           "probes.volume_interval")  # a name ending in '.' or '_' is a prefix
#: an inlet's time law: compared over the analysed windows instead (``window_fraction``)
INLET_LAW = ("schedule", "start", "ramp")


def spans(nf: int, segments=None) -> list[tuple[int, int]]:
    """The (first, end) frames of each segment of a record of ``nf`` frames pooled from several runs, ``segments``
    their first frames (None: one segment, the whole record)."""
    starts = sorted({0, *(int(s) for s in (segments if segments is not None else ()) if 0 < s < nf)})
    return list(zip(starts, starts[1:] + [nf]))


def flat(cfg) -> dict:
    """'section.key' (boundary faces as 'boundary.FACE.key') -> value of a loaded config."""
    out = {}
    for f in dataclasses.fields(cfg):
        if f.metadata.get("internal"):
            continue
        v = getattr(cfg, f.name)
        if f.name == "boundary":
            for face, spec in v:
                out |= {f"boundary.{face}.{k}": x for k, x in dataclasses.asdict(spec).items()}
        elif dataclasses.is_dataclass(v):
            out |= {f"{f.name}.{k}": x for k, x in dataclasses.asdict(v).items()}
        else:
            out[f.name] = v
    return out


def window_fraction(spec, t0: float, t1: float) -> float | None:
    """The inlet's velocity fraction over [t0, t1] [s] where it holds one value there (None where it changes)."""
    from ..schedule import fraction_at

    ts = [t0, t1] + [float(r[0]) for r in spec.schedule if t0 < float(r[0]) < t1]
    if not spec.schedule:
        ts += [t for t in (spec.start, spec.start + spec.ramp) if t0 < t < t1]
    vals = [fraction_at(spec, t) for t in ts]
    return vals[0] if max(vals) - min(vals) <= 1e-12 else None


def _session_key(key: str) -> bool:
    return any(key.startswith(s) if s.endswith((".", "_")) else key == s for s in SESSION)


def _inlet_law(key: str) -> bool:
    return key.startswith("boundary.") and key.rsplit(".", 1)[1] in INLET_LAW


def check_same_case(run_dirs: list[pathlib.Path], windows: list[tuple[float, float]], cfgs=None) -> list[str]:
    """Raise ConfigError naming the first key that makes the runs different cases (or an inlet that changes within
    an analysed window [s]); return notes on the session keys that differ (they are allowed). ``cfgs``: the runs'
    loaded config.toml, where the caller has them."""
    from .. import config as cfgmod

    cfgs = cfgs if cfgs is not None else [cfgmod.load(d / "config.toml") for d in run_dirs]
    flats = [flat(c) for c in cfgs]
    first, notes = flats[0], []
    for d, c, fl, (t0, t1) in zip(run_dirs, cfgs, flats, windows):
        for face, spec in c.boundary:
            if spec.kind == "velocity_inlet" and window_fraction(spec, t0, t1) is None:
                raise ConfigError(f"the inlet changes during the analysed window {t0:g}-{t1:g} s of this run, so its "
                                  "frames are not one operating point", str(d / "config.toml"),
                                  f"boundary.{face}.schedule", hint="start the window after the ramp "
                                  "(output.average_from) and analyse it again, or leave the run out")
        for key in sorted(set(first) | set(fl)):
            a, b = first.get(key), fl.get(key)
            law = _inlet_law(key)
            if law:
                face = key.split(".")[1]
                spec0, spec = dict(cfgs[0].boundary).get(face), dict(c.boundary).get(face)
                if spec0 is None or spec is None:
                    continue  # the face itself differs: its kind is compared below
                raw = a != b
                a = window_fraction(spec0, *windows[0]) if spec0.kind == "velocity_inlet" else a
                b = window_fraction(spec, t0, t1) if spec.kind == "velocity_inlet" else b
                if raw and a == b:
                    notes.append(f"{key}: differs in {d}, but the inlet blows {a!r} of its velocity over both windows")
            if a == b:
                continue
            if _session_key(key):
                notes.append(f"{key}: {a!r} in {run_dirs[0]}, {b!r} in {d}")
                continue
            what = "the inlet's fraction over the analysed window" if law else "the value"
            raise ConfigError(f"these runs are not one case: {what} is {a!r} in {run_dirs[0]} and {b!r} here",
                              str(d / "config.toml"), key, hint="pool only sessions of one case (the same preset "
                              "and overrides; how each session starts, how long it runs and what else it records "
                              "may differ); compare different cases with `fbed sweep` and `fbed analyze SWEEP_DIR`")
    return notes


def keys_that_differ(cfgs) -> list[str]:
    """The case keys (not ``SESSION``'s, not an inlet's time law) whose values differ between the configs: what
    tells cases apart in a side-by-side table."""
    flats = [flat(c) for c in cfgs]
    keys = sorted(set().union(*flats))
    return [k for k in keys if not _session_key(k) and not _inlet_law(k) and len({repr(f.get(k)) for f in flats}) > 1]

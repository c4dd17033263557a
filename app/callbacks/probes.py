"""Probe attachment: the [probes] records (slab, planes, volume, MRI; the rCFD frames) a run asks for."""
from __future__ import annotations

from ..probes import Probes
from ..rcfd_probe import RcfdRecorder


def attach_probes(sim, cfg, runfile, out_dir, guard, resume_time, notify, checkpoints=None, parts=None) -> None:
    """Attach what [probes] asks for, each record behind the guard. ``resume_time``: the time a resumed run
    continues from (None for a fresh run), for the rCFD recorder's file; ``checkpoints``: the run's checkpoint
    writer, which saves the recorder's open frame (its part), and ``parts``: the parts of the checkpoint resumed."""
    pr = cfg.probes
    flow = sim.flow
    if flow is not None and (pr.slab_interval or pr.planes_interval or pr.volume_interval or pr.mri_interval):
        Probes(cfg, flow, flow.fields.active.to_numpy()).attach(sim, runfile, guard.guarded)
    if sim.coupler is not None and pr.rcfd_from >= 0:
        v = cfg.vessel
        axis = v.center if v.shape == "cylinder" else tuple(0.5 * (a + b) for a, b in zip(cfg.domain.lo[:2],
                                                                                         cfg.domain.hi[:2]))
        rec = RcfdRecorder(cfg, axis)
        rec.attach(sim, out_dir, guard.guarded, resume_time, notify, (parts or {}).get(rec.PART))
        if checkpoints is not None:
            checkpoints.parts[rec.PART] = rec.saved

"""The summary: summary.json (what ran, how it ended, its cost and split, its last diagnostics, the bed's
figures) and summary_units.json, written when a run ends."""
from __future__ import annotations

from ..io import store
from ..scene import device_bytes
from ..sim import runtime
from ..sim.fields import bytes_per_grain
from ..postprocess import post_process
from ..provenance import code_id
from .writers import DEM_SERIES, GAS_SERIES, write_xdmf

UNITS = {"time": "s", "wall_time": "s", "dem_dt": "s", "collision_time": "s", "rayleigh_time": "s",
         "bed_height": "m", "kinetic_energy": "J", "particle_substeps_per_s": "1/s", "bytes_per_grain": "B",
         "device_memory": "B", "gpu_memory": "B",
         "gas_cell_size": "m", "gas_max_speed": "m/s", "steps_per_s": "1/s", "bed_weight_per_area": "Pa",
         "bed_area": "m^2",
         "mean_pressure_drop": "Pa", "mean_bed_height": "m", "pressure_drop_over_weight": "1", "average_from": "s",
         "render_time": "s", "render_share": "1", "unstable_at": "s", "last_good_time": "s"}


class Summary:
    """Collects a run's figures at its end. ``start_step``: the step this process started from (its rates
    count the steps it made); ``bed``: BedMeasures of a coupled run; ``video``: VideoFrames, or None."""

    def __init__(self, scene, name: str, arch: str, out_dir, start_step: int, renderer=None, video=None, bed=None):
        self.scene, self.name, self.arch, self.out_dir = scene, name, arch, out_dir
        self.start_step, self.renderer, self.video, self.bed = start_step, renderer, video, bed

    def figures(self, sim, status: str, message: str, wall: float) -> dict:
        cfg, der, scene = self.scene.cfg, self.scene.derived, self.scene
        steps_here = max(1, sim.step_count - self.start_step)
        rate = 1.0 / max(sim.wall_elapsed, 1e-9)
        out = {"preset": self.name, "status": status, "message": message, "arch": self.arch,
               "precision": cfg.run.precision, "time": sim.time, "steps": sim.step_count,
               "duration": cfg.run.duration, "wall_time": wall, "steps_per_s": steps_here * rate,
               "fbed_version": store.VERSION, "fbed_code": code_id()}  # the code that ran it (app/provenance.py)
        if sim.dem is not None:
            out.update({"grains": scene.n, "dem_dt": der.dt, "substeps_per_step": der.substeps,
                        "collision_time": der.collision_time, "rayleigh_time": der.rayleigh_time,
                        "neighbor_slots": scene.model.slots,
                        "bytes_per_grain": bytes_per_grain(scene.model, 8 if cfg.run.precision == "float64" else 4),
                        "particle_substeps_per_s": scene.n * der.substeps * steps_here * rate,
                        "neighbor_rebuilds": sim.dem.nlist.builds})
        out["device_memory"] = device_bytes(scene)
        if self.arch == "cuda":  # the GPU's memory as the start-up's memory check read it (libcuda)
            out["gpu_memory"] = runtime.cuda_memory()
        if sim.flow is not None:
            out.update({"gas_cells": list(scene.flow.shape), "gas_cell_size": cfg.gas.cell_size,
                        "gas_split_peak": sim.gas_split_peak, "gas_split_changes": sim.gas_split_changes})
        split = sim.wall_split()  # coupling, gas and DEM sampled on every 25th step; callbacks on all
        if split:
            total = sum(split.values())
            out["wall_split"] = {k: round(v, 3) for k, v in split.items()}
            out["wall_split_share"] = {k: round(v / total, 4) for k, v in split.items()}
        if self.renderer is not None:
            r = self.renderer
            out.update({"frames": r.frames, "render_time": r.render_seconds,
                        "render_share": r.render_seconds / max(wall, 1e-9)})
            if self.video is not None:
                w = self.video.writer  # video_frames: the file's, with those kept from before a resume
                out.update({"video": str(w.path), "video_encoder": w.encoder, "video_frames": w.frames})
        if self.bed is not None:  # also for a guard stop: `fbed analyze` of its data needs the bed weight
            out.update(self.bed.summary(self.out_dir / "run.h5", cfg))
        d = sim.diagnostics() if status not in ("unstable", "disk_full") else {}
        out.update({k: d[k] for k in DEM_SERIES + GAS_SERIES if k in d})
        if status in ("unstable", "disk_full") and (self.out_dir / "checkpoint.h5").exists():
            out["last_good_checkpoint"] = str(self.out_dir / "checkpoint.h5")
        return out

    def write(self, figures: dict, analyze: bool = True) -> None:
        """summary.json; then (``analyze``: the run finished or was interrupted) the preset's analysis, whose key
        figures join it; summary_units.json and the ParaView indexes (bed.xdmf too)."""
        store.write_json(self.out_dir / "summary.json", figures)
        kind = self.scene.cfg.probes.analysis
        if kind != "none" and analyze:
            figures.update(post_process(kind, self.out_dir))  # it reads the summary written above
            store.write_json(self.out_dir / "summary.json", figures)
        store.write_json(self.out_dir / "summary_units.json", UNITS)
        write_xdmf(self.out_dir)

"""Going on from an earlier state: `fbed run --resume` (its checks: the same scene, readable files; the gas and
coupler restored) and run.start_from (the preparation preset run once and cached, its state the start)."""
from __future__ import annotations

import dataclasses
import fcntl
import hashlib
import json
import pathlib

import h5py

from . import config as cfgmod
from .callbacks.progress import log
from .config import ConfigError
from .io.store import SPLIT_KEY
from .provenance import code_id


def prepared_state(cfg, preset_path: pathlib.Path, arch: str, runner, chain: tuple = ()) -> pathlib.Path:
    """The checkpoint of ``run.start_from``'s preparation preset: reused from the cache
    (runs/prepared/<name>-<hash of its resolved config>-<fbed's code fingerprint>/) when it holds a finished run,
    else run there now. The hash covers the preparation's own chain, so editing any stage
    reruns it and everything after it; the fingerprint (app.provenance) makes a bed prepared by other fbed code
    be prepared again, not reused as this code's. ``runner``: ``app.run.run`` (given, so this module needs no
    import of the runner that imports it)."""
    prep = cfgmod.resolve_path(cfg, cfg.run.start_from)
    if not prep.exists():
        raise ConfigError("preparation preset not found", str(prep), "run.start_from",
                          hint=f"a path relative to {preset_path.name}'s folder")
    if prep.resolve() in chain:
        raise ConfigError("run.start_from chain loops back on itself", str(prep), "run.start_from")
    prep_cfg = cfgmod.load(prep, [])
    text = cfgmod.dump(prep_cfg)
    if prep_cfg.run.start_from:  # its own preparation's identity is part of its identity
        text += str(prepared_state(prep_cfg, prep, arch, runner, chain + (prep.resolve(),)))
    key = hashlib.sha1(text.encode()).hexdigest()[:10]
    cache = pathlib.Path("runs") / "prepared" / f"{prep.stem}-{key}-{code_id()[:8]}"
    older = [p for p in cache.parent.glob(f"{prep.stem}-{key}-*") if p != cache and (p / "checkpoint.h5").is_file()]
    if older and not cache.exists():
        last = max(older, key=lambda p: p.stat().st_mtime)
        log(f"fbed: note: {last} holds {prep.name} as other fbed code prepared it; the code has changed since, so it "
            f"is prepared again. To start from its grains anyway: --set particles.initial_state={last}/checkpoint.h5 "
            "--set run.start_from=''")
    # one process prepares at a time (sweep cases start together): the others wait for it, then reuse its result
    locks = cache.parent / ".locks"
    locks.mkdir(parents=True, exist_ok=True)
    with open(locks / (cache.name + ".lock"), "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        return _prepare(prep, cache, arch, runner)


def _prepare(prep: pathlib.Path, cache: pathlib.Path, arch: str, runner) -> pathlib.Path:
    summary = cache / "summary.json"
    status = None  # of the cached preparation: None when there is none to go on from
    if (cache / "checkpoint.h5").exists() and (cache / "config.toml").exists():
        try:  # no summary: the preparation was killed after a checkpoint
            status = json.loads(summary.read_text()).get("status") if summary.exists() else "killed"
        except ValueError:
            status = "killed"
    if status == "finished":
        log(f"fbed: starting from the prepared state in {cache} ({prep.name}, reused)")
        return cache / "checkpoint.h5"
    if status in ("interrupted", "killed"):  # a stopped preparation goes on from its checkpoint
        log(f"fbed: resuming the preparation {prep.name} in {cache} (it was {status})")
        rc = runner(None, [], arch=arch, resume=str(cache))
    else:
        log(f"fbed: preparing {prep.name} first (cached in {cache} for later runs)")
        rc = runner(str(prep), [], out=str(cache), arch=arch, overwrite=True)
    if rc != 0:
        raise ConfigError(f"the preparation run did not finish (exit {rc}); see {cache}", str(prep), "run.start_from")
    return cache / "checkpoint.h5"


def restore_gas(flow, coupler, gas_arrays: dict) -> None:
    """Load a checkpoint's gas group: the gas solver's arrays and, under the coupling_ prefix, the coupler's."""
    flow.load_state_arrays(gas_arrays)
    if coupler is not None:
        coupler.load_state_arrays({k[len("coupling_"):]: v for k, v in gas_arrays.items()
                                   if k.startswith("coupling_")})


def restore(sim, scene, arrays, gas_arrays, meta, prepared: bool, resume_dir) -> None:
    """A prepared or resumed run's gas, coupler and clock (its grains came with the Scene: ``arrays``, the
    checkpoint's, must be there when the scene has grains). ``resume_dir``: the run folder resumed, or None."""
    cfg, ckpt = scene.cfg, (resume_dir / "checkpoint.h5" if resume_dir else None)
    if resume_dir and scene.model is not None and arrays is None:
        raise ConfigError("the checkpoint does not hold this preset's grains", str(ckpt), "--resume",
                          hint="resume with the run's own config.toml")
    if prepared:
        load_prepared(cfg, sim, sim.flow, sim.coupler, gas_arrays, meta)
        sim.fresh = True
    if not resume_dir:
        return
    if str(meta.get("fbed_code", code_id())) != code_id():  # (a checkpoint from before it was kept says nothing)
        log(f"fbed: note: {ckpt} was written by other fbed code ({meta['fbed_code']}; this is {code_id()}): the run "
            "goes on from it, but not bit for bit as the run would have gone on under the code that began it")
    if sim.flow is not None:
        if gas_arrays is None:
            raise ConfigError("the checkpoint holds no gas state", str(ckpt), "--resume",
                              hint="resume with the run's own config.toml")
        restore_gas(sim.flow, sim.coupler, gas_arrays)
        if SPLIT_KEY in gas_arrays:  # (a checkpoint from before it was kept: the steps start whole, as they did)
            sim.gas_split, sim.gas_split_peak, sim.gas_split_changes = map(int, gas_arrays[SPLIT_KEY])
            sim.gas_split = min(sim.gas_split, sim.max_gas_split)  # (gas.max_split may be lowered on a resume)
    sim.step_count = int(meta["step"])
    sim.fresh = False  # its start was recorded by the run it continues (even one stopped at step 0)
    if sim.step_count >= sim.total_steps:
        log(f"{resume_dir}: already at t = {sim.time:g} s >= run.duration; extend it with --set run.duration=...")


def load_prepared(cfg, sim, flow, coupler, gas_arrays, meta) -> None:
    """Start from a prepared state: its gas (when it has one) and its clock (its grains, with their full contact
    state when the models match, were placed by build_simulation from the Scene's initial grains)."""
    t = float(meta["time"])
    steps = t / cfg.run.step
    if abs(steps - round(steps)) > 1e-6:
        raise ConfigError(f"the prepared state's time {t:g} s is not a whole number of steps of {cfg.run.step:g} s",
                          cfg.source or "", "run.step", hint="use the preparation preset's run.step")
    if flow is not None and gas_arrays is not None:
        restore_gas(flow, coupler, gas_arrays)
    sim.step_count = int(round(steps))
    if sim.step_count >= sim.total_steps:
        raise ConfigError(f"the prepared state is at t = {t:g} s, past run.duration = {cfg.run.duration:g} s",
                          cfg.source or "", "run.duration", hint="run.duration is the end time: raise it")


# what a resumed run may change: its end, its outputs, its checks, its machine, and the knobs the guard names when
# it stops a run (the DEM step's settings, the pressure solve's and the adaptive fluid step's: no state depends on
# them, so a run stopped unstable goes on from its last good checkpoint with them turned); everything else (the
# vessel, the grains, the contact model, the gas grid, run.step) must be the run's own, or the checkpoint means nothing
RESUME_FREE = {"run": {"duration", "name", "threads", "precision", "start_from"},
               "dem": {"dt", "dt_fraction", "max_dt_fraction", "force_dt", "impact_speed"},
               "gas": {"tolerance", "max_iterations", "max_viscous_sweeps", "max_cfl", "max_split"},
               "output": None, "video": None, "guard": None, "probes": None, "boundary": None}


def resume_free() -> str:
    """What a resume may change, in words, from :data:`RESUME_FREE` (the hint named run.duration alone of [run])."""
    keys = [f"{name}.{k}" for name, free in RESUME_FREE.items() if free for k in sorted(free) if k != "start_from"]
    sections = [f"[{name}]" for name, free in RESUME_FREE.items() if free is None]
    return ", ".join(keys + sections[:-1]) + f" and {sections[-1]}"


def _flat(cfg) -> dict:
    out = {}
    for name, section in cfgmod.loader.sections_of(cfg).items():
        free = RESUME_FREE.get(name, set())
        if free is None:
            continue
        out[f"[{name}]"] = "absent" if section is None else "present"
        if section is None:
            continue
        for f in dataclasses.fields(section):
            if f.name in free:
                continue
            v = getattr(section, f.name)
            if f.name in ("initial_state", "sdf_file") and v:
                v = str(cfgmod.resolve_path(cfg, v).resolve())
            out[f"{name}.{f.name}"] = v
    return out


def check_same_scene(cfg, run_cfg, preset_path: pathlib.Path, out_dir: pathlib.Path) -> None:
    """Refuse to resume a run with a preset (or --set) whose scene differs from the run's config.toml."""
    a, b = _flat(cfg), _flat(run_cfg)
    diff = [k for k in sorted(set(a) | set(b)) if a.get(k) != b.get(k)]
    whole = {k[1:-1] for k in diff if k.startswith("[")}  # a section one side lacks: named once, not key by key
    diff = [k for k in diff if k.startswith("[") or k.split(".")[0] not in whole]
    if diff:
        names = ", ".join(diff[:12]) + (f" and {len(diff) - 12} more" if len(diff) > 12 else "")
        values = "; ".join(f"{k}: {a.get(k, 'absent')!s:.30} here, {b.get(k, 'absent')!s:.30} in the run"
                           for k in diff[:3])
        raise ConfigError(f"this preset's scene differs from the run's in {names} ({values})", str(preset_path),
                          "--resume", hint=f"resume with the run's own settings (fbed run --resume {out_dir}); a "
                          f"resume may change only {resume_free()}")


#: run.h5's frame records and the [probes] keys that shape their frames: a resume that changed one would append
#: frames of another layout (a changed probes.mri_pixel had HDF5 cut the earlier MRI frames to the new pixel count)
RECORD_KEYS = {"mri": ("mri_pixel", "slab_width"), "slab": ("slab_width",)}


def check_records(cfg, run_cfg, out_dir: pathlib.Path) -> None:
    """Refuse a resume that changes a key of :data:`RECORD_KEYS` from the run's (``run_cfg``) while run.h5 holds
    frames of that record."""
    path = out_dir / "run.h5"
    if not path.exists():
        return
    with h5py.File(path, "r") as f:
        held = [g for g in RECORD_KEYS if g in f and "time" in f[g] and f[g]["time"].shape[0]]
    for g in held:
        for k in RECORD_KEYS[g]:
            here, there = json.dumps(getattr(cfg.probes, k)), json.dumps(getattr(run_cfg.probes, k))
            if here != there:
                raise ConfigError(f"probes.{k} = {here} here, {there} in the run, whose /{g} frames are made with it",
                                  str(path), f"probes.{k}", hint=f"resume with probes.{k} = {there} (drop the --set); "
                                  "frames of another layout need a new run (--out)")


def check_recording(cfg, out_dir: pathlib.Path) -> None:
    """Refuse a resume whose rCFD recording settings ([probes] rcfd_*) differ from those rcfd.h5 was recorded with:
    its frames would be appended to the file as if they were of one kind (a changed probes.rcfd_interval gave
    10 ms frames in a file that says 5 ms). A file from before the settings were kept is checked on what it says:
    its start, frame interval, tag and whether it holds fluxes."""
    path = out_dir / "rcfd.h5"
    if cfg.probes.rcfd_from < 0 or not path.exists():
        return
    from .config.derived import interval_steps
    from .rcfd.database import recording_settings

    now = recording_settings(cfg)
    with h5py.File(path, "r") as f:
        a = f.attrs
        if "settings" in a:
            was = json.loads(a["settings"])
        else:
            was = {"rcfd_from": float(a["rcfd_from"]), "rcfd_tag": str(a["tag"]), "rcfd_fluxes": "frame/flux_x" in f}
            now["rcfd_interval"] = interval_steps(now["rcfd_interval"], cfg.run.step) * cfg.run.step
            was["rcfd_interval"] = float(a["frame_interval"])
    diff = [k for k in now if k in was and (abs(now[k] - was[k]) > 1e-12 * abs(was[k])
                                            if isinstance(was[k], float) else now[k] != was[k])]
    if diff:
        k, here, there = diff[0], json.dumps(now[diff[0]]), json.dumps(was[diff[0]])  # as TOML writes them
        raise ConfigError(f"probes.{k} = {here} here, {there} in the recording this run appends to",
                          str(path), f"probes.{k}", hint=f"resume with probes.{k} = {there} (drop the --set), "
                          "or move rcfd.h5 aside to record anew from the next frame boundary, or set "
                          "probes.rcfd_from = -1 to stop recording")


#: what a resume does without each file, for the hint when one is damaged
_WITHOUT = {"checkpoint.h5": "nothing to resume", "run.h5": "its series restart",
            "rcfd.h5": "the rCFD frames start anew at the next frame boundary"}


def check_readable(out_dir: pathlib.Path) -> None:
    """Refuse a run folder whose checkpoint.h5, run.h5 or rcfd.h5 cannot be read (a damaged file loses nothing
    more: a process killed while it wrote can leave an HDF5 file so)."""
    for name, must in (("checkpoint.h5", ("step", "time")), ("run.h5", ()), ("rcfd.h5", ())):
        path = out_dir / name
        if not path.exists():
            continue
        try:
            with h5py.File(path, "r") as f:
                missing = [k for k in must if k not in f.attrs]
                if name == "run.h5" and "series" in f:
                    f["series"]["time"][...] if "time" in f["series"] else None
                if name == "rcfd.h5":  # what the probe's resume reads and truncates
                    f["boundary/time"][...], f["frame/b1"][...], f["frame/offset"][...]
        except Exception as err:  # noqa: BLE001 - h5py raises OSError, KeyError or RuntimeError on damage
            raise ConfigError(f"{name} is damaged and cannot be read ({str(err).splitlines()[0][:80]})", str(path),
                              "--resume", hint=f"move it aside and resume ({name}: {_WITHOUT[name]}), or start "
                              "again with --overwrite") from None
        if missing:
            raise ConfigError(f"{name} lacks {', '.join(missing)}: not an fbed checkpoint", str(path), "--resume")

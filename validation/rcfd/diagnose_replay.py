"""Where does the replay error come from? Small experiments on a fine recording (validation/rcfd/README.md).

    python3 validation/rcfd/diagnose_replay.py record PRESET OUT [--from 0.4 --to 1.4] [--set KEY=VALUE ...]
        runs PRESET to --to with rCFD frames every fluid step from --from, and also keeps every grain's position
        at every frame boundary (OUT/positions.npy, float32 (B, grains, 3); the probe does not write positions,
        so this script wraps its one reader, app.rcfd_probe.read_solvers)
    python3 validation/rcfd/diagnose_replay.py analyze OUT [--tag z<0.015] > table
        the experiments: the replay's error against the real grains' tracer as the frame interval, the cell size,
        the precision and the region change, and the one-frame split of the error into its cause.
"""
from __future__ import annotations

import argparse
import json
import pathlib
import sys

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))


def record(preset: str, out: str, t_from: float, t_to: float, overrides: list) -> int:
    from app import rcfd_probe
    from app.run import run

    keep = []
    inner = rcfd_probe.read_solvers

    def reader(sim, what):
        v = inner(sim, what)
        if what == "grains":
            keep.append(np.asarray(v[0], np.float32).copy())
        return v

    rcfd_probe.read_solvers = reader
    rc = run(preset, [f"run.duration={t_to!r}", f"probes.rcfd_from={t_from!r}", "probes.rcfd_interval=0.001",
                      "probes.rcfd_fluxes=false"] + list(overrides), out=out, arch="cpu", overwrite=True)
    np.save(pathlib.Path(out) / "positions.npy", np.stack(keep))
    return rc


def cells_of(x: np.ndarray, origin, h: float, shape) -> np.ndarray:
    """Flat cell index of each point (the probe's rule: by centre, clipped into the region)."""
    q = np.floor((x - origin) / h).astype(np.int64)
    for a in range(3):
        np.clip(q[..., a], 0, shape[a] - 1, out=q[..., a])
    return (q[..., 0] * shape[1] + q[..., 1]) * shape[2] + q[..., 2]


def replay(cells: np.ndarray, vol: np.ndarray, tagged: np.ndarray, lag: int, n: int, dtype=np.float64) -> dict:
    """Replay the shifts built from ``cells`` (B, grains) every ``lag`` boundaries against the real grains' tracer
    on the same cells: the largest |M_replay - M_real| and the final values."""
    from app.rcfd.database import shift_operator
    from app.rcfd.transport import mixing_index

    vol = vol.astype(dtype)
    idx = np.arange(0, cells.shape[0], lag)
    real_m = lambda b: np.bincount(cells[b], weights=vol * tagged, minlength=n)
    real_u = lambda b: np.bincount(cells[b], weights=vol * ~tagged, minlength=n)
    m, u = real_m(idx[0]).astype(dtype), real_u(idx[0]).astype(dtype)
    Mr, Mx = [mixing_index(m, u)], [mixing_index(m, u)]
    split = 0.0  # the one-frame error summed: spurious mixing of each frame started from the real state
    for b0, b1 in zip(idx[:-1], idx[1:]):
        pair = cells[b0] * n + cells[b1]
        keys, inv = np.unique(pair, return_inverse=True)
        P, _ = shift_operator(keys // n, keys % n, np.bincount(inv, weights=vol), n)
        P = P.astype(dtype)
        m, u = P @ m, P @ u
        rm, ru = real_m(b1), real_u(b1)
        one = mixing_index(P @ real_m(b0), P @ real_u(b0)) - mixing_index(real_m(b0), real_u(b0))
        split += one - (mixing_index(rm, ru) - mixing_index(real_m(b0), real_u(b0)))
        Mr.append(mixing_index(rm, ru))
        Mx.append(mixing_index(m, u))
    Mr, Mx = np.array(Mr), np.array(Mx)
    return {"max_abs_error": float(np.max(np.abs(Mx - Mr))), "M_real_end": float(Mr[-1]),
            "M_replay_end": float(Mx[-1]), "M_real_max": float(Mr.max()),
            "sum_of_one_frame_excess_mixing": float(split), "frames": int(idx.size - 1)}


def memory(cells: np.ndarray, vol: np.ndarray, lag: int, n: int, shape, h: float) -> dict:
    """The Markov test of the cell-to-cell shifts: (1) of the grains that changed cell in a frame, the share that
    go back to the cell they came from in the next frame, against the share the chain sends back (the operator's
    probability of that move, from the cell they are in); (2) the grains' vertical mean-square displacement on cell
    centres against the chain's, started from the same grain volumes, after 0.1, 0.2, 0.5 s and at the end."""
    from app.rcfd.database import shift_operator

    idx = np.arange(0, cells.shape[0], lag)
    zc = (np.unravel_index(np.arange(n), shape)[2] + 0.5) * h
    ops = []
    for b0, b1 in zip(idx[:-1], idx[1:]):
        pair = cells[b0] * n + cells[b1]
        keys, inv = np.unique(pair, return_inverse=True)
        ops.append(shift_operator(keys // n, keys % n, np.bincount(inv, weights=vol), n)[0])
    back_real = back_chain = moved = 0.0
    for k in range(len(ops) - 1):
        c0, c1, c2 = cells[idx[k]], cells[idx[k + 1]], cells[idx[k + 2]]
        mv = c1 != c0
        moved += mv.sum()
        back_real += np.sum(mv & (c2 == c0))
        back_chain += float(np.asarray(ops[k + 1][c0[mv], c1[mv]]).sum())
    Q = np.eye(n)
    a0 = np.bincount(cells[idx[0]], weights=vol, minlength=n)
    out = {"moved_share_per_frame": float(moved / (cells.shape[1] * (len(ops) - 1))),
           "back_next_frame_real": float(back_real / moved), "back_next_frame_chain": float(back_chain / moved),
           "msd_mm2": {}}
    dt = 1e-3 * lag
    marks = {int(round(t / dt)) for t in (0.1, 0.2, 0.5)} | {len(ops)}
    for k, P in enumerate(ops, 1):
        Q = P @ Q
        if k in marks:
            chain = float(np.sum(a0 * (Q * (zc[:, None] - zc[None, :]) ** 2).sum(0)) / a0.sum())
            real = float(np.sum(vol * (zc[cells[idx[k]]] - zc[cells[idx[0]]]) ** 2) / vol.sum())
            out["msd_mm2"][f"{k * dt:.2f} s"] = {"real": real * 1e6, "chain": chain * 1e6}
    return out


def analyze(out: str, tag: str) -> dict:
    import h5py

    from app.rcfd import commands, paths as pathmod
    from app.rcfd.database import load, tag_mask
    from app.rcfd.transport import GrainTracer, mixing_index, mixing_index_real

    d = pathlib.Path(out)
    X = np.load(d / "positions.npy").astype(np.float64)
    with h5py.File(d / "rcfd.h5", "r") as f:
        h, origin, shape = float(f.attrs["h"]), np.asarray(f.attrs["origin"]), tuple(f.attrs["shape"])
        counted = f["grains_counted"][...]
        vol = f["grains_volume"][...]
        cells_rec = f["boundary/cells"][...].astype(np.int64)
    X = X[:, counted]
    tagged = tag_mask(tag, X[0])
    n = int(np.prod(shape))
    res = {"boundaries": int(X.shape[0]), "grains": int(X.shape[1]), "tag": tag}
    # 0. the probe's cells are the cells of the positions (same rule), so nothing is lost in the recording
    res["recorded_cells_equal_positions"] = bool(np.array_equal(cells_of(X, origin, h, shape), cells_rec))
    # 1. the app's own replay (float32 boundary fields, the engine, the path) against this script's float64 one
    if tag == str(h5py.File(d / "rcfd.h5", "r").attrs["tag"]):
        db = load(d, 5)
        eng = commands.Engine(db, solids="cells")
        rp = pathmod.replay(db.n_frames, eng.successor)
        b00 = int(db.b0[rp.frames[0]])
        r = eng.transport(rp, commands.initial_concentration(db, b00, None), b00)
        states = np.concatenate([[b00], db.b1[rp.frames]])
        Mreal = np.array([mixing_index_real(db.tagged[b], db.solid[b]) for b in states])
        res["app_cell_shift_replay_lag5"] = {"max_abs_error": float(np.max(np.abs(r["M"] - Mreal)))}
    # 1b. the grain tracer (app.rcfd.transport.GrainTracer): exact along the recorded order; averaged over the
    # cells at resets every L frames of 5 ms (a path's jumps at its mean sequence length)
    db = load(d, 5)
    eng = commands.Engine(db, solids="grains")
    rp = pathmod.replay(db.n_frames, eng.successor)
    states = np.concatenate([[db.b0[rp.frames[0]]], db.b1[rp.frames]])
    Mreal = np.array([mixing_index_real(db.tagged[b], db.solid[b]) for b in states])
    tau0 = tag_mask(tag, X[int(db.b0[rp.frames[0]])]).astype(float)
    res["grain_tracer_replay_lag5"] = {}
    for L in (0, 5, 10, 20, 40, 100):
        p = pathmod.with_resets(rp, L, db.b0) if L else rp
        r = eng.transport(p, None, 0, tau0=tau0)
        Mr = r["M"] if tag == str(db.tag) else None
        if Mr is None:  # the real index for another tag, from the positions' cells
            Mr = np.array([mixing_index(*[np.bincount(db.cells[b], weights=db.grain_volume * w, minlength=n)
                                          for w in (tau0, 1 - tau0)]) for b in states])
        else:
            Mr = Mreal
        res["grain_tracer_replay_lag5"][f"resets every {L} frames" if L else "no resets"] = {
            "max_abs_error": float(np.max(np.abs(r["M"] - Mr))), "M_end": float(r["M"][-1]), "M_real_end": float(Mr[-1]),
            "drift": r["drift"]}
    # 2. frame interval (lag L boundaries of 1 ms), recorded cells (5 mm, region below z_max)
    res["frame_interval_ms"] = {L: replay(cells_rec, vol, tagged, L, n) for L in (1, 2, 5, 10, 20, 50, 100)}
    # 3. float32 throughout at 5 ms
    res["float32_lag5"] = replay(cells_rec, vol, tagged, 5, n, np.float32)["max_abs_error"]
    # 4. the whole domain height (no region clip) at 5 mm, 5 ms
    zfull = int(round(0.12 / h))
    res["whole_height_lag5"] = replay(cells_of(X, origin, h, shape[:2] + (zfull,)), vol, tagged, 5,
                                      shape[0] * shape[1] * zfull)
    # 5. the Markov test: do grains remember where they came from?
    res["memory_lag5"] = memory(cells_rec, vol, 5, n, shape, h)
    res["memory_lag50"] = memory(cells_rec, vol, 50, n, shape, h)
    # 6. the cell size (the tracer grid) at 5 ms: both the real tracer and the replay on the same grid
    res["cell_size_mm"] = {}
    for hh in (2.5e-3, 5e-3, 10e-3):
        sh = tuple(max(1, int(round(s * h / hh))) for s in shape)
        res["cell_size_mm"][hh * 1e3] = replay(cells_of(X, origin, hh, sh), vol, tagged, 5, int(np.prod(sh)))
    # 7. the averaging grid: resets every 0.1 s (20 frames of 5 ms), the index measured on the 5 mm cells
    res["reset_every_100ms_by_averaging_cell_mm"] = {}
    c5 = cells_of(X, origin, h, shape)
    for hh in (1.25e-3, 2.5e-3, 5e-3, 10e-3):
        sh = tuple(max(1, int(round(s * h / hh))) for s in shape)
        fine = cells_of(X, origin, hh, sh)
        # averaging on the fine grid, measured on the 5 mm one: tau from the fine cells, M on c5
        tr, nf = GrainTracer(vol, tagged.astype(float), int(np.prod(sh))), int(np.prod(sh))
        M, real = [], []
        ref = GrainTracer(vol, tagged.astype(float), n)
        for b in range(0, X.shape[0]):
            if b and b % 100 == 0:
                m, u = tr.volumes(fine[b])
                tr.tau = np.divide(m, m + u, out=np.zeros(nf), where=m + u > 0)[fine[b]]
            M.append(mixing_index(*[np.bincount(c5[b], weights=vol * w, minlength=n) for w in (tr.tau, 1 - tr.tau)]))
            real.append(ref.mixing_index(c5[b]))
        res["reset_every_100ms_by_averaging_cell_mm"][hh * 1e3] = float(np.max(np.abs(np.array(M) - real)))
    return res


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("action", choices=("record", "analyze"))
    ap.add_argument("args", nargs="+")
    ap.add_argument("--from", dest="t_from", type=float, default=0.4)
    ap.add_argument("--to", dest="t_to", type=float, default=1.4)
    ap.add_argument("--tag", default="z<0.015")
    ap.add_argument("--set", dest="overrides", action="append", default=[], help="record: a preset override")
    a = ap.parse_args()
    if a.action == "record":
        sys.exit(record(a.args[0], a.args[1], a.t_from, a.t_to, a.overrides))
    print(json.dumps(analyze(a.args[0], a.tag), indent=1))

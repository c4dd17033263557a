"""Markov paths through the recorded frames (after CFDEMcoupling-PFM's MarkovPath; our own code).

A path is a list of frames. Within a sequence it follows the recorded order; once a sequence has
``l_min`` frames it ends after each further frame with probability p = 1 / (l_mean - l_min + 1), so
sequence lengths are l_min + a geometric number of frames with mean l_mean (before the cut at the end
of a recorded stretch, where a jump is forced). At a jump from state s (the boundary the last frame
ended at) the path goes on with the frame that starts at the state j most similar to s,
argmin_j R(s, j), over the states |j - s| >= window from which at least l_min frames follow in
recorded order. A seeded numpy Generator draws the lengths: a path is reproduced from (seed, index).
"""
from __future__ import annotations

import dataclasses

import numpy as np


@dataclasses.dataclass(frozen=True)
class PathParams:
    l_min: int     # frames a sequence runs at least
    l_mean: int    # mean sequence length [frames]
    window: int    # exclusion window of the jump search [states]

    @staticmethod
    def default(n_frames: int, period_frames: float | None = None) -> "PathParams":
        """L_min = N/20, L_mean = N/10 (at least L_min + 1), window = half a period (or L_min)."""
        l_min = max(1, n_frames // 20)
        l_mean = max(l_min + 1, n_frames // 10)
        w = int(np.ceil(0.5 * period_frames)) if period_frames and np.isfinite(period_frames) else l_min
        return PathParams(l_min, l_mean, max(1, w))


@dataclasses.dataclass
class Path:
    frames: np.ndarray            # the frames in order
    jumps: list                   # (position in frames, from state, to state, R at the jump)
    seed: tuple

    @property
    def sequences(self) -> list[tuple[int, int]]:
        """(first frame, length) of each sequence."""
        cuts = [0] + [j[0] for j in self.jumps] + [len(self.frames)]
        return [(int(self.frames[a]), b - a) for a, b in zip(cuts[:-1], cuts[1:]) if b > a]


def run_lengths(successor: np.ndarray) -> np.ndarray:
    """For each frame, how many frames follow it in recorded order including itself."""
    n = successor.size
    out = np.ones(n, np.int64)
    for k in range(n - 2, -1, -1):
        if successor[k] >= 0:
            out[k] = out[successor[k]] + 1
    return out


def jump_targets(R: np.ndarray, b0: np.ndarray, successor: np.ndarray, params: PathParams) -> tuple[np.ndarray, np.ndarray]:
    """For each state s: the frame a jump from s continues with (-1: none allowed) and R at it."""
    n_states = R.shape[0]
    starts = run_lengths(successor) >= params.l_min
    cand_state = b0[starts]
    cand_frame = np.nonzero(starts)[0]
    if cand_state.size == 0:
        raise ValueError(f"no frame starts a run of {params.l_min} recorded frames: lower l_min")
    target = np.full(n_states, -1, np.int64)
    value = np.full(n_states, np.nan)
    for s in range(n_states):
        ok = np.abs(cand_state - s) >= params.window
        if not ok.any():
            continue
        r = R[s, cand_state[ok]]
        i = int(np.argmin(r))
        target[s], value[s] = cand_frame[ok][i], r[i]
    if (target < 0).all():
        raise ValueError(f"the exclusion window ({params.window} states: half the bed's period, or a twentieth of "
                         f"the database) leaves no state to jump to among its {n_states}: record a database several "
                         "of the bed's periods long (probes.rcfd_from earlier, or run.duration later)")
    return target, value


def markov_path(n_frames: int, start_state: int, R: np.ndarray, b0: np.ndarray, b1: np.ndarray,
                successor: np.ndarray, params: PathParams, seed: tuple, targets=None) -> Path:
    """A path of ``n_frames`` frames that starts by jumping from ``start_state`` (the state the tracer is
    tagged at; when a frame starts there and its run is long enough, it starts there instead)."""
    rng = np.random.default_rng(list(seed))
    target, value = targets if targets is not None else jump_targets(R, b0, successor, params)
    p_end = 1.0 / (params.l_mean - params.l_min + 1)
    frames = np.empty(n_frames, np.int64)
    jumps = []
    starts = np.nonzero(b0 == start_state)[0]
    lengths = run_lengths(successor)
    if starts.size and lengths[starts[0]] >= params.l_min:
        cur = int(starts[0])
    else:
        cur = int(target[start_state])
        if cur < 0:
            raise ValueError(f"state {start_state} has no jump target outside the exclusion window")
        jumps.append((0, int(start_state), int(b0[cur]), float(value[start_state])))
    run = 0
    for i in range(n_frames):
        frames[i] = cur
        run += 1
        if i == n_frames - 1:
            break
        nxt = successor[cur]
        end = nxt < 0 or (run >= params.l_min and rng.random() < p_end)
        if end:
            s = int(b1[cur])
            t = int(target[s])
            if t < 0:  # no target outside the window from this state: carry on if the record allows
                if nxt < 0:
                    raise ValueError(f"state {s} ends a recorded stretch and has no jump target")
                cur = int(nxt)
                continue
            jumps.append((i + 1, s, int(b0[t]), float(value[s])))
            cur, run = t, 0
        else:
            cur = int(nxt)
    return Path(frames, jumps, tuple(seed))


def replay(n_frames: int, successor: np.ndarray) -> Path:
    """The recorded order from frame 0 (a replay of the database)."""
    frames = [0]
    while len(frames) < n_frames and successor[frames[-1]] >= 0:
        frames.append(int(successor[frames[-1]]))
    return Path(np.asarray(frames), [], ())


def with_resets(path: Path, every: int, b0: np.ndarray) -> Path:
    """The same frames with a jump from each ``every``-th frame's start state to itself: what a jump does to the
    tracer (the grain tracer averages over each cell there) without changing the flow's order, so a replay
    with resets at the paths' mean sequence length isolates the transport error of the jumps."""
    pos = range(every, len(path.frames), max(1, int(every)))
    return Path(path.frames, [(p, int(b0[path.frames[p]]), int(b0[path.frames[p]]), 0.0) for p in pos], path.seed)


def visit_balance(frames: np.ndarray, n: int) -> float:
    """Most visits of a frame over the mean visits of the visited frames."""
    v = np.bincount(frames, minlength=n)
    v = v[v > 0]
    return float(v.max() / v.mean()) if v.size else float("nan")

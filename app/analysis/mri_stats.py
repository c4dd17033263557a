"""The statistics of the MRI pipeline (``app.analysis.mri``; seed 002, Section 3.3.3 and 3.3.7): bootstrap
intervals, the gradient quality score and the choice of a threshold per metric from the study's acceptance
criteria alone; runs pooled (their agreement, blocks within one run). Plain numpy and scipy; also reachable as
``app.analysis.mri.bootstrap`` etc."""
from __future__ import annotations

import math

import numpy as np
from scipy import stats

from .pooling import spans

THRESHOLDS = (0.15, 0.20, 0.25, 0.30, 0.35, 0.40)  # solid-fraction thresholds of the study (Step 4)
N_BOOT = 10_000           # bootstrap resamples
V_RANGE = (0.05, 0.80)    # m/s: the expected bubble velocities (Pigford, 1968), the study's criterion
CV_MAX = 30.0             # %: the study's acceptance criteria (3.3.7)
CI_MAX = 30.0             # % of the mean
KS_MIN = 0.01
GRADIENT_MIN = 0.3


def bootstrap(values, n_boot: int = N_BOOT, seed: int = 0) -> dict:
    """Mean, median, max, std (n - 1), CV [%] of ``values`` and the 95% percentile intervals of the mean and the
    median over n_boot resamples with replacement."""
    v = np.asarray(values, float)
    v = v[np.isfinite(v)]
    out = dict(n=int(v.size))
    if v.size == 0:
        return out | dict(mean=math.nan, median=math.nan, max=math.nan, std=math.nan, cv=math.nan,
                          mean_lo=math.nan, mean_hi=math.nan, median_lo=math.nan, median_hi=math.nan)
    rng = np.random.default_rng(seed)
    means, medians = np.empty(n_boot), np.empty(n_boot)
    chunk = max(1, int(2e6 // max(v.size, 1)))
    for a in range(0, n_boot, chunk):
        b = min(n_boot, a + chunk)
        s = v[rng.integers(0, v.size, size=(b - a, v.size))]
        means[a:b] = s.mean(1)
        medians[a:b] = np.median(s, 1)
    mean = float(v.mean())
    std = float(v.std(ddof=1)) if v.size > 1 else 0.0
    return out | dict(mean=mean, median=float(np.median(v)), max=float(v.max()), std=std,
                      cv=100.0 * std / abs(mean) if mean else math.inf,
                      mean_lo=float(np.percentile(means, 2.5)), mean_hi=float(np.percentile(means, 97.5)),
                      median_lo=float(np.percentile(medians, 2.5)), median_hi=float(np.percentile(medians, 97.5)))


def integral_time(x, dt: float = 1.0) -> float:
    """Integral time scale of a series [the unit of dt; frames for dt = 1]: its autocorrelation summed up to the
    first zero (dt for a constant series: one whose values are all equal, although y - mean may not be 0 in floating
    point, 0.236 - 0.236 = 5.6e-17, with variance 0; that divided by zero)."""
    y = np.asarray(x, np.float64)
    if y.size == 0 or not np.ptp(y) > 0:
        return dt
    y = y - y.mean()
    ac = np.correlate(y, y, "full")[y.size - 1:] / (y.var() * y.size)
    zero = np.nonzero(ac <= 0)[0]
    end = int(zero[0]) if zero.size else ac.size
    return float(ac[:end].sum() * dt)


def block_frames(series, segments=None) -> int:
    """Frames per block for :func:`block_bootstrap`: two integral times of ``series`` (one value a frame, e.g. the bed
    height), so that blocks are near independent; at least 1. Pooled segments (``segments``: their first frames):
    the segments' integral times, weighted by their lengths (the jump between two runs is no correlation)."""
    x = np.asarray(series, np.float64)
    sp = spans(x.size, segments)
    t = sum((b - a) * integral_time(x[a:b]) for a, b in sp) / max(1, x.size)
    return max(1, int(round(2.0 * t)))


def block_stats(h: np.ndarray, block: int) -> dict:
    """Mean and std of a series [its unit] with their standard errors from ``block``-sample blocks (each about two
    integral times, so the blocks are near independent): the mean's from the block means, the std's from the blocks'
    mean squared deviation (its variance's error, halved by the square root). NaN errors under two blocks."""
    h = np.asarray(h, np.float64)
    nb = h.size // max(1, block)
    m, sd = float(h.mean()), float(h.std())
    if nb < 2:
        return {"mean": m, "mean_se": float("nan"), "std": sd, "std_se": float("nan"), "blocks": nb}
    b = h[:nb * block].reshape(nb, block)
    sq = ((b - m) ** 2).mean(1)
    return {"mean": m, "mean_se": float(b.mean(1).std(ddof=1) / np.sqrt(nb)), "std": sd,
            "std_se": float(sq.std(ddof=1) / np.sqrt(nb) / (2 * max(sd, 1e-300))), "blocks": nb}


def z_between(a: dict, b: dict) -> dict:
    """How many standard errors apart two :func:`block_stats` are, in mean and in std (NaN without errors)."""
    with np.errstate(invalid="ignore", divide="ignore"):  # equal values without errors (a constant series): 0
        return {k: 0.0 if a[k] == b[k] else float(abs(a[k] - b[k]) / np.hypot(a[f"{k}_se"], b[f"{k}_se"]))
                for k in ("mean", "std")}


def halves(series, block: int) -> dict:
    """Is a record steady? :func:`block_stats` of its first and second halves and how far apart they lie (``z``, in
    standard errors). A drift of several standard errors means the window's statistics are not yet the bed's
    steady ones (validation/rcfd/README.md, 000: a bed whose spread fell from 8.6 to 5.3 mm over 8 s)."""
    x = np.asarray(series, np.float64)
    first, second = block_stats(x[:x.size // 2], block), block_stats(x[x.size // 2:], block)
    return {"first": first, "second": second, "z": z_between(first, second)}


def block_bootstrap(groups, block: int, n_boot: int = N_BOOT, seed: int = 0, segments=None) -> dict:
    """95% interval of the mean of the values in ``groups`` (one array of values a frame, in frame order) over
    n_boot moving-block resamples: blocks of ``block`` consecutive frames drawn with replacement until they hold as
    many frames as the record. Frames 4 ms apart see the same bubbles and the same surge of the bed, so resampling
    frames (or bubbles) one by one, as :func:`bootstrap` and the study do, gives intervals too narrow by about the
    square root of the frames a value stays correlated over; this is the interval that allows for it. A record pooled
    from several runs (``segments``: their first frames) draws only blocks within one run (a run shorter than a
    block adds none)."""
    counts = np.array([np.size(g) for g in groups], np.float64)
    sums = np.array([np.sum(g) if np.size(g) else 0.0 for g in groups], np.float64)
    nf = counts.size
    out = dict(block_frames=int(block))
    if nf == 0 or counts.sum() == 0:
        return out | dict(mean_lo_blocks=math.nan, mean_hi_blocks=math.nan)
    sp = spans(nf, segments)
    b = max(1, min(int(block), max(e - a for a, e in sp)))
    cs, cc = np.concatenate([[0.0], np.cumsum(sums)]), np.concatenate([[0.0], np.cumsum(counts)])
    bs, bc = cs[b:] - cs[:-b], cc[b:] - cc[:-b]  # each block start's sum and count
    ok = block_starts(nf, b, segments)
    bs, bc = bs[ok], bc[ok]
    k = int(math.ceil(nf / b))
    rng = np.random.default_rng(seed)
    starts = rng.integers(0, bs.size, size=(n_boot, k))
    num, den = bs[starts].sum(1), bc[starts].sum(1)
    means = num[den > 0] / den[den > 0]
    return out | dict(mean_lo_blocks=float(np.percentile(means, 2.5)), mean_hi_blocks=float(np.percentile(means, 97.5)))


def block_starts(nf: int, block: int, segments=None) -> np.ndarray:
    """The first frames of the blocks of ``block`` frames that lie within one segment (all nf - block + 1 starts
    for one segment)."""
    return np.concatenate([np.arange(a, e - block + 1) for a, e in spans(nf, segments)] + [np.zeros(0, int)])


def sessions_agree(series, segments, block: int) -> dict:
    """Do runs pooled as realisations of one case agree? Each segment's :func:`block_stats` of ``series`` (e.g. the
    bed height), their mean weighted by 1 / se^2, and chi^2 = sum ((mean_i - weighted mean) / se_i)^2 with its
    p-value on (segments - 1) degrees of freedom: a small p (< 0.01) says the runs are not one steady operating point
    (one still settling, or another case). NaN without two blocks in every segment."""
    x = np.asarray(series, np.float64)
    rows = [block_stats(x[a:e], block) | dict(first=a, frames=e - a) for a, e in spans(x.size, segments)]
    se = np.array([r["mean_se"] for r in rows])
    m = np.array([r["mean"] for r in rows])
    if len(rows) < 2 or not np.all(np.isfinite(se) & (se > 0)):
        return dict(rows=rows, weighted_mean=math.nan, chi2=math.nan, dof=len(rows) - 1, p=math.nan)
    w = 1.0 / se ** 2
    mw = float((w * m).sum() / w.sum())
    chi2 = float((((m - mw) / se) ** 2).sum())
    return dict(rows=rows, weighted_mean=mw, chi2=chi2, dof=len(rows) - 1, p=float(stats.chi2.sf(chi2, len(rows) - 1)))


def gradient_quality(values: list[float], thresholds=THRESHOLDS) -> list[float]:
    """fbed's reading of the study's 'gradient quality score' (it names no formula): the sensitivity
    S = dM/d(alpha_s) (eq. 16; central differences, one-sided at the ends) scored as
    min(|S|, S_med) / max(|S|, S_med), S_med the median |S| over the thresholds: 1 at the median sensitivity,
    towards 0 for excessive or insufficient sensitivity; > 0.3 is within a factor 3.3 of the median.
    Thresholds whose metric is undefined (no bubble there: nan) get nan and the others are scored among
    themselves (one empty threshold used to make every threshold's score nan, so all failed 'gradient')."""
    m = np.asarray(values, float)
    a = np.asarray(thresholds, float)
    ok = np.isfinite(m)
    out = [math.nan] * m.size
    if ok.sum() < 2:
        return out
    s = np.abs(np.gradient(m[ok], a[ok]))
    med = float(np.median(s))
    for i, x in zip(np.nonzero(ok)[0], s):
        out[i] = (1.0 if x == 0.0 else 0.0) if med == 0.0 else (float(min(x, med) / max(x, med)) if x > 0 else 0.0)
    return out


def choose_threshold(rows: list[dict], velocity: bool = False) -> tuple[int, list[str]]:
    """Index of the threshold chosen for one metric from its per-threshold rows (keys cv, ci_width_pct, ks_p,
    gradient_quality, mean) and the criteria each row fails. Of the thresholds that pass every criterion the
    one with the narrowest interval (the study's 'measurement precision') is chosen; with none passing, the one
    failing fewest, then the narrowest. No measured value enters."""
    fails = []
    for r in rows:
        f = []
        if not (r["cv"] < CV_MAX):
            f.append("cv")
        if not (r["ci_width_pct"] < CI_MAX):
            f.append("ci_width")
        if not (r["ks_p"] > KS_MIN):
            f.append("ks")
        if not (r["gradient_quality"] > GRADIENT_MIN):
            f.append("gradient")
        if velocity and not (V_RANGE[0] <= r["mean"] <= V_RANGE[1]):
            f.append("velocity_range")
        if r["n"] < 2:
            f.append("too_few")
        fails.append(f)
    key = [(len(f), r["ci_width_pct"] if np.isfinite(r["ci_width_pct"]) else math.inf) for f, r in zip(fails, rows)]
    return int(min(range(len(rows)), key=lambda i: key[i])), [";".join(f) for f in fails]

"""Bubble rise velocities between two horizontal planes of porosity (Verma et al. 2014's plane pairs): the
cross-correlation of the two planes' signals (``rise_velocity``) and, as a check on it, bubble noses and tails timed
cell by cell (``edge_velocities``). SI units; frames (nt, nx, ny) sampled every dt. (In ``bubbles`` before
2026-12-07.)"""
from __future__ import annotations

import math

import numpy as np

from .bubbles import THRESHOLD, _as_frames, _check_mask
from .pooling import spans


def rise_velocity(lower, upper, dt: float, spacing: float, mask=None,
                  max_lag: int | None = None, segments=None) -> tuple[float, float]:
    """Bubble rise velocity between two horizontal planes by cross-correlation.

    lower, upper: (nt, nx, ny) porosity of the lower and upper plane, sampled every ``dt`` [s];
    ``spacing`` [m] is the vertical distance between the planes. For every cell the time mean
    is subtracted, then the cross-correlation

        C(k) = sum_cells w_c sum_t a_c(t) b_c(t + k)

    (a: lower, b: upper, w_c: cell area, uniform here, 0 outside ``mask``) is formed with FFTs
    (zero padded, no wrap-around). Only lags k >= 0 are searched (the upper plane sees a bubble
    later), up to ``max_lag`` samples (default nt // 2). The peak is refined by a parabola
    through C(k-1), C(k), C(k+1). Returns (velocity [m/s], lag [s]) = (spacing / lag, lag);
    (nan, nan) when the correlation has no positive peak at a positive lag (peak value <= 0,
    peak at the end of the search window, or refined lag <= 0). A record pooled from several runs (``segments``:
    their first frames): each run's means subtracted and its correlation formed alone, the correlations summed
    (no product pairs frames of two runs); lags up to half the longest run.
    """
    a = _as_frames(lower).astype(float)
    b = _as_frames(upper).astype(float)
    if a.shape != b.shape:
        raise ValueError(f"lower {a.shape} and upper {b.shape} shapes differ")
    nt = a.shape[0]
    nan = (float("nan"), float("nan"))
    if nt < 4:
        return nan
    w = np.ones(a.shape[1:])
    m = _check_mask(mask, a.shape[1:])
    if m is not None:
        w = w * m
    sp = [(i, e) for i, e in spans(nt, segments) if e - i >= 4]
    if not sp:
        return nan
    longest = max(e - i for i, e in sp)
    nfft = 1 << int(math.ceil(math.log2(2 * longest)))
    c = np.zeros(nfft)
    for i, e in sp:
        sa = np.nan_to_num(a[i:e] - np.nanmean(a[i:e], axis=0))
        sb = np.nan_to_num(b[i:e] - np.nanmean(b[i:e], axis=0))
        spec = np.einsum("tij,tij,ij->t", np.conj(np.fft.rfft(sa, n=nfft, axis=0)), np.fft.rfft(sb, n=nfft, axis=0), w)
        c += np.fft.irfft(spec, n=nfft)  # c[k] = sum a(t) b(t+k); c[-k] at index nfft-k
    if max_lag is None:
        max_lag = longest // 2
    max_lag = int(min(max_lag, longest - 2))
    k = int(np.argmax(c[: max_lag + 1]))
    if c[k] <= 0.0 or k == max_lag:
        return nan
    ym, y0, yp = c[k - 1], c[k], c[k + 1]  # c[-1] is the lag -1 value
    den = ym - 2.0 * y0 + yp
    delta = 0.5 * (ym - yp) / den if den < 0.0 else 0.0
    lag = (k + delta) * dt
    if not lag > 0.0:
        return nan
    return float(spacing / lag), float(lag)


def _crossings(series: np.ndarray, threshold: float, rising: bool) -> np.ndarray:
    """Sub-sample times (in samples) where a 1-D series crosses ``threshold`` upward
    (``rising``) or downward, by linear interpolation between the two samples."""
    above = series > threshold
    i = np.nonzero((~above[:-1] & above[1:]) if rising else (above[:-1] & ~above[1:]))[0]
    s0, s1 = series[i], series[i + 1]
    return i + (threshold - s0) / (s1 - s0)  # s0 != s1: one is above, one is not


def _interquartile_mean(x: np.ndarray) -> float:
    q1, q3 = np.percentile(x, [25.0, 75.0])
    mid = x[(x >= q1) & (x <= q3)]
    return float(mid.mean())


def edge_velocities(lower, upper, dt: float, spacing: float, threshold: float = THRESHOLD, mask=None,
                    min_velocity: float = 0.05, segments=None) -> dict:
    """Rise velocities of bubble noses and tails between two horizontal planes, by time of flight.

    A check on ``rise_velocity`` (which correlates the whole porosity signal): in every cell
    (inside ``mask``), each time the porosity of the lower plane crosses ``threshold`` upward (a
    bubble's nose arrives) is paired with the next upward crossing in the same cell of the upper
    plane, if no other lower crossing comes first and the lag is at most spacing / min_velocity;
    downward crossings (tails) likewise. Crossing times are interpolated linearly between samples.
    A bubble that stretches as it rises has a faster nose than tail; the correlation lag sits
    between the two.

    lower, upper: (nt, nx, ny) porosity sampled every ``dt`` [s]; ``spacing`` [m] between the planes.
    Returns {"nose": {...}, "tail": {...}}, each with ``velocity`` [m/s] = spacing / lag, where
    ``lag`` [s] is the mean of the paired lags between their quartiles (robust to the few
    mispaired events), and ``count``, the number of paired events; velocity and lag are nan
    when no event pairs. A record pooled from several runs (``segments``: their first frames): crossings are
    paired within one run only.
    """
    a = _as_frames(lower).astype(float)
    b = _as_frames(upper).astype(float)
    if a.shape != b.shape:
        raise ValueError(f"lower {a.shape} and upper {b.shape} shapes differ")
    m = _check_mask(mask, a.shape[1:])
    cells = np.argwhere(m) if m is not None else np.argwhere(np.ones(a.shape[1:], bool))
    max_lag = spacing / min_velocity / dt  # samples
    runs = spans(a.shape[0], segments)
    out = {}
    for kind, rising in (("nose", True), ("tail", False)):
        lags = []
        for (i, j), (s0, s1) in ((c, r) for c in cells for r in runs):
            ta = _crossings(a[s0:s1, i, j], threshold, rising)
            tb = _crossings(b[s0:s1, i, j], threshold, rising)
            if not ta.size or not tb.size:
                continue
            nxt = np.append(ta[1:], np.inf)  # the next lower crossing after each
            k = np.searchsorted(tb, ta, side="right")  # first upper crossing after each lower one
            ok = k < tb.size
            ta, nxt, after = ta[ok], nxt[ok], tb[k[ok]]
            lag = after - ta
            keep = (after < nxt) & (lag > 0.0) & (lag <= max_lag)
            lags.append(lag[keep])
        lag = np.concatenate(lags) if lags else np.zeros(0)
        if lag.size:
            mean_lag = _interquartile_mean(lag) * dt
            out[kind] = {"velocity": float(spacing / mean_lag), "lag": mean_lag, "count": int(lag.size)}
        else:
            out[kind] = {"velocity": float("nan"), "lag": float("nan"), "count": 0}
    return out

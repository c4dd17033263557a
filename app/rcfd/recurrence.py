"""Recurrence statistics of a recorded void-fraction field.

- The recurrence matrix (Lichtenegger & Pirker 2016; the source paper's Eq. 11-12):
  R_ij = int (eps_i - eps_j)^2 dV / max_ij int (eps_i - eps_j)^2 dV over the bed cells, computed as a
  Gram matrix: with X the states (rows) times cells (columns) weighted by sqrt(V) and centred on the
  time mean, |x_i - x_j|^2 = G_ii + G_jj - 2 G_ij, G = X X^T summed over chunks of cells.
- Spectra: a Hann-windowed periodogram of a signal sampled at the frame interval; the dominant
  period is the peak's, resolved to one bin df = 1 / (N dt).
- The mean distance against lag D(tau) = mean_i R(i, i + tau); its first local minimum after its
  first rise is a second estimate of the period.
- The database-length check: b(i) = max over j <= i - w of (1 - R_ij), how similar each state is
  to its best earlier recurrence, and its running mean S(n) (CFDEM's standardRecStatAnalysis); the
  database is long enough when b stops rising (its last quarter's mean within 0.01 of the quarter
  before; S(n), a cumulative mean, approaches its limit only as 1/n).
- The Taylor time scale sqrt(<g^2> / <dg/dt^2>) of g = eps - mean(eps) (the source paper's Eq. 13).
"""
from __future__ import annotations

import numpy as np


def state_matrix(eps: np.ndarray, mask: np.ndarray, volume: np.ndarray | float = 1.0) -> np.ndarray:
    """X (states, cells in mask): eps minus its time mean, times sqrt(cell volume), float32."""
    e = np.asarray(eps, np.float64).reshape(eps.shape[0], -1)[:, mask.ravel()]
    v = np.broadcast_to(np.asarray(volume, np.float64), mask.shape).ravel()[mask.ravel()]
    return ((e - e.mean(0)) * np.sqrt(v)).astype(np.float32)


def squared_distances(X: np.ndarray, chunk: int = 32768) -> np.ndarray:
    """D_ij = |x_i - x_j|^2 from the Gram matrix accumulated over column chunks (float64 sums), clipped at 0."""
    n = X.shape[0]
    G = np.zeros((n, n))
    for c in range(0, X.shape[1], chunk):
        Xc = np.asarray(X[:, c:c + chunk], np.float64)
        G += Xc @ Xc.T
    d = np.diag(G).copy()
    D = d[:, None] + d[None, :] - 2.0 * G
    np.fill_diagonal(D, 0.0)
    return np.maximum(D, 0.0)


def recurrence_matrix(X: np.ndarray, chunk: int = 32768) -> tuple[np.ndarray, float]:
    """(R, norm): R = D / max D in [0, 1] (0 on the diagonal), norm = max D [m^3, for eps weighted by sqrt(V)]."""
    D = squared_distances(X, chunk)
    norm = float(D.max())
    return (D / norm if norm > 0 else D), norm


def spectrum(signal: np.ndarray, dt: float) -> dict:
    """Hann-windowed one-sided periodogram of ``signal`` (its mean removed) sampled every ``dt`` [s].
    Returns freq [Hz], power, the peak's frequency [Hz] and period [s] (the zero bin excluded), the bin width
    df [Hz]; the peak frequency is refined by a parabola through the three bins around it, which stays within
    the peak bin."""
    x = np.asarray(signal, np.float64)
    x = x - x.mean()
    n = x.size
    win = np.hanning(n)
    power = np.abs(np.fft.rfft(x * win)) ** 2
    freq = np.fft.rfftfreq(n, dt)
    k = int(np.argmax(power[1:])) + 1 if n > 2 else 0
    f_peak = freq[k]
    if 1 <= k < power.size - 1:
        a, b, c = np.log(power[k - 1:k + 2] + 1e-300)
        den = a - 2 * b + c
        if den < 0:
            f_peak = freq[k] + 0.5 * (a - c) / den * (freq[1] - freq[0])
    df = 1.0 / (n * dt)
    return {"freq": freq, "power": power, "peak_frequency": float(f_peak), "peak_bin": k,
            "period": float(1.0 / f_peak) if f_peak > 0 else float("inf"), "df": df}


def mean_distance_by_lag(R: np.ndarray) -> np.ndarray:
    """D(tau) = mean_i R(i, i + tau), tau = 0 .. n - 1."""
    n = R.shape[0]
    return np.array([np.diagonal(R, t).mean() for t in range(n)])


def first_recurrence(Dtau: np.ndarray) -> int:
    """The lag of D(tau)'s first local minimum after it first rises (0 when there is none)."""
    for t in range(1, Dtau.size - 1):
        if Dtau[t] <= Dtau[t - 1] and Dtau[t] <= Dtau[t + 1] and Dtau[:t].max() > Dtau[t] * 1.0001:
            return t
    return 0


def best_recurrence(R: np.ndarray, window: int) -> np.ndarray:
    """max over j <= i - window of (1 - R_ij) for each state i (NaN before the first state with an earlier one
    outside the window): how well each state recurs in what came before it."""
    n = R.shape[0]
    best = np.full(n, np.nan)
    for i in range(window, n):
        best[i] = 1.0 - R[i, : i - window + 1].min()
    return best


def similarity_curve(R: np.ndarray, window: int) -> np.ndarray:
    """S(n) = mean over i <= n of best_recurrence(i) (CFDEMcoupling's average similarity)."""
    best = best_recurrence(R, window)
    out = np.full(best.size, np.nan)
    ok = ~np.isnan(best)
    out[ok] = np.cumsum(best[ok]) / np.arange(1, ok.sum() + 1)
    return out


def levelled_off(best: np.ndarray, tol: float = 0.01) -> dict:
    """Does the best earlier recurrence level off? The mean of best_recurrence over the last quarter of the
    states against the quarter before it: within ``tol``, a longer database would find no better recurrences."""
    s = best[~np.isnan(best)]
    if s.size < 8:
        return {"levelled_off": False, "last_quarter_rise": float("nan")}
    q = s.size // 4
    rise = float(s[-q:].mean() - s[-2 * q:-q].mean())
    return {"levelled_off": bool(rise <= tol), "last_quarter_rise": rise}


def taylor_time(var: float, rate_var: float) -> float:
    """sqrt(<g^2> / <dg/dt^2>) [s] (inf when the field does not change)."""
    return float(np.sqrt(var / rate_var)) if rate_var > 0 else float("inf")

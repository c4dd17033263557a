"""Transport of a solids tracer by the recorded shift operators, and the stitch at a jump.

Two solids tracers. GrainTracer (used when the database holds each grain's cell) carries the tag on the
recorded grains along a sequence and averages over a cell only at a jump. SolidsTracer (the shift form)
averages over a cell every frame; its replay error is measured in validation/rcfd/README.md. It carries
the tracer as two volumes per cell, tagged m and untagged u (both >= 0); every
operator is column-stochastic and non-negative (each column sums to one), so
- sum(m) and sum(u) are kept to round-off (no balance correction, which rCFD-PFM needs),
- c = m / (m + u) stays in [0, 1] exactly, with no CFL limit.
Frame k moves the volume by P_k (app.rcfd.database.shift_operator: the grain volume that went from
c0 to c1 over the frame, over the volume in c0): a cell's grains all carry its mean composition
(a well-mixed cell), the source of the numerical diffusion. For a uniform drift of a fraction f of
a cell per frame that is D = f (1 - f) dx^2 / (2 dt) (``shift_diffusivity``).

At a jump from state s to state j the carried volume (the grains' distribution a_s) must become
a_j, the distribution P_j was recorded from: the stitch (app.rcfd.stitch.Stitcher), column-stochastic
too, so it keeps m and u and the bounds; the volume it moves is reported.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp


def mixing_index(m: np.ndarray, u: np.ndarray) -> float:
    """M = 1 - sum |c - cbar| b / (2 cbar (1 - cbar) sum b), b = m + u, c = m / b: 0 segregated, 1 mixed
    (for a half/half split 1 - 2 sum |c - 1/2| b / sum b, the index of rCFD-PFM's fluidized-bed tutorial).
    Computed as sum |m - cbar b|, which needs no division by b."""
    b = m + u
    tot = float(b.sum())
    cbar = float(m.sum()) / tot if tot > 0 else 0.0
    if cbar <= 0 or cbar >= 1:
        return float("nan")
    return 1.0 - float(np.abs(m - cbar * b).sum()) / (2.0 * cbar * (1.0 - cbar) * tot)


def lacey_index(m: np.ndarray, b: np.ndarray, n: np.ndarray) -> np.ndarray | float:
    """Lacey's mixing index (Lacey 1954, J. Appl. Chem. 4:257), per row of (..., samples) arrays: tagged volume m,
    grain volume b and number of grains n per sample (cell). M_L = (s0^2 - s^2) / (s0^2 - sR^2) with
    s^2 = sum n (c - p)^2 / N the grain-weighted sample variance of c = m / b about p = sum m / sum b (samples of
    unequal size weighted by their grains), s0^2 = p (1 - p) the fully segregated one (every sample pure) and
    sR^2 = p (1 - p) (K - 1) / (N - 1) its exact expectation when the tags are shuffled at random over the N grains
    in K occupied samples (each sample's c hypergeometric: var p (1 - p) (N - n) / (n (N - 1))). So M_L = 0
    segregated, E[M_L] = 1 random, whatever the grains per sample; ``lacey_random_std`` gives its scatter."""
    m, b, n = (np.asarray(x, np.float64) for x in (m, b, n))
    occ = n > 0
    N, K = n.sum(-1), occ.sum(-1)
    p = m.sum(-1) / np.maximum(b.sum(-1), 1e-300)
    c = np.divide(m, b, out=np.zeros_like(m), where=occ & (b > 0))
    s2 = (n * (c - p[..., None]) ** 2).sum(-1) / np.maximum(N, 1e-300)
    s0 = p * (1.0 - p)
    sr = s0 * (K - 1) / np.maximum(N - 1, 1e-300)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = np.where((p > 0) & (p < 1) & (K > 1), (s0 - s2) / (s0 - sr), np.nan)
    return float(out) if out.ndim == 0 else out


def lacey_random_std(n: np.ndarray, p: float) -> float:
    """The standard deviation of lacey_index for tags laid at random (binomial per sample, the hypergeometric's
    correction dropped: relative O(n / N)) on samples of n grains: var s^2 = sum (mu4 - mu2^2) / n^2 / N^2 with
    mu2 = n p q, mu4 = n p q (1 + 3 (n - 2) p q) the central moments of Bin(n, p)."""
    n = np.asarray(n, np.float64)
    n = n[n > 0]
    q = 1.0 - p
    mu2 = n * p * q
    mu4 = mu2 * (1.0 + 3.0 * (n - 2.0) * p * q)
    N, K = n.sum(), n.size
    var_s2 = np.sum((mu4 - mu2 ** 2) / n ** 2) / N ** 2
    return float(np.sqrt(var_s2) / (p * q * (1.0 - (K - 1) / (N - 1))))


def mixing_index_real(tagged: np.ndarray, solid: np.ndarray) -> float:
    """The same index from the real grains: tagged volume and total grain volume per cell."""
    t = np.asarray(tagged, np.float64)
    return mixing_index(t, np.maximum(np.asarray(solid, np.float64) - t, 0.0))


def shift_diffusivity(f: float, dx: float, dt: float) -> float:
    """Numerical diffusivity [m^2/s] of a shift moving a fraction f of each cell one cell on per step dt."""
    return f * (1.0 - f) * dx * dx / (2.0 * dt)


class SolidsTracer:
    """Tagged (m) and untagged (u) grain volume per cell, moved by column-stochastic operators."""

    def __init__(self, tagged: np.ndarray, solid: np.ndarray):
        self.m = np.asarray(tagged, np.float64).copy()
        self.u = np.maximum(np.asarray(solid, np.float64) - self.m, 0.0)
        self.m0, self.u0 = self.m.sum(), self.u.sum()

    def apply(self, P: sp.csr_matrix) -> None:
        self.m = P @ self.m
        self.u = P @ self.u

    @property
    def concentration(self) -> np.ndarray:
        b = self.m + self.u
        return np.divide(self.m, b, out=np.zeros_like(b), where=b > 0)

    def mixing_index(self) -> float:
        return mixing_index(self.m, self.u)

    def drift(self) -> float:
        """Largest relative change of the tagged or untagged total since the start."""
        return max(abs(self.m.sum() - self.m0) / self.m0 if self.m0 else 0.0,
                   abs(self.u.sum() - self.u0) / self.u0 if self.u0 else 0.0)


class GrainTracer:
    """The tagged share tau in [0, 1] of each recorded grain (the database's boundary/cells).

    Along a sequence the path replays recorded frames, whose grains are the recorded grains: the tracer rides
    on them, and the tagged volume per cell at any boundary is sum vol tau over the grains in the cell -- no
    operator, no numerical diffusion, whatever the grains' motion. Only at a jump from state s to state j do
    grains lose their identity (state j's grains are not state s's): the tagged and untagged volumes per cell
    of state s are stitched onto state j's grain distribution (S, column-stochastic), and each grain of state j
    takes its cell's concentration. That is the one place where a cell is assumed well mixed, so the tracer is
    kept to round-off and stays in [0, 1] as with the cell shifts (SolidsTracer). The jump's cells may be finer
    than the index's (Engine stitches on half cells where boundary/octant is recorded): the error of a jump
    grows with the cell it averages over (validation/rcfd/README.md). ``permute`` is the other jump: grains matched
    one to one (app.rcfd.matching), no averaging at all."""

    def __init__(self, volume: np.ndarray, tau: np.ndarray, n_cells: int):
        self.vol = np.asarray(volume, np.float64)
        self.tau = np.clip(np.asarray(tau, np.float64), 0.0, 1.0).copy()
        self.n = int(n_cells)
        self.m0, self.u0 = float(np.sum(self.vol * self.tau)), float(np.sum(self.vol * (1.0 - self.tau)))

    def volumes(self, cells: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(tagged, untagged) grain volume per cell [m^3] with the grains in ``cells``."""
        return (np.bincount(cells, weights=self.vol * self.tau, minlength=self.n),
                np.bincount(cells, weights=self.vol * (1.0 - self.tau), minlength=self.n))

    def jump(self, cells_from: np.ndarray, cells_to: np.ndarray, S: sp.csr_matrix) -> None:
        """Stitch by S (on the grid the cells index: the cells, or a finer one) and give each grain its cell's
        concentration."""
        n = S.shape[0]
        m = np.bincount(cells_from, weights=self.vol * self.tau, minlength=n)
        u = np.bincount(cells_from, weights=self.vol * (1.0 - self.tau), minlength=n)
        m, u = S @ m, S @ u
        b = m + u
        c = np.divide(m, b, out=np.zeros_like(b), where=b > 0).clip(0.0, 1.0)
        self.tau = c[cells_to]

    def permute(self, perm: np.ndarray) -> None:
        """A matching jump (app.rcfd.matching): grain g of the new state takes the tag of grain perm[g] of the old
        one (matched grains have equal volumes, so the tagged volume is kept to round-off)."""
        self.tau = self.tau[perm]

    def mixing_index(self, cells: np.ndarray) -> float:
        return mixing_index(*self.volumes(cells))

    def mixing_indices(self, cells: np.ndarray, solid: np.ndarray | None = None) -> np.ndarray:
        """mixing_index at each row of ``cells`` (L, grains), the rows' states (one bincount for all of them:
        tau does not change between jumps); ``solid`` (L, n): the states' grain volume per cell, if known."""
        L = cells.shape[0]
        idx = (cells + self.n * np.arange(L)[:, None]).ravel()
        m = np.bincount(idx, weights=np.tile(self.vol * self.tau, L), minlength=L * self.n).reshape(L, self.n)
        b = solid if solid is not None else \
            np.bincount(idx, weights=np.tile(self.vol, L), minlength=L * self.n).reshape(L, self.n)
        tot = b.sum(1)
        cbar = m.sum(1) / tot
        with np.errstate(invalid="ignore", divide="ignore"):
            M = 1.0 - np.abs(m - cbar[:, None] * b).sum(1) / (2.0 * cbar * (1.0 - cbar) * tot)
        return np.where((cbar > 0) & (cbar < 1), M, np.nan)

    def drift(self) -> float:
        m, u = float(np.sum(self.vol * self.tau)), float(np.sum(self.vol * (1.0 - self.tau)))
        return max(abs(m - self.m0) / self.m0 if self.m0 else 0.0, abs(u - self.u0) / self.u0 if self.u0 else 0.0)


def _sides(axis: int) -> tuple[tuple, tuple]:
    """Index tuples of the cells left and right of the interior faces normal to ``axis`` (all but the last, all but
    the first along it)."""
    left, right = [slice(None)] * 3, [slice(None)] * 3
    left[axis], right[axis] = slice(None, -1), slice(1, None)
    return tuple(left), tuple(right)


class GasTracer:
    """A gas-phase tracer c on the recorded frame-mean face fluxes: first-order upwind finite volumes,
    (theta V eps c)^{n+1} = (theta V eps c)^n - tau sum_faces F c_upwind, with eps linear in time within the frame
    and tau a substep keeping every cell's outflow within its gas volume (Courant number <= ``cfl``; no longer than
    ``max_substep`` [s] where given: upwind's numerical diffusion falls as the Courant number rises, so two
    transports compare like for like on a common substep). Where the
    recorded fluxes satisfy continuity (analyze reports the residual), c stays within its inflow bounds. The
    bottom face takes c_in; the region's top face is the outlet (backflow takes the top cell's c); side faces are
    walls or cut faces (their flux is zero where closed). At a jump eps switches frame and c is kept: the tracer
    gas volume changes by sum c (eps_new - eps_old) theta V, reported as ``jump_mass``.

    ``scheme="fct"``: flux-corrected transport (Zalesak 1979, J. Comput. Phys. 31:335) on top of it: the
    Lax-Wendroff face value's excess over upwind, 0.5 |F| (1 - C_f) (c_R - c_L) on each interior face, is added as
    far as it makes no cell leave the range of its own and its neighbours' c and upwind result. Second order where c
    is smooth, bounded and conservative like upwind; it removes most of upwind's numerical dispersion (a plug flow's
    (sigma / tau)^2 = (1 - C) / N, tests/test_rcfd.py), which set most of the bubbling bed's RTD spread
    (validation/rcfd/README.md, 0000)."""

    SCHEMES = ("upwind", "fct")

    def __init__(self, open_volume: np.ndarray, h: float, c0: np.ndarray | float = 0.0, cfl: float = 0.9,
                 max_substep: float | None = None, scheme: str = "upwind"):
        if scheme not in self.SCHEMES:
            raise ValueError(f"gas tracer scheme {scheme!r}: one of {', '.join(self.SCHEMES)}")
        self.scheme = scheme
        self.V = np.asarray(open_volume, np.float64) * h ** 3
        self.gas = self.V > 0
        self.c = np.broadcast_to(np.asarray(c0, np.float64), self.V.shape).copy()
        self.cfl = cfl
        self.max_substep = max_substep
        self.inflow = self.outflow = self.jump_mass = 0.0
        self.outlet_flow = 0.0
        self.outlet_c = 0.0
        self.substeps = 0

    def mass(self, eps: np.ndarray) -> float:
        return float(np.sum(self.V * eps * self.c))

    @staticmethod
    def _upwind(c: np.ndarray, F: np.ndarray, axis: int, lo_ghost: np.ndarray) -> np.ndarray:
        """c on the faces normal to ``axis`` from the side the flux comes from (ghosts outside)."""
        hi = np.take(c, [c.shape[axis] - 1], axis=axis)
        ext = np.concatenate([lo_ghost, c, hi], axis=axis)
        n = ext.shape[axis]
        left = np.take(ext, range(0, n - 1), axis=axis)
        right = np.take(ext, range(1, n), axis=axis)
        return np.where(F > 0, left, right)

    def frame(self, fluxes, eps0: np.ndarray, eps1: np.ndarray, dt: float, c_in: float) -> None:
        fx, fy, fz = fluxes
        out = (np.maximum(fx[1:], 0) + np.maximum(-fx[:-1], 0) + np.maximum(fy[:, 1:], 0) + np.maximum(-fy[:, :-1], 0)
               + np.maximum(fz[:, :, 1:], 0) + np.maximum(-fz[:, :, :-1], 0))
        gv = self.V * np.minimum(eps0, eps1)
        ratio = np.where(self.gas & (gv > 0), out * dt / np.maximum(gv, 1e-300), 0.0)
        n = max(1, int(np.ceil(ratio.max() / self.cfl)))
        if self.max_substep:
            n = max(n, int(np.ceil(dt / self.max_substep - 1e-9)))
        tau = dt / n
        self.substeps += n
        for s in range(n):
            ea = eps0 + (eps1 - eps0) * (s / n)
            eb = eps0 + (eps1 - eps0) * ((s + 1) / n)
            c = self.c
            ghosts = [np.take(c, [0], axis=0), np.take(c, [0], axis=1), np.full(c[:, :, :1].shape, c_in)]
            div = np.zeros_like(c)
            for a, F in enumerate((fx, fy, fz)):
                q = F * self._upwind(c, F, a, ghosts[a])
                div += np.diff(q, axis=a)
            self.inflow += tau * c_in * float(np.maximum(fz[:, :, 0], 0).sum())
            top = fz[:, :, -1] * c[:, :, -1]  # out at the top cell's c; backflow takes it too
            self.outflow += tau * float(top.sum())
            self.outlet_flow += tau * float(np.maximum(fz[:, :, -1], 0).sum())
            self.outlet_c += tau * float((np.maximum(fz[:, :, -1], 0) * c[:, :, -1]).sum())
            mass = self.V * ea * c - tau * div
            gas_b = self.V * eb
            if self.scheme == "fct":
                mass = mass - tau * self._antidiffusion(c, mass, gas_b, (fx, fy, fz), self.V * ea, tau)
            self.c = np.where(self.gas & (gas_b > 0), mass / np.maximum(gas_b, 1e-300), 0.0)

    def _antidiffusion(self, c, mass_low, gas_b, fluxes, gas_a, tau) -> np.ndarray:
        """Zalesak's limited antidiffusive fluxes: their divergence per cell [m^3/s of tracer gas]. Interior faces
        only: the inlet and the outlet keep upwind's flux, so the accounting of what enters and leaves holds."""
        ok = self.gas & (gas_b > 0)
        low = np.where(ok, mass_low / np.maximum(gas_b, 1e-300), 0.0)  # upwind's result
        hi, lo = np.where(ok, np.maximum(c, low), -np.inf), np.where(ok, np.minimum(c, low), np.inf)
        c_max, c_min = hi.copy(), lo.copy()
        sides = [_sides(a) for a in range(3)]  # the cells left and right of each axis's interior faces
        A = []
        for (L, R), F in zip(sides, fluxes):
            Fi = F[R][L]  # the interior faces: F's 1..n-1 along the axis
            g_up = np.where(Fi > 0, gas_a[L], gas_a[R])
            courant = np.clip(np.abs(Fi) * tau / np.maximum(g_up, 1e-300), 0.0, 1.0)
            A.append(np.where(g_up > 0, 0.5 * np.abs(Fi) * (1.0 - courant) * (c[R] - c[L]), 0.0))
            for ext, src, f in ((c_max, hi, np.maximum), (c_min, lo, np.minimum)):  # the neighbours' range, in place:
                f(ext[L], src[R], out=ext[L])                                       # each cell takes both sides
                f(ext[R], src[L], out=ext[R])
        p_in, p_out = np.zeros_like(c), np.zeros_like(c)  # antidiffusive inflow and outflow of each cell
        for (L, R), Aa in zip(sides, A):
            p_in[R] += np.maximum(Aa, 0.0)
            p_out[L] += np.maximum(Aa, 0.0)
            p_in[L] += np.maximum(-Aa, 0.0)
            p_out[R] += np.maximum(-Aa, 0.0)
        room_up = np.where(ok, np.maximum(gas_b * (c_max - low), 0.0), 0.0)
        room_down = np.where(ok, np.maximum(gas_b * (low - c_min), 0.0), 0.0)
        r_up = np.where(p_in > 0, np.minimum(1.0, room_up / np.maximum(tau * p_in, 1e-300)), 0.0)
        r_down = np.where(p_out > 0, np.minimum(1.0, room_down / np.maximum(tau * p_out, 1e-300)), 0.0)
        div = np.zeros_like(c)
        for a, ((L, R), Aa) in enumerate(zip(sides, A)):
            q = Aa * np.where(Aa > 0, np.minimum(r_up[R], r_down[L]), np.minimum(r_up[L], r_down[R]))
            zero = np.zeros(q.shape[:a] + (1,) + q.shape[a + 1:])
            div += np.diff(np.concatenate([zero, q, zero], axis=a), axis=a)
        return div

    def jump(self, eps_old: np.ndarray, eps_new: np.ndarray) -> None:
        self.jump_mass += float(np.sum(self.V * (eps_new - eps_old) * self.c))

    def take_outlet(self) -> float:
        """Flow-weighted mean c through the outlet since the last call (the mixing-cup value)."""
        v = self.outlet_c / self.outlet_flow if self.outlet_flow > 0 else float("nan")
        self.outlet_c = self.outlet_flow = 0.0
        return v


def step_response(open_volume: np.ndarray, h: float, frames, dt: float, c_in: float = 1.0,
                  max_substep: float | None = None, scheme: str = "upwind") -> dict:
    """A gas tracer fed at c_in through the inlet from the first frame on (a step input), clean gas before:
    ``frames`` gives, frame by frame, (fluxes (fx, fy, fz), eps at its start, eps at its end, eps before a jump
    into it or None), all float64. F: the outlet's mixing-cup c over each frame (F[0] = 0, the step response);
    the tracer balance relative to the inflow; the volume moved at jumps; c's range; the substeps
    (``max_substep``, ``scheme``: GasTracer's)."""
    g = GasTracer(open_volume, h, 0.0, max_substep=max_substep, scheme=scheme)
    F, m_start, eps1 = [0.0], None, None
    for fluxes, eps0, eps1, before in frames:
        if m_start is None:
            m_start = g.mass(eps0)
        elif before is not None:
            g.jump(before, eps0)
        g.frame(fluxes, eps0, eps1, dt, c_in)
        F.append(g.take_outlet())
    balance = g.mass(eps1) - m_start - (g.inflow - g.outflow) - g.jump_mass
    return {"F": np.asarray(F), "c_min": float(g.c.min()), "c_max": float(g.c.max()),
            "balance_error": float(abs(balance) / max(g.inflow, 1e-300)),
            "jump_share": float(abs(g.jump_mass) / max(g.inflow, 1e-300)), "substeps": g.substeps}


def recorded_frames(db, fluxes, start: int, n: int, k: int = 1):
    """n frames of k recorded frames each from frame ``start`` on, in recorded order, as ``step_response`` takes
    them: (fluxes averaged over the k frames, eps at the first's start, eps at the last's end, None), float64. A
    recording at k times the interval holds exactly these. ``fluxes``: the database's (flux_x, flux_y, flux_z);
    ValueError where the k frames are not consecutive (a gap in the recording)."""
    for g in range(n):
        a = start + g * k
        if np.any(db.b1[a:a + k - 1] != db.b0[a + 1:a + k]):
            raise ValueError(f"frames {a}-{a + k - 1} are not consecutive (a gap in the recording)")
        yield ([f[a:a + k].astype(np.float64).mean(0) for f in fluxes], db.eps[db.b0[a]].astype(np.float64),
               db.eps[db.b1[a + k - 1]].astype(np.float64), None)


def rtd_moments(F: np.ndarray, dt: float) -> dict:
    """The residence time distribution's mean tau = int (1 - F) dt, spread sigma (int 2 t (1 - F) dt = tau^2 +
    sigma^2) and median t50 [s], from a step response given as frame means over frames of dt [s] (F[0] = 0 at the
    step, F[i] over frame i; times at the frames' middles, t50 interpolated between them), and F's last value."""
    f = np.asarray(F[1:], np.float64)
    mid = (np.arange(f.size) + 0.5) * dt
    tau = float(np.sum(1.0 - f) * dt)
    second = float(np.sum(2.0 * mid * (1.0 - f)) * dt)
    above = np.nonzero(f >= 0.5)[0]
    t50 = float("nan")
    if above.size:
        i = int(above[0])
        t0, f0 = (mid[i - 1], f[i - 1]) if i > 0 else (0.0, 0.0)
        t50 = float(t0 + (0.5 - f0) * (mid[i] - t0) / (f[i] - f0)) if f[i] > f0 else float(mid[i])
    return {"tau": tau, "sigma": float(np.sqrt(max(second - tau * tau, 0.0))), "t50": t50, "F_end": float(f[-1])}

"""Drag laws: the gas-grain momentum-exchange coefficient, one convention for all.

Owns: every drag closure fbed offers, written once as a plain formula that runs both in
Taichi kernels (``beta_func``) and on numpy arrays (``beta``, for plots and tests).

Convention (all laws):
    eps   gas volume fraction, phi = 1 - eps
    w     slip speed |u_gas - v_grain| [m/s] (interstitial gas velocity)
    Re    = eps rho_g d |w| / mu   (particle Reynolds number on the superficial slip)
    beta  Model-A momentum-exchange coefficient [kg m^-3 s^-1]: the gas feels
          beta (v_p - u) per unit volume, and one grain of volume V_p feels the drag
          F = beta V_p / phi (u - v_p), besides -V_p grad p. Each law is coded as beta / phi
          (``per_grain_volume``), which keeps its single-sphere limit where phi rounds to 0.
Model B uses beta / eps on the gas and buoyancy on the grains (see ``app.sim.coupling``).

Laws (each formula's source in its function's docstring):
    stokes, schiller_naumann, wen_yu, gidaspow, di_felice, beetstra, tang, koch_hill.
"""
import enum
import warnings

import numpy as np
import taichi as ti

# The formulas below are plain Python traced by Taichi (straight-line arithmetic, selects
# instead of branches); Taichi warns about that on every compile, harmlessly.
warnings.filterwarnings("ignore", message=".*Calling non-taichi function.*")

RE_MIN = 1e-12  # keeps 1/Re finite where the slip vanishes (beta stays finite: it has a Stokes limit)


class Law(enum.IntEnum):
    STOKES = 0
    SCHILLER_NAUMANN = 1
    WEN_YU = 2
    GIDASPOW = 3
    DI_FELICE = 4
    BEETSTRA = 5
    TANG = 6
    KOCH_HILL = 7


LAWS = {law.name.lower(): law for law in Law}


class _NumpyOps:
    sqrt = staticmethod(np.sqrt)
    exp = staticmethod(np.exp)
    log = staticmethod(np.log)
    where = staticmethod(np.where)
    maximum = staticmethod(np.maximum)


class _TaichiOps:
    sqrt = staticmethod(ti.sqrt)
    exp = staticmethod(ti.exp)
    log = staticmethod(ti.log)
    maximum = staticmethod(ti.max)

    @staticmethod
    def where(c, a, b):
        return ti.select(c, a, b)


LN10 = 2.302585092994046


def _re(eps, w, d, rho, mu, m):
    return m.maximum(eps * rho * d * w / mu, RE_MIN)


# Each law is written as g = beta / phi, the coefficient per unit grain volume (one grain of volume V_p
# feels V_p g (u - v_p)), with phi passed in rather than formed as 1 - eps: in float32 a grain that fills
# less than ~1e-7 of its cell has eps rounding to 1, and beta V_p / phi would be 0 / 0 (the dilute limit of
# every law is the single-sphere drag, which g keeps). beta itself is phi g.


def stokes(eps, phi, w, d, rho, mu, m):
    """Stokes (1851) drag on each grain, no crowding: F = 3 pi mu d w -> beta = 18 mu phi / d^2."""
    return 18.0 * mu / (d * d) + 0.0 * (w + eps + phi)


def schiller_naumann(eps, phi, w, d, rho, mu, m):
    """Single-sphere drag of Schiller & Naumann (1935), Z. Ver. Dtsch. Ing. 77:318, no crowding:
    beta = 3/4 C_D rho |w| phi / d, C_D = 24/Re (1 + 0.15 Re^0.687), 0.44 above Re = 1000
    (each grain feels C_D (pi d^2 / 8) rho w^2)."""
    re = _re(eps, w, d, rho, mu, m)
    visc = 18.0 * mu / (eps * d * d) * (1.0 + 0.15 * re ** 0.687)  # = 3/4 (24/Re)(1 + ...) rho w / d
    return m.where(re < 1000.0, visc, 0.75 * 0.44 * rho * w / d) + 0.0 * phi


def wen_yu(eps, phi, w, d, rho, mu, m):
    """Wen & Yu (1966), Chem. Eng. Prog. Symp. Ser. 62:100:
    beta = 3/4 C_D rho eps phi |w| / d eps^-2.65, C_D of Schiller-Naumann at Re = eps rho d |w|/mu.
    Written with the Stokes part apart so beta stays finite as w -> 0."""
    re = _re(eps, w, d, rho, mu, m)
    visc = 18.0 * mu / (d * d) * (1.0 + 0.15 * re ** 0.687)  # = 3/4 (24/Re) rho eps w / d (1 + ...)
    inertial = 0.75 * 0.44 * rho * eps * w / d
    return m.where(re < 1000.0, visc, inertial) * eps ** -2.65 + 0.0 * phi


def ergun(eps, phi, w, d, rho, mu, m):
    """Ergun (1952), Chem. Eng. Prog. 48:89: beta = 150 phi^2 mu / (eps d^2) + 1.75 phi rho |w| / d."""
    return 150.0 * phi * mu / (eps * d * d) + 1.75 * rho * w / d


def gidaspow(eps, phi, w, d, rho, mu, m):
    """Gidaspow (1994), Multiphase Flow and Fluidization: Ergun for eps <= 0.8, Wen-Yu above."""
    return m.where(eps <= 0.8, ergun(eps, phi, w, d, rho, mu, m), wen_yu(eps, phi, w, d, rho, mu, m))


def di_felice(eps, phi, w, d, rho, mu, m):
    """Di Felice (1994), Int. J. Multiphase Flow 20:153: one grain feels
    F = 1/2 C_D rho (pi d^2/4) eps^2 |w| w eps^-chi, C_D = (0.63 + 4.8/sqrt(Re))^2,
    chi = 3.7 - 0.65 exp(-(1.5 - log10 Re)^2 / 2)  ->  beta = 3/4 C_D rho eps^2 phi |w| eps^-chi / d.
    The C_D w product is expanded so beta stays finite as w -> 0."""
    re = _re(eps, w, d, rho, mu, m)
    lg = m.log(re) / LN10
    chi = 3.7 - 0.65 * m.exp(-(1.5 - lg) ** 2 / 2.0)
    sq = m.sqrt(re)
    # C_D w = (0.63 sqrt(Re) + 4.8)^2 / Re * w, and Re / w = eps rho d / mu
    cd_w = (0.63 * sq + 4.8) ** 2 * mu / (eps * rho * d)
    return 0.75 * cd_w * rho * eps * eps * m.exp(-chi * m.log(eps)) / d + 0.0 * phi


def beetstra(eps, phi, w, d, rho, mu, m):
    """Beetstra, van der Hoef & Kuipers (2007), AIChE J. 53:489 (monodisperse, fits of lattice-
    Boltzmann data, van der Hoef et al. 2005, J. Fluid Mech. 528:233):
    F = 10 phi/eps^2 + eps^2 (1 + 1.5 sqrt(phi))
        + 0.413 Re / (24 eps^2) (1/eps + 3 eps phi + 8.4 Re^-0.343) / (1 + 10^(3 phi) Re^-(1 + 4 phi)/2),
    normalised by the Stokes drag on the superficial slip, so beta = 18 mu eps phi F / d^2
    (as OpenFOAM's Beetstra model: K = 3/4 CdRe mu phi / d^2 with CdRe = 24 eps F)."""
    re = _re(eps, w, d, rho, mu, m)
    f0 = 10.0 * phi / (eps * eps) + eps * eps * (1.0 + 1.5 * m.sqrt(phi))
    f1 = 0.413 * re / (24.0 * eps * eps) * (1.0 / eps + 3.0 * eps * phi + 8.4 * re ** -0.343) / (
        1.0 + m.exp(3.0 * phi * LN10) * re ** (-(1.0 + 4.0 * phi) / 2.0))
    return 18.0 * mu * eps * (f0 + f1) / (d * d)


def tang(eps, phi, w, d, rho, mu, m):
    """Tang, Peters, Kuipers, Kriebitzsch & van der Hoef (2015), AIChE J. 61:688 (fixed arrays,
    Re <= 1000): F = 10 phi/eps^2 + eps^2 (1 + 1.5 sqrt(phi))
    + Re (0.11 phi (1 + phi) - 0.00456/eps^4 + (0.169 eps + 0.0644/eps^4) Re^-0.343),
    same normalisation as Beetstra: beta = 18 mu eps phi F / d^2."""
    re = _re(eps, w, d, rho, mu, m)
    e4 = eps ** 4
    f = (10.0 * phi / (eps * eps) + eps * eps * (1.0 + 1.5 * m.sqrt(phi))
         + re * (0.11 * phi * (1.0 + phi) - 0.00456 / e4 + (0.169 * eps + 0.0644 / e4) * re ** -0.343))
    return 18.0 * mu * eps * f / (d * d)


def koch_hill(eps, phi, w, d, rho, mu, m):
    """Koch & Hill (2001), Annu. Rev. Fluid Mech. 33:619, in the form CFDEM and Lethe use:
    beta = 18 mu eps^2 phi (F0 + F3 Re / 2) / d^2 with
    F0 = (1 + 3 sqrt(phi/2) + 135/64 phi ln phi + 16.14 phi) / (1 + 0.681 phi - 8.48 phi^2 + 8.16 phi^3)
    for phi < 0.4 and 10 phi / eps^3 above; F3 = 0.0673 + 0.212 phi + 0.0232 / eps^5."""
    re = _re(eps, w, d, rho, mu, m)
    ph = m.maximum(phi, 1e-12)  # phi ln phi -> 0 as phi -> 0
    f0_dilute = (1.0 + 3.0 * m.sqrt(ph / 2.0) + 135.0 / 64.0 * ph * m.log(ph) + 16.14 * ph) / (
        1.0 + 0.681 * ph - 8.48 * ph * ph + 8.16 * ph * ph * ph)
    f0 = m.where(phi < 0.4, f0_dilute, 10.0 * phi / (eps * eps * eps))
    f3 = 0.0673 + 0.212 * phi + 0.0232 / eps ** 5
    return 18.0 * mu * eps * eps * (f0 + 0.5 * f3 * re) / (d * d)


_FORMULAS = {Law.STOKES: stokes, Law.SCHILLER_NAUMANN: schiller_naumann, Law.WEN_YU: wen_yu,
             Law.GIDASPOW: gidaspow, Law.DI_FELICE: di_felice, Law.BEETSTRA: beetstra, Law.TANG: tang,
             Law.KOCH_HILL: koch_hill}


def law_of(name) -> Law:
    if isinstance(name, Law):
        return name
    try:
        return LAWS[str(name).lower()]
    except KeyError:
        raise ValueError(f"unknown drag law {name!r}; choose one of {', '.join(LAWS)}") from None


def per_grain_volume(law, eps, slip, diameter, gas_density, gas_viscosity, phi=None) -> np.ndarray:
    """beta / phi [kg m^-3 s^-1] on numpy arrays (broadcasting): one grain of volume V_p feels
    V_p times this times (u - v_p). ``phi`` (grain fraction) defaults to 1 - eps; pass it where eps
    is too close to 1 for that difference to keep its digits."""
    f = _FORMULAS[law_of(law)]
    eps = np.asarray(eps, float)
    phi = 1.0 - eps if phi is None else np.asarray(phi, float)
    w = np.abs(np.asarray(slip, float))
    out = f(eps, phi, w, np.asarray(diameter, float), np.asarray(gas_density, float),
            np.asarray(gas_viscosity, float), _NumpyOps)
    return np.asarray(out, float)


def beta(law, eps, slip, diameter, gas_density, gas_viscosity) -> np.ndarray:
    """Model-A exchange coefficient [kg m^-3 s^-1] on numpy arrays (broadcasting).

    eps: gas fraction (0 < eps < 1); slip: |u_gas - v_p| [m/s]; diameter [m];
    gas_density [kg/m^3]; gas_viscosity [Pa s]."""
    eps = np.asarray(eps, float)
    return (1.0 - eps) * per_grain_volume(law, eps, slip, diameter, gas_density, gas_viscosity)


def terminal_slip(law, diameter, grain_density: float, gas_density: float, gas_viscosity: float,
                  gravity: float) -> np.ndarray:
    """Slip speed [m/s] at which a lone grain (eps = 1) of each diameter [m] hangs in the gas by this law:
    g(w) w = (rho_p - rho_g) |gravity| per unit grain volume (drag against weight less buoyancy), solved by
    bisection to 1e-12 relative (each law's drag grows with the slip). 0 where the grain is no denser than the gas
    or there is no gravity: any gas speed then carries it."""
    d = np.atleast_1d(np.asarray(diameter, float))
    weight = max(grain_density - gas_density, 0.0) * abs(gravity)  # [N/m^3]
    if weight == 0.0:
        return np.zeros_like(d)

    def drag(w):
        return per_grain_volume(law, 1.0, w, d, gas_density, gas_viscosity, phi=0.0) * w

    lo, hi = np.zeros_like(d), np.full_like(d, 1e-6)
    for _ in range(200):  # bracket: double until the drag outweighs the grain
        short = drag(hi) < weight
        if not short.any():
            break
        lo, hi = np.where(short, hi, lo), np.where(short, 2.0 * hi, hi)
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        light = drag(mid) < weight
        lo, hi = np.where(light, mid, lo), np.where(light, hi, mid)
    return 0.5 * (lo + hi)


@ti.func
def per_grain_volume_func(law: ti.template(), eps, phi, w, d, rho, mu):
    """beta / phi inside a kernel (``law`` a compile-time Law); phi is the grain fraction, passed in."""
    return _FORMULAS[law](eps, phi, w, d, rho, mu, _TaichiOps)


@ti.func
def beta_func(law: ti.template(), eps, w, d, rho, mu):
    """The Model-A coefficient beta inside a kernel."""
    return (1.0 - eps) * per_grain_volume_func(law, eps, 1.0 - eps, w, d, rho, mu)

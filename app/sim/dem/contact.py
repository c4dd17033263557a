"""The contact law, written once: normal, tangential and rolling, for grain pairs and walls alike.

Sign conventions: ``n`` points from grain i to its partner (the other grain or the wall),
``delta`` > 0 is the overlap, ``vrel`` the velocity of i relative to the partner at the
contact point. A wall is a partner of infinite mass and radius: the caller passes r* = r_i,
m* = m_i and the wall's constants are chosen at compile time (``wall`` is static).

- normal: linear  F = k_n d + 2 zeta sqrt(m* k_n) dd/dt, or
          Hertz   F = 4/3 E* sqrt(R*) d^1.5 + alpha sqrt(m* k_n) d^0.25 dd/dt,
  clamped at F >= 0 (no attraction); zeta / alpha are solved from the restitution in
  ``app.config.derived``.
- tangential (with friction only): an incremental spring on the accumulated slip xi,
  k_t = 8 G* sqrt(R* d) (Mindlin) or the linear k_t, with damping of the same
  dimensionless strength as the normal one, capped by Coulomb |F_t| <= mu F_n (the
  spring is reset to the capped force, so sliding dissipates).
- rolling (optional): constant torque mu_r R* F_n against the relative rolling
  velocity, or ``epsd``: the elastic-plastic spring-dashpot of Ai et al. (2011) Powder
  Technol. 206:269-282 in the form of LIGGGHTS' ``rolling_model epsd``
  (src/rolling_model_epsd.h, torsionTorque off, its default); see ``rolling_torque``.
"""
import taichi as ti

from ..fields import ROLL_CONSTANT, ROLL_EPSD


@ti.func
def normal_force(model: ti.template(), wall: ti.template(), delta, ddelta, r_eff, m_eff):
    """Normal force magnitude (>= 0), the normal stiffness k_n = F_elastic / d (Hertz: 4/3 E* sqrt(R* d),
    the secant, as LIGGGHTS' normal models hand to the rolling models; linear: k_n) and the two roots the
    tangential law reuses: sqrt(R* d) and the damping factor sqrt(m* k_n) (both models).

    Written for few square roots: for equal grains R*, m* are compile-time constants, so only
    sqrt(d) and d^(1/4) are computed per contact."""
    e_star = ti.static(model.w_e_star if wall else model.e_star)
    damping = ti.static(model.w_damping if wall else model.damping)
    fn = 0.0
    k_n = 0.0
    root_rd = 0.0
    damp_root = 0.0
    if ti.static(model.hertz):
        sr = ti.sqrt(r_eff)
        sd = ti.sqrt(delta)
        kn = 4.0 / 3.0 * e_star * sr
        damp_root = ti.sqrt(m_eff * kn) * ti.sqrt(sd)
        fn = kn * delta * sd + damping * damp_root * ddelta
        k_n = kn * sd
        root_rd = sr * sd
    else:
        damp_root = ti.sqrt(m_eff * model.kn)
        fn = model.kn * delta + 2.0 * damping * damp_root * ddelta
        k_n = ti.cast(model.kn, float)
    return ti.max(fn, 0.0), k_n, root_rd, damp_root


def float32() -> bool:
    """Whether the kernels compute in float32 (read at compile time)."""
    return ti.lang.impl.current_cfg().default_fp == ti.f32


@ti.func
def tangential_force(model: ti.template(), wall: ti.template(), spring, n, vt, fn, root_rd, damp_root):
    """Tangential force on grain i and the updated slip spring (``root_rd``, ``damp_root`` from
    ``normal_force``)."""
    e_star = ti.static(model.w_e_star if wall else model.e_star)
    g_star = ti.static(model.w_g_star if wall else model.g_star)
    damping = ti.static(model.w_damping if wall else model.damping)
    mu = ti.static(model.w_mu if wall else model.mu)
    # keep the spring in the current tangent plane, at its length: times sqrt(mag2 / proj2) = sqrt(1 + y),
    # y = sn^2 / proj2. In float32 that is skipped where 1 + y rounds to 1, as it does for most contacts (the
    # contact's slow turn keeps y tiny; measured 1.08x faster substeps at 125k grains); float64 always
    # rescales (there y is rarely below its rounding, and the test costs more than it saves)
    mag2 = spring.dot(spring)
    sn = spring.dot(n)
    spring -= sn * n
    rescale = True
    if ti.static(float32()):
        rescale = sn * sn > 2.0 ** -24 * mag2
    if rescale:
        proj2 = spring.dot(spring)
        if proj2 > 1e-60:
            spring *= ti.sqrt(mag2 / proj2)
    spring += vt * model.dt
    kt = 0.0
    gamma = 0.0
    if ti.static(model.hertz):
        kt = 8.0 * g_star * root_rd
        # same dimensionless damping as the normal law: gamma_t = alpha sqrt(2/3 m* k_t), and
        # 2/3 m* k_t / (m* k_n sqrt(d)) = 4 G* / E*, so gamma_t = alpha damp_root sqrt(4 G* / E*)
        gamma = damping * damp_root * ti.static((4.0 * g_star / e_star) ** 0.5 if e_star > 0 else 0.0)
    else:
        kt = ti.cast(model.kt, float)
        gamma = 2.0 * damping * damp_root * ti.static((model.kt / model.kn) ** 0.5 if model.kn > 0 else 0.0)
    ft = -kt * spring - gamma * vt
    ft2 = ft.dot(ft)
    limit = mu * fn
    if ft2 > limit * limit:
        ftn = ti.sqrt(ft2)
        if ftn > 1e-30:
            ft *= limit / ftn
        if kt > 0:
            spring = -(ft + gamma * vt) / kt
    return ft, spring


@ti.func
def rolling_torque(model: ti.template(), wall: ti.template(), roll_spring, n, w_rel, fn, k_n, damp_root, r_eff,
                   gyration):
    """Rolling-resistance torque on grain i (its partner gets the opposite) and the updated spring torque.

    ``epsd`` is LIGGGHTS' ``rolling_model epsd`` (Ai et al. 2011: their model type C), with
    w_r = (w_i - w_j) less its component along n (torsion is not resisted) and the stored spring
    torque M_k less its component along n (it follows the tangent plane as the contact turns):
      spring     M_k <- M_k - k_r w_r dt,          k_r = 2.25 k_n mu_r^2 R*^2   (k_n from ``normal_force``)
      plastic    |M_k| <= mu_r R* F_n (full mobilisation: M_k is scaled back and there is no damping)
      dashpot    M_d = -C_r w_r below the limit,   C_r = eta_r 2 sqrt(I_r k_r),
                 I_r = 1.4 m_i r_i^2 m_j r_j^2 / (m_i r_i^2 + m_j r_j^2) (a wall: 1.4 m_i r_i^2),
    and M = M_k + M_d. eta_r is contact.rolling_damping (LIGGGHTS' coefficientRollingViscousDamping).
    Computed as C_r = 3 eta_r mu_r R* sqrt(m* k_n) sqrt(I_r / m*) from ``damp_root`` = sqrt(m* k_n) and
    ``gyration`` = sqrt(I_r / m*) (sqrt(1.4) r for equal grains and for walls: no root per contact).
    One deviation: LIGGGHTS keeps M_k as stored; dropping its normal part keeps torsion unresisted when
    the contact normal turns (a grain rolling over another; the magnitude lost is second order in the
    normal's turn per step)."""
    mu_r = ti.static(model.w_mu_roll if wall else model.mu_roll)
    tr = ti.Vector([0.0, 0.0, 0.0])
    limit = mu_r * r_eff * fn
    if ti.static(model.rolling == ROLL_CONSTANT):
        wn = w_rel.norm()
        if wn > 1e-12:
            tr = -limit * w_rel / wn
    elif ti.static(model.rolling == ROLL_EPSD):
        eta_r = ti.static(model.w_roll_damping if wall else model.roll_damping)
        w_roll = w_rel - w_rel.dot(n) * n
        roll_spring -= roll_spring.dot(n) * n
        kr = ti.static(2.25 * mu_r * mu_r) * r_eff * r_eff * k_n
        roll_spring -= kr * w_roll * model.dt
        m2 = roll_spring.dot(roll_spring)
        tr = roll_spring
        if m2 > limit * limit:
            roll_spring *= limit / ti.sqrt(m2)
            tr = roll_spring
        else:
            if ti.static(eta_r > 0):
                tr -= ti.static(3.0 * eta_r * mu_r) * r_eff * damp_root * gyration * w_roll
    return tr, roll_spring


@ti.func
def contact(model: ti.template(), wall: ti.template(), n, delta, vrel, w_rel, r_eff, m_eff, gyration, spring,
            roll_spring):
    """One contact, the whole law in order: normal, then tangential (with friction), then rolling.

    Returns the force on grain i, the tangential force (its torque is arm x F_t, with the
    caller's lever arms), the rolling torque on i, and the updated springs. ``gyration`` is
    sqrt(I_r / m*) of the elastic-plastic rolling model (see ``rolling_torque``; unused otherwise)."""
    vn = vrel.dot(n)
    fn, k_n, root_rd, damp_root = normal_force(model, wall, delta, vn, r_eff, m_eff)
    force = -fn * n
    ft = ti.Vector([0.0, 0.0, 0.0])
    tr = ti.Vector([0.0, 0.0, 0.0])
    if ti.static(model.friction):
        ft, spring = tangential_force(model, wall, spring, n, vrel - vn * n, fn, root_rd, damp_root)
        force += ft
        if ti.static(model.rolling != 0):
            tr, roll_spring = rolling_torque(model, wall, roll_spring, n, w_rel, fn, k_n, damp_root, r_eff, gyration)
    return force, ft, tr, spring, roll_spring

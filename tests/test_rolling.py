"""The elastic-plastic spring-dashpot (EPSD) rolling model against its analytic behaviour.

The model (LIGGGHTS' ``rolling_model epsd``, Ai et al. 2011 Powder Technol. 206:269): rolling spring
k_r = 2.25 k_n mu_r^2 R*^2 (k_n = F_n / d, the secant normal stiffness), plastic limit |M| <= mu_r R* F_n,
dashpot C_r = eta_r 2 sqrt(I_r k_r) below the limit (I_r = 7/5 m R^2 on a wall), no torque against the
relative rotation along the contact normal (torsion).

One 2 mm grain (2500 kg/m^3, E = 5e6 Pa) lies on the floor of a box, in float64. Its static overlap
d = (m g / (4/3 E* sqrt(R)))^(2/3) = 0.93 um sets k_n = m g / d and the elastic rolling angle
theta_y = mu_r R m g / k_r = d / (2.25 mu_r R), the rotation over which the torque builds up to the limit.
"""
import math

import numpy as np
import pytest
import taichi as ti
from scipy.optimize import curve_fit

from app.sim.dem.contact import rolling_torque
from dem_helpers import make

pytestmark = pytest.mark.verification

R, RHO, G = 1e-3, 2500.0, 9.81
FLOOR = -0.05
MASS = RHO * 4.0 / 3.0 * math.pi * R ** 3


def on_floor(mu_r, eta_r, x0=0.0, v=(0.0, 0.0, 0.0), omega=(0.0, 0.0, 0.0), model="epsd"):
    """The grain resting on the floor at its static overlap (so F_n = m g from the first step)."""
    scene, _ = make(particles={"count": 1}, vessel={"shape": "box"}, domain={"gravity": [0.0, 0.0, -G]},
                    contact={"friction": 0.5, "rolling_friction": mu_r, "rolling_model": model,
                             "rolling_damping": eta_r, "restitution": 0.5})
    delta = (MASS * G / (4.0 / 3.0 * scene.model.w_e_star * math.sqrt(R))) ** (2.0 / 3.0)
    _, dem = make(positions=[[x0, 0.0, FLOOR + R - delta]], velocities=[list(v)], omega=[list(omega)],
                  particles={"count": 1}, vessel={"shape": "box"}, domain={"gravity": [0.0, 0.0, -G]},
                  contact={"friction": 0.5, "rolling_friction": mu_r, "rolling_model": model,
                           "rolling_damping": eta_r, "restitution": 0.5})
    k_n = MASS * G / delta
    k_r = 2.25 * k_n * mu_r ** 2 * R ** 2
    return dem, delta, k_r


@pytest.mark.parametrize("eta_r", [0.0, 0.3])
def test_rolling_ball_stops_where_the_plastic_torque_says_and_springs_back_by_the_elastic_angle(eta_r):
    """Rolling at the plastic limit, the constant torque M = mu_r R m g decelerates the ball at
    a = M arm / (I + m arm^2) (arm = R - d/2, the lever arm of the friction force; 5/7 mu_r g for arm = R).
    The model adds two things at the start, while its spring builds up over theta_y (3 steps here):
    the spring torque is short of M by M theta_y / (2 w0) in angular impulse (w0 = v0 / arm), and the
    dashpot, uncapped below the limit (Ai et al.'s f = 0 form, as LIGGGHTS), adds C_r theta_y. So the ball
    stops as one decelerating at a from v_eff = v0 - 2 eta_r a / omega_r + a theta_y / (2 w0)
    (omega_r = sqrt(k_r / I_r); the dashpot's share is 2% of v0 at eta_r = 0.3): after t = v_eff / a, at
    s = v_eff^2 / (2 a). Then the spring, which holds M, lets the ball roll back by R theta_y = R M / k_r,
    where the dashpot brings it to rest (undamped, it rocks about that point).

    Tolerance on t and s: 0.5%. What the prediction leaves out is second order in the start-up
    (the velocity change during the 3 build-up steps, 0.1% of v0, times the build-up itself) and the
    step's error (symplectic Euler, 2700 steps to the stop). The spring-back: within 10% of R theta_y
    (the friction spring's release, m a / k_t = 0.06 um, is 3% of R theta_y = 2 um)."""
    mu_r, v0 = 0.2, 0.05
    dem, delta, k_r = on_floor(mu_r, eta_r, x0=-0.01)
    arm = R - 0.5 * delta
    w0 = v0 / arm
    dem.set_grains(dem.read("position"), np.array([[v0, 0, 0]]), np.array([R]), np.array([[0, w0, 0]]))
    torque = mu_r * R * MASS * G
    a = torque * arm / (0.4 * MASS * R * R + MASS * arm * arm)
    theta_y = torque / k_r
    assert theta_y == pytest.approx(delta / (2.25 * mu_r * R))
    omega_r = math.sqrt(k_r / (1.4 * MASS * R * R))
    v_eff = v0 - 2 * eta_r * a / omega_r + a * theta_y / (2 * w0)
    t_stop, s_stop = v_eff / a, v_eff ** 2 / (2 * a)

    dt, chunk = dem.m.dt, 10
    x0 = dem.read("position")[0, 0]
    t, v_prev, x_prev = 0.0, v0, x0
    while True:
        dem.advance(chunk)
        t += chunk * dt
        v, x = dem.read("velocity")[0, 0], dem.read("position")[0, 0]
        if v <= 0:
            frac = v_prev / (v_prev - v)  # the zero crossing, linearly between the two samples
            t_cross = t - chunk * dt * (1 - frac)
            x_cross = x_prev + frac * (x - x_prev)
            break
        v_prev, x_prev = v, x
        assert t < 2 * t_stop, "the ball did not stop"
    assert t_cross == pytest.approx(t_stop, rel=0.005)
    assert x_cross - x0 == pytest.approx(s_stop, rel=0.005)

    # about five rocking periods (2 pi / omega_r = 7.6 ms) after the stop
    xs, vs = [], []
    for _ in range(int(0.04 / dt) // chunk):
        dem.advance(chunk)
        xs.append(dem.read("position")[0, 0])
        vs.append(dem.read("velocity")[0, 0])
    rest = x_cross - R * theta_y
    if eta_r > 0:  # at rest where the spring is relaxed (a constant torque would make it chatter)
        assert abs(vs[-1]) < 1e-3 * v0
        assert x_cross - xs[-1] == pytest.approx(R * theta_y, rel=0.10)
    else:  # it rocks about that point, never rolling on
        xs = np.asarray(xs[len(xs) // 2:])
        assert 0.5 * (xs.max() + xs.min()) == pytest.approx(rest, abs=0.10 * R * theta_y)
        assert xs.max() - xs.min() == pytest.approx(2 * R * theta_y, rel=0.10)


@pytest.mark.parametrize("eta_r", [0.0, 0.3])
def test_rocking_ball_oscillates_at_the_rolling_springs_frequency_with_the_damping_ratio(eta_r):
    """Below the plastic limit a ball on a plane is a damped oscillator in its rolling angle: it turns
    about the contact point (I_r = 7/5 m R^2) against the spring k_r with the dashpot eta_r 2 sqrt(I_r k_r),
    so omega_0 = sqrt(k_r / I_r) and the decay rate is eta_r omega_0.

    Tolerances: 1% on omega_0 and 0.01 on the damping ratio. The friction spring's compliance turns the
    rigid roll into a two-mode system; with mu_r = 0.05 the rolling frequency (205 rad/s) lies 33 times
    below the sliding one (sqrt(7/2 k_t / m) = 6800 rad/s), which shifts it by about (1/33)^2 / 2 = 0.05%
    and lets the friction dashpot add a damping ratio of the same order. The amplitude (0.18 theta_y)
    stays elastic."""
    mu_r, w0 = 0.05, 0.3
    dem, delta, k_r = on_floor(mu_r, eta_r)
    arm = R - 0.5 * delta
    dem.set_grains(dem.read("position"), np.array([[w0 * arm, 0, 0]]), np.array([R]), np.array([[0, w0, 0]]))
    omega_0 = math.sqrt(k_r / (1.4 * MASS * R * R))
    assert w0 / omega_0 < 0.2 * (mu_r * R * MASS * G / k_r)  # elastic: the amplitude is below theta_y

    dt, chunk = dem.m.dt, 4
    periods = 3 if eta_r == 0 else 2
    n = int(periods * 2 * math.pi / omega_0 / (chunk * dt))
    ts, ws = np.empty(n), np.empty(n)
    for k in range(n):
        dem.advance(chunk)
        ts[k], ws[k] = (k + 1) * chunk * dt, dem.read("omega")[0, 1]
    # first guesses from the record itself: the zero crossings' spacing and the first peak
    crossings = ts[1:][np.sign(ws[1:]) != np.sign(ws[:-1])]
    wd_guess = math.pi / np.mean(np.diff(crossings))

    def damped(t, amp, sigma, wd, phase):
        return amp * np.exp(-sigma * t) * np.cos(wd * t + phase)

    (amp, sigma, wd, phase), _ = curve_fit(damped, ts, ws, p0=[w0, 0.0, wd_guess, 0.0])
    residual = np.sqrt(np.mean((ws - damped(ts, amp, sigma, wd, phase)) ** 2))
    assert residual < 0.01 * w0  # it is a damped oscillation
    w_nat = math.hypot(wd, sigma)
    assert w_nat == pytest.approx(omega_0, rel=0.01)
    assert sigma / w_nat == pytest.approx(eta_r, abs=0.01)


def test_spin_about_the_normal_meets_no_rolling_resistance():
    """A ball spinning about the vertical on the floor: the contact point does not move, and the relative
    rotation lies along the normal (torsion), which the model does not resist: the spin is kept. The old
    epsd resisted it with up to mu_r R m g, which would stop 50 rad/s within 0.4 R * 50 / (mu_r g) = 10 ms."""
    spin = 50.0
    dem, _, _ = on_floor(0.2, 0.3, omega=(0.0, 0.0, spin))
    dem.advance(int(0.02 / dem.m.dt))
    w = dem.read("omega")[0]
    assert w[2] == pytest.approx(spin, rel=1e-9)
    assert abs(w[0]) < 1e-9 and abs(w[1]) < 1e-9


# ------------------------------------------------------------------ the law itself, one contact at a time

# float64 spelled out: this module is imported before conftest starts Taichi in float64
@ti.kernel
def impose(model: ti.template(), steps: ti.i32, n: ti.types.vector(3, ti.f64), w: ti.types.vector(3, ti.f64),
           fn: ti.f64, k_n: ti.f64, r_eff: ti.f64, m_eff: ti.f64, inertia: ti.f64, out: ti.template()):
    """``steps`` steps of a constant relative rotation rate w at a grain-grain contact: the torque on i and
    the stored spring torque."""
    for _ in range(1):
        spring = ti.Vector([0.0, 0.0, 0.0], ti.f64)
        tr = ti.Vector([0.0, 0.0, 0.0], ti.f64)
        for _s in range(steps):
            tr, spring = rolling_torque(model, False, spring, n, w, fn, k_n, ti.sqrt(m_eff * k_n), r_eff,
                                        ti.sqrt(inertia / m_eff))
        out[0] = tr
        out[1] = spring


@pytest.fixture(scope="module")
def pair_model():
    scene, _ = make(contact={"friction": 0.5, "rolling_friction": 0.4, "rolling_model": "epsd",
                             "rolling_damping": 0.25})
    return scene.model


def run_contact(model, steps, n, w, fn=1e-3, k_n=500.0, r_eff=0.5e-3, m_eff=5e-6, inertia=4e-12):
    out = ti.Vector.field(3, ti.f64, 2)
    impose(model, steps, ti.Vector(list(n), ti.f64), ti.Vector(list(w), ti.f64), fn, k_n, r_eff, m_eff, inertia, out)
    return out.to_numpy()


def test_elastic_torque_is_the_spring_times_the_angle_plus_the_dashpot(pair_model):
    """Below the limit: M = -k_r theta - eta_r 2 sqrt(I_r k_r) w_r, theta = w_r N dt (to rounding)."""
    m = pair_model
    fn, k_n, r_eff, inertia, steps = 1e-3, 500.0, 0.5e-3, 4e-12, 50
    k_r = 2.25 * k_n * 0.4 ** 2 * r_eff ** 2
    w = np.array([0.0, 2.0, 0.0])
    theta = w * steps * m.dt
    assert k_r * np.linalg.norm(theta) < 0.5 * 0.4 * r_eff * fn  # elastic
    torque, spring = run_contact(m, steps, [0, 0, 1.0], w, fn=fn, k_n=k_n, r_eff=r_eff, inertia=inertia)
    np.testing.assert_allclose(spring, -k_r * theta, rtol=1e-12, atol=0)
    np.testing.assert_allclose(torque, -k_r * theta - 0.25 * 2 * math.sqrt(inertia * k_r) * w, rtol=1e-12, atol=0)


def test_torque_is_capped_at_the_rolling_friction_torque_without_dashpot(pair_model):
    """Past the elastic angle the spring torque stays at mu_r R* F_n, against the rolling, undamped."""
    fn, r_eff = 1e-3, 0.5e-3
    w = np.array([1.0, -3.0, 0.0]) * 20
    torque, spring = run_contact(pair_model, 400, [0, 0, 1.0], w, fn=fn, r_eff=r_eff)
    limit = 0.4 * r_eff * fn
    np.testing.assert_allclose(spring, -limit * w / np.linalg.norm(w), rtol=1e-12)
    np.testing.assert_allclose(torque, spring, rtol=0, atol=0)


def test_relative_rotation_along_the_normal_gets_no_torque(pair_model):
    """Torsion: w_r parallel to n gives nothing; a mixed w_r acts through its tangential part only."""
    n = np.array([1.0, 2.0, -2.0]) / 3.0
    tangential = np.array([2.0, -1.0, 0.0])  # orthogonal to n
    pure, _ = run_contact(pair_model, 50, n, tangential)
    torque, spring = run_contact(pair_model, 50, n, 7.0 * n)  # faster than the tangential rate, along n
    assert np.abs(torque).max() < 1e-12 * np.linalg.norm(pure) and np.abs(spring).max() < 1e-12 * np.linalg.norm(pure)
    mixed, _ = run_contact(pair_model, 50, n, tangential + 7.0 * n)
    np.testing.assert_allclose(mixed, pure, rtol=0, atol=1e-12 * np.linalg.norm(pure))
    assert abs(mixed @ n) < 1e-12 * np.linalg.norm(mixed)

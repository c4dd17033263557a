"""Verification tier: single contacts against exact results.

Tolerances: the DEM step is 1/50 of the collision time (dt_fraction 0.02, the default);
symplectic Euler's error in the rebound speed is O(dt/t_c) ~ 1%, inside the issue's 2%.
"""
import math

import numpy as np
import pytest

from dem_helpers import make

pytestmark = pytest.mark.verification

R = 1e-3
V = 0.5  # m/s impact speed


def run_until(dem, done, max_steps=200000, chunk=10):
    for _ in range(0, max_steps, chunk):
        dem.advance(chunk)
        if done():
            return
    raise AssertionError("event never happened")


@pytest.mark.parametrize("model", ["hertz_mindlin", "linear"])
@pytest.mark.parametrize("e", [0.5, 0.7, 0.9])
def test_pair_restitution(model, e):
    gap = 1e-6
    contact = {"model": model, "restitution": e, "friction": 0.0}
    if model == "linear":
        contact["normal_stiffness"] = 2000.0
    _, dem = make(positions=[[-R - gap, 0, 0], [R + gap, 0, 0]], velocities=[[V / 2, 0, 0], [-V / 2, 0, 0]],
                  contact=contact, dem={"impact_speed": V})

    def separated():
        x = dem.read("position")
        return x[1, 0] - x[0, 0] > 2 * R + 2 * gap

    run_until(dem, separated)
    v = dem.read("velocity")
    assert (v[1, 0] - v[0, 0]) / V == pytest.approx(e, rel=0.02)


@pytest.mark.parametrize("model", ["hertz_mindlin", "linear"])
@pytest.mark.parametrize("e", [0.5, 0.7, 0.9])
def test_wall_restitution(model, e):
    gap = 1e-6
    contact = {"model": model, "restitution": 0.3, "wall_restitution": e, "friction": 0.0}
    if model == "linear":
        contact["normal_stiffness"] = 2000.0
    _, dem = make(positions=[[0, 0, -0.05 + R + gap]], velocities=[[0, 0, -V]], particles={"count": 1},
                  vessel={"shape": "box"}, contact=contact, dem={"impact_speed": V})
    run_until(dem, lambda: dem.read("position")[0, 2] > -0.05 + R + gap)
    assert dem.read("velocity")[0, 2] / V == pytest.approx(e, rel=0.02)


@pytest.mark.parametrize("speed", [0.2, 2.0])
def test_hertz_contact_duration(speed):
    """Elastic (e = 1) Hertz impact lasts 2.868 (m*^2 / (R* E*^2 v))^(1/5)."""
    E, nu, rho = 5e6, 0.3, 2500.0
    _, dem = make(positions=[[-R, 0, 0], [R, 0, 0]], velocities=[[speed / 2, 0, 0], [-speed / 2, 0, 0]],
                  contact={"restitution": 1.0, "friction": 0.0, "youngs_modulus": E, "poisson_ratio": nu},
                  dem={"impact_speed": speed, "dt_fraction": 0.005})
    m = rho * 4 / 3 * math.pi * R ** 3
    e_star = E / (2 * (1 - nu ** 2))
    expected = 2.868 * ((m / 2) ** 2 / ((R / 2) * e_star ** 2 * speed)) ** 0.2
    dt = dem.m.dt
    steps = 0
    while True:
        dem.advance(1)
        x = dem.read("position")
        if x[1, 0] - x[0, 0] >= 2 * R:
            break
        steps += 1
    assert steps * dt == pytest.approx(expected, rel=0.05)


def _incline(theta_deg, mu, seconds=0.05):
    g = 9.81
    th = math.radians(theta_deg)
    grav = [g * math.sin(th), 0.0, -g * math.cos(th)]
    _, dem = make(positions=[[-0.04, 0, -0.05 + R * 0.999]], particles={"count": 1},
                  domain={"gravity": grav}, vessel={"shape": "box"},
                  contact={"friction": 0.3, "wall_friction": mu, "restitution": 0.5})
    dem.advance(int(0.005 / dem.m.dt))  # let the contact settle
    t0_v = dem.read("velocity")[0, 0]
    n = int(seconds / dem.m.dt)
    dem.advance(n)
    return (dem.read("velocity")[0, 0] - t0_v) / (n * dem.m.dt), g, th


def test_sphere_rolls_without_slipping_below_the_friction_limit():
    a, g, th = _incline(10.0, 0.3)  # tan 10 deg = 0.18 < 3.5 * 0.3
    assert a == pytest.approx(5 / 7 * g * math.sin(th), rel=0.03)


def test_sphere_slides_above_the_friction_limit():
    a, g, th = _incline(40.0, 0.1)  # tan 40 deg = 0.84 > 3.5 * 0.1
    assert a == pytest.approx(g * (math.sin(th) - 0.1 * math.cos(th)), rel=0.03)


def _momenta(dem):
    x, v, w = dem.read("position"), dem.read("velocity"), dem.read("omega")
    m, r = dem.masses(), dem.radii()
    p = (m[:, None] * v).sum(0)
    L = (np.cross(x, m[:, None] * v) + (0.4 * m * r ** 2)[:, None] * w).sum(0)
    return p, L


@pytest.mark.parametrize("model", ["hertz_mindlin", "linear"])
def test_oblique_pair_conserves_momentum(model):
    """Off-centre impact of spinning grains with friction: linear and angular momentum are conserved."""
    contact = {"model": model, "restitution": 0.7, "friction": 0.4}
    if model == "linear":
        contact["normal_stiffness"] = 2000.0
    x = [[-R - 1e-6, -0.4 * R, 0.1 * R], [R + 1e-6, 0.4 * R, -0.1 * R]]
    v = [[0.4, 0.05, 0.0], [-0.3, -0.1, 0.02]]
    w = [[0.0, 0.0, 300.0], [50.0, -80.0, 0.0]]
    _, dem = make(positions=x, velocities=v, omega=w, contact=contact, dem={"impact_speed": 1.0})
    p0, L0 = _momenta(dem)
    dem.advance(2000)
    p1, L1 = _momenta(dem)
    assert np.linalg.norm(dem.read("velocity")[0] - np.asarray(v[0])) > 0.1  # they did collide
    assert np.linalg.norm(p1 - p0) <= 1e-6 * np.linalg.norm(p0)
    assert np.linalg.norm(L1 - L0) <= 1e-6 * np.linalg.norm(L0)


def test_float32_oblique_impact_matches_float64(session_runtime_after):
    """The same off-centre impact of spinning grains with friction in float32 and float64: float32 skips the
    tangential spring's rescale where it would round to nothing (``contact.tangential_force``), so its result
    must still be float64's to float32 rounding carried through the contact (1e-5 of the largest speed and
    spin: measured 1.6e-7 and 2.8e-7, about three float32 ulps)."""
    from app.sim import runtime

    x = [[-R - 1e-6, -0.4 * R, 0.1 * R], [R + 1e-6, 0.4 * R, -0.1 * R]]
    v = [[0.4, 0.05, 0.0], [-0.3, -0.1, 0.02]]
    w = [[0.0, 0.0, 300.0], [50.0, -80.0, 0.0]]
    out = {}
    for precision in ("float32", "float64"):
        runtime.init("cpu", precision)
        _, dem = make(positions=x, velocities=v, omega=w, contact={"restitution": 0.7, "friction": 0.4},
                      dem={"impact_speed": 1.0})
        dem.advance(2000)
        out[precision] = dem.read("velocity").astype(float), dem.read("omega").astype(float)
    (v32, w32), (v64, w64) = out["float32"], out["float64"]
    assert np.linalg.norm(v64[0] - np.asarray(v[0])) > 0.1  # they did collide
    assert np.abs(v32 - v64).max() <= 1e-5 * np.abs(v64).max()
    assert np.abs(w32 - w64).max() <= 1e-5 * np.abs(w64).max()


def test_a_polydisperse_dems_masses_come_from_its_stored_radii(session_runtime_after):
    """A polydisperse DEM took its masses from the radii it was given: float64 from the filler, float32 from a
    checkpoint. In float32 the masses then differed in the last bit after a resume, and the runs parted
    (mri_small resumed at 10 ms: 17,255 velocity components differed at 20 ms). Given its own float32 radii back,
    the DEM must have the same masses to the bit. (The float64 round trip: test_dem_sort.)"""
    from app.sim import runtime

    runtime.init("cpu", "float32")
    x = [[0.0, 0.0, 0.0], [0.01, 0.0, 0.0], [0.02, 0.0, 0.0], [0.03, 0.0, 0.0]]
    radius = np.array([0.9e-3, 1.0e-3, 1.2e-3, 1.1e-3]) * (1 + 1e-9)  # no float32 number, as from the filler
    _, dem = make(positions=x, radius=radius, particles={"count": 4, "diameter": 0.0, "diameters": [1.8e-3, 2.4e-3],
                                                         "fractions": [0.5, 0.5]})
    first, stored = dem.read("mass"), dem.read("radius")
    assert stored.dtype == np.float32 and not np.array_equal(stored, radius)
    dem.set_grains(x, radius=stored)  # as a resume does, from the checkpoint's radii
    np.testing.assert_array_equal(dem.read("mass"), first)


@pytest.mark.parametrize("shape, start, velocity, through", [
    ("box", [0, 0, -0.05 + 1.5 * R], [0, 0, -2000.0], "floor"),
    ("box", [0.05 - 1.5 * R, 0, 0], [2000.0, 0, 0], "side"),
    ("cylinder", [0, 0.05 - 1.5 * R, 0], [0, 2000.0, 0], "side"),
    ("box", [0, 0, 0.05 - 1.5 * R], [0, 0, 2000.0], None),  # the top is open: the grain leaves, as by an outlet
    ("none", [0, 0, -0.05 + 1.5 * R], [0, 0, -2000.0], None),  # no vessel: every face open
    ("box", [0, 0, -0.06], [0, 0, 0.0], None),  # outside the domain at the start: removed, through no wall
])
def test_a_grain_driven_through_a_wall_is_counted_apart_from_one_leaving_by_an_open_face(shape, start, velocity,
                                                                                       through):
    """A grain at 2000 m/s moves ~1 mm a DEM step and crosses the floor or a side wall in two (the Hertz force at
    half a radius of overlap changes its speed by ~0.1 m/s a step). Such grains were removed as if they had left by
    an outlet, and the run said "done" (domain.gravity = 1e6 m/s^2 lost settle's 300 grains through the floor).
    The DEM now counts the grains that leave by a face the walls seal (the guard stops the run on them:
    test_cli)."""
    vessel = {"shape": shape, "radius": 0.05, "center": [0.0, 0.0]} if shape == "cylinder" else {"shape": shape}
    _, dem = make(positions=[start], velocities=[velocity], particles={"count": 1}, vessel=vessel)
    dem.advance(20)
    d = dem.diagnostics()
    assert d["grains_removed"] == 1 and d["grains_through_walls"] == (1 if through else 0), (through, d)


@pytest.mark.parametrize("start, velocity, through", [
    ([0, 0, -0.05 + 1.5 * R], [0, 0, -2000.0], True),  # the cup's floor
    ([0.05 - 1.5 * R, 0, 0], [2000.0, 0, 0], True),  # its side
    ([0, 0, 0.05 - 1.5 * R], [0, 0, 2000.0], False),  # its open top
])
def test_a_grain_driven_through_a_sampled_vessel_is_counted(tmp_path, start, velocity, through):
    """A sampled vessel sealed no face (its openings were not read off its clearance): a grain driven through its
    floor or side was removed as if it had left by an outlet, uncounted. A face on which the clearance is nowhere
    positive is sealed now; the cup's open top is not."""
    h = 2.5e-3
    ax = np.arange(-0.05, 0.05 + h / 2, h)
    X, Y, Z = np.meshgrid(ax, ax, ax, indexing="ij")
    np.savez(tmp_path / "cup.npz", values=np.minimum(np.minimum(0.05 - abs(X), 0.05 - abs(Y)), Z + 0.05),
             origin=[ax[0]] * 3, spacing=h)
    _, dem = make(positions=[start], velocities=[velocity], particles={"count": 1},
                  vessel={"shape": "sampled", "sdf_file": str(tmp_path / "cup.npz")})
    dem.advance(20)
    d = dem.diagnostics()
    assert d["grains_removed"] == 1 and d["grains_through_walls"] == (1 if through else 0), (through, d)


def test_the_faces_a_vessel_seals():
    """geometry.sealed_faces: which of x-, x+, y-, y+, z-, z+ a grain can leave only through a wall."""
    from app.sim import geometry

    lo, hi = (-1.0, -1.0, 0.0), (1.0, 1.0, 2.0)
    floor = geometry.PlaneWall((0.0, 0.0, 0.5), (0.0, 0.0, 1.0))
    lid = geometry.PlaneWall((0.0, 0.0, 1.5), (0.0, 0.0, -1.0))
    assert geometry.sealed_faces([floor], lo, hi) == (False,) * 4 + (True, False)
    assert geometry.sealed_faces([floor, lid], lo, hi) == (False,) * 4 + (True, True)
    assert geometry.sealed_faces([geometry.CylinderWall((0.0, 0.0), 0.9)], lo, hi) == (True,) * 4 + (False,) * 2
    assert geometry.sealed_faces([geometry.CylinderWall((0.0, 0.0), 1.1)], lo, hi) == (False,) * 6  # wider
    assert geometry.sealed_faces(geometry.box_walls(lo, hi, faces=("x-", "x+")), lo, hi) == (True, True) + (False,) * 4
    tilted = geometry.PlaneWall((0.0, 0.0, 0.5), (0.0, 0.6, 0.8))
    assert geometry.sealed_faces([tilted, geometry.PlaneWall((0.0, 0.0, 3.0), (0.0, 0.0, -1.0))], lo, hi) == \
        (False,) * 6  # tilted, and a lid above the domain
    # a sampled cylinder with a floor at z = 0.5 (nodes every 0.25): its side lies inside this domain, outside a
    # narrower one; its clearance is largest between nodes nowhere, so the nodes' lines give the faces' largest
    ax, zs = np.arange(-1.0, 1.01, 0.25), np.arange(0.0, 2.01, 0.25)
    X, Y, Z = np.meshgrid(ax, ax, zs, indexing="ij")
    cyl = geometry.SampledWall(np.minimum(0.9 - np.hypot(X, Y), Z - 0.5), (-1.0, -1.0, 0.0), 0.25)
    assert geometry.sealed_faces([cyl], lo, hi) == (True,) * 4 + (True, False)
    assert geometry.sealed_faces([cyl], (-0.5, -0.5, 0.0), (0.5, 0.5, 2.0)) == (False,) * 4 + (True, False)
    assert geometry.sampled_face_max(cyl, lo, hi, 5) == pytest.approx(0.9)  # the top: open over the axis

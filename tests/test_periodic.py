"""Periodic faces for the grains (issue 19's laterally periodic bed): a grain that leaves by one face enters by
the other, contacts and their springs reach across (the nearest image), the neighbour list wraps, and the
coupling's deposit and smoothing wrap with the gas grid; set-ups the DEM cannot wrap are refused with the key
to change."""
import dataclasses

import numpy as np
import pytest

from app.config import ConfigError
from app.scene import build_simulation, place_grains
from app.sim.dem import DemSolver

from dem_helpers import grains, scene_of

pytestmark = pytest.mark.verification

PERIODIC_XY = {"x-": {"kind": "periodic"}, "x+": {"kind": "periodic"}, "y-": {"kind": "periodic"},
               "y+": {"kind": "periodic"}}


def dem_of(initial, **changes):
    scene = scene_of(initial=initial, **changes)
    dem = DemSolver(scene.model)
    place_grains(dem, scene.initial)
    return scene, dem


def test_a_pair_crossing_a_periodic_face_mid_contact_moves_as_the_same_pair_inside():
    """Two frictional grains collide obliquely while the first crosses the x+ face (it re-enters at x-): every
    step, their separation, velocities and spins equal those of the same pair placed in the middle of a box with
    no periodic face, to rounding. Were the contact (or its tangential spring) lost at the crossing, the
    spins would differ by their whole size; a list that did not wrap would find no contact at all."""
    r, hi, period = 1e-3, 0.05, 0.1
    a = np.array([hi - 2e-5, 1e-3, 0.0])  # 20 um inside the x+ face, moving out of it at 0.6 m/s
    b = a + [2 * r * 0.999, 0.0, 0.0]     # beyond the face: placed at its image near x-
    v = [[0.6, 0.01, 0.0], [0.5, -0.01, 0.0]]
    _, wrapped = dem_of(grains([a, b], r, v), contact={"friction": 0.5}, boundary=PERIODIC_XY)
    shift = np.array([hi, 0.0, 0.0])
    _, inside = dem_of(grains([a - shift, b - shift], r, v), contact={"friction": 0.5})
    assert wrapped.m.periodic == (True, True, False) and inside.m.periodic == (False, False, False)
    crossed_in_contact = False
    for step in range(40):
        wrapped.advance(5)
        inside.advance(5)
        xw, xi = wrapped.read("position"), inside.read("position")
        assert np.all((xw[:, 0] >= -hi) & (xw[:, 0] < hi))  # kept inside the period
        # the same place modulo the period, to rounding of the positions (1e-16 m)
        np.testing.assert_allclose((xw - xi - shift + period / 2) % period - period / 2, 0, atol=1e-13)
        vw, vi = wrapped.read("velocity"), inside.read("velocity")
        ww, wi = wrapped.read("omega"), inside.read("omega")
        np.testing.assert_allclose(vw, vi, rtol=0, atol=1e-12)
        np.testing.assert_allclose(ww, wi, rtol=1e-9, atol=1e-9)
        if step == 0:  # the first grain has crossed and the contact is still on
            crossed_in_contact = xw[0, 0] < 0 and wrapped.diagnostics()["contacts"] == 1
    assert crossed_in_contact
    assert abs(ww[0, 2]) > 1.0  # the oblique contact spun them up (rad/s)
    assert vw[0, 0] < 0.51 and vw[1, 0] > 0.59  # and exchanged their x momentum


def random_box(n=500, seed=3, polydisperse=True):
    """n grains placed at random through a 12 x 12 x 6 mm slice of a box periodic in x and y (each pair at
    least 0.9 of its contact distance apart through the faces, so many touch, some across a face), drifting
    across the faces, no gravity; the z faces are far (nothing leaves)."""
    rng = np.random.default_rng(seed)
    d = np.array([0.8e-3, 1.0e-3, 1.3e-3])
    radius = rng.choice(d, n) / 2 if polydisperse else np.full(n, 0.5e-3)
    pos = np.empty((n, 3))
    k = 0
    while k < n:
        p = rng.uniform([-6e-3, -6e-3, -3e-3], [6e-3, 6e-3, 3e-3])
        sep = pos[:k] - p
        sep[:, :2] -= 12e-3 * np.round(sep[:, :2] / 12e-3)
        if np.all(np.linalg.norm(sep, axis=1) >= 0.9 * (radius[:k] + radius[k])):
            pos[k] = p
            k += 1
    vel = rng.normal(0, 0.05, (n, 3)) + [0.5, -0.3, 0.0]
    vel[:, 2] = 0.0
    particles = {"diameter": 0.0, "diameters": d.tolist(), "fractions": [1.0, 1.0, 1.0], "count": n} \
        if polydisperse else {"diameter": 1e-3, "count": n}
    return dem_of(grains(pos, radius, vel), particles=particles, boundary=PERIODIC_XY,
                  domain={"lo": [-6e-3, -6e-3, -0.05], "hi": [6e-3, 6e-3, 0.05], "gravity": [0.0, 0.0, 0.0]},
                  contact={"friction": 0.3, "youngs_modulus": 1e6})


def touching_pairs(x, radius, period=12e-3):
    """Brute force: pairs closer than the sum of radii, each through its nearest image in x and y (None: no
    images)."""
    d = x[None, :, :] - x[:, None, :]
    if period is not None:
        d[..., :2] -= period * np.round(d[..., :2] / period)
    dist = np.linalg.norm(d, axis=-1)
    touch = dist < radius[None, :] + radius[:, None]
    return int(np.triu(touch, 1).sum())


@pytest.mark.parametrize("polydisperse", [False, True])
def test_contacts_across_periodic_faces_are_those_of_the_nearest_images(polydisperse):
    scene, dem = random_box(polydisperse=polydisperse)
    radius = dem.radii()
    dem.advance(1)
    x = dem.read("position")
    expected = touching_pairs(x, radius)
    through_faces = touching_pairs(x, radius) - touching_pairs(x, radius, period=None)
    assert through_faces > 10  # the test has pairs that meet only across a face
    assert dem.diagnostics()["contacts"] == expected


def test_momentum_is_kept_while_grains_cross_periodic_faces():
    """Pair forces are equal and opposite through the faces too: with no wall and no gravity the total
    momentum stays what it was (float64 rounding) while every grain crosses faces and keeps colliding."""
    scene, dem = random_box()
    m = dem.masses()[:, None]
    p0 = (m * dem.read("velocity")).sum(0)
    x0 = dem.read("position")
    dem.advance(400)
    d = dem.diagnostics()
    assert d["grains_removed"] == 0 and d["contacts"] > 20
    moved = np.abs(dem.read("position") - x0)[:, 0].max()
    assert moved > 6e-3  # grains have wrapped (a jump of ~ a period between two reads)
    p1 = (m * dem.read("velocity")).sum(0)
    np.testing.assert_allclose(p1, p0, rtol=0, atol=1e-12 * np.abs(m * dem.read("velocity")).sum())


def test_sorts_and_a_resume_across_periodic_faces_change_nothing():
    """Grains re-ordered by cell at every list build (the wrapped cells) follow the same paths by grain id as
    unsorted ones, to rounding; a checkpoint taken while grains wrap resumes bit for bit."""
    scene, _ = random_box()
    init = scene.initial

    def solver(sort_interval):
        dem = DemSolver(dataclasses.replace(scene.model, sort_interval=sort_interval, sort_min_grains=0))
        place_grains(dem, init)
        return dem

    sorted_, plain = solver(1), solver(0)
    for dem in (sorted_, plain):
        dem.advance(300)
    a, b = sorted_.state_arrays(), plain.state_arrays()
    assert (a["grain_order"] != np.arange(len(a["grain_order"]))).mean() > 0.5 and sorted_.nlist.builds >= 3
    period = 12e-3
    dx = (a["position"] - b["position"] + period / 2) % period - period / 2  # the same place modulo the period
    assert np.abs(dx[:, :2]).max() < 1e-12 and np.abs(dx[:, 2]).max() < 1e-12
    assert np.abs(a["velocity"] - b["velocity"]).max() < 1e-9 * np.abs(b["velocity"]).max()
    resumed = DemSolver(sorted_.m)
    resumed.load_state_arrays(a)
    sorted_.advance(200)
    resumed.advance(200)
    a, c = sorted_.state_arrays(), resumed.state_arrays()
    assert not [k for k in a if not np.array_equal(a[k], c[k])]


def coupled_lattice(periodic: bool):
    """A 3-D lattice of grains, one every 1.5 mm, filling a 12 x 12 mm box of 2 mm gas cells from 2 to 10 mm
    high, shifted so that no grain sits on a cell centre: with wrapped corners every column of cells is alike."""
    h, s = 2e-3, 1.5e-3
    xs = np.arange(-6e-3 + 0.3e-3, 6e-3, s)
    zs = np.arange(2e-3 + 0.3e-3, 10e-3, s)
    X, Y, Z = np.meshgrid(xs, xs, zs, indexing="ij")
    pos = np.column_stack([X.ravel(), Y.ravel(), Z.ravel()])
    boundary = {"bottom": {"kind": "velocity_inlet", "velocity": [0.0, 0.0, 0.2]}, "top": "pressure_outlet"}
    if periodic:
        boundary = {**PERIODIC_XY, **boundary}
    scene = scene_of(grains(pos, 0.4e-3), particles={"diameter": 0.8e-3, "count": len(pos)},
                     domain={"lo": [-6e-3, -6e-3, 0.0], "hi": [6e-3, 6e-3, 0.024], "gravity": [0.0, 0.0, -9.81]},
                     vessel={"shape": "box"}, gas={"cell_size": h}, coupling={"smoothing_width": 1.5e-3},
                     boundary=boundary)
    sim = build_simulation(scene)
    sim.coupler.deposit(1e-3)
    return sim, 4 / 3 * np.pi * 0.4e-3 ** 3 * len(pos)


def test_deposit_and_smoothing_wrap_across_periodic_faces():
    """The lattice's volume, spread with the trilinear weights and smoothed, is the same in every column of
    cells when the corners and the smoothing's neighbours wrap (the lattice repeats every 3 cells, the box
    is 6 cells: two periods of the pattern). In the walled box the first and last columns differ."""
    sim, volume = coupled_lattice(True)
    assert sim.coupler.deposited_volume() == pytest.approx(volume, rel=1e-12)
    solid = sim.coupler.cf.solid.to_numpy()
    assert solid[:, :, 2:4].min() > 0
    for shift in (3,):  # the pattern's period in cells
        np.testing.assert_allclose(np.roll(solid, shift, axis=0), solid, rtol=1e-10, atol=1e-12 * solid.max())
        np.testing.assert_allclose(np.roll(solid, shift, axis=1), solid, rtol=1e-10, atol=1e-12 * solid.max())
    walled, _ = coupled_lattice(False)
    closed = walled.coupler.cf.solid.to_numpy()
    assert np.abs(np.roll(closed, 3, axis=0) - closed).max() > 1e-3 * closed.max()


@pytest.mark.parametrize("changes, key", [
    ({"vessel": {"shape": "cylinder", "radius": 0.04}}, "vessel.shape"),
    ({"domain": {"lo": [-2e-3, -0.05, -0.05], "hi": [2e-3, 0.05, 0.05]}}, "domain.hi"),
    ({"boundary": {**PERIODIC_XY, "z-": {"kind": "periodic"}, "z+": {"kind": "periodic"}}}, "boundary.z-"),
    ({"boundary": {"x-": {"kind": "periodic"}}}, "boundary.x-"),
    ({"boundary": {**PERIODIC_XY, "top": "pressure_outlet"}}, "boundary.z+"),
])
def test_what_the_grains_cannot_wrap_is_refused_naming_the_key(changes, key):
    """A cylinder cannot be periodic; a period under 3 cut-offs (2 mm grains: 3 x 2.3 mm); grains cannot wrap
    vertically (the floor holds the bed); faces come in pairs; without gas only periodic faces mean something."""
    changes = {"boundary": PERIODIC_XY, **changes}
    with pytest.raises(ConfigError) as err:
        scene_of(**changes)
    assert err.value.key == key, err.value

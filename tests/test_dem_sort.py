"""Memory order follows space: the DEM re-orders its grains by cell, and nothing outside it can tell.

Sorting changes only the order of floating-point sums (a grain's contacts are visited in another order),
so a sorted run matches an unsorted one to rounding, amplified by the contacts over the run; a dropped
spring, a partner renamed wrong or a grain's arrays left behind would give differences of the order of
the motion itself. A sorted run resumed from its checkpoint repeats the uninterrupted one bit for bit
(memory order is part of the checkpoint)."""
import dataclasses

import numpy as np
import pytest

from dem_helpers import make
from app.sim.dem import DemSolver

pytestmark = pytest.mark.verification

N = 300
CONTACT = {"friction": 0.4, "rolling_friction": 0.05, "rolling_model": "epsd"}


def scrambled_bed(poly: bool, half_width: float = 0.05):
    """300 grains in a box on a jittered lattice, ids shuffled (memory order has nothing to do with
    space), moving fast enough to rebuild the list every few substeps; tri-disperse when ``poly``. The box spans
    +-``half_width`` [m] across and up to ``half_width`` (the default is dem_helpers' domain)."""
    rng = np.random.default_rng(7)
    side = 7
    grid = np.stack(np.meshgrid(*[np.arange(side)] * 3, indexing="ij"), -1).reshape(-1, 3)[:N]
    pos = (grid - side / 2) * 2.6e-3 + rng.uniform(-1e-4, 1e-4, (N, 3))
    pos = pos[rng.permutation(N)]
    vel = rng.normal(0.0, 0.5, (N, 3))
    radius = rng.choice([0.9e-3, 1.0e-3, 1.2e-3], N) if poly else np.full(N, 1e-3)
    particles = {"count": N}
    if poly:
        particles.update(diameter=0.0, diameters=[1.8e-3, 2.0e-3, 2.4e-3], fractions=[0.34, 0.33, 0.33])
    # the floor just below the lowest grains: they land on it within the run (wall springs)
    domain = {"gravity": [0.0, 0.0, -9.81], "lo": [-half_width, -half_width, -0.0106], "hi": [half_width] * 3}
    scene, _ = make(domain=domain, particles=particles, vessel={"shape": "box"}, contact=CONTACT)
    return scene, pos, vel, radius


def solver(scene, pos, vel, radius, sort_interval):
    model = dataclasses.replace(scene.model, sort_interval=sort_interval, sort_min_grains=0, serial=True)
    dem = DemSolver(model)
    dem.set_grains(pos, vel, radius)
    return dem


def run(dem, fluid_steps, substeps=10):
    for _ in range(fluid_steps):
        dem.advance(substeps)


@pytest.mark.parametrize("poly", [False, True], ids=["monodisperse", "tri-disperse"])
def test_sorted_run_matches_unsorted_by_grain_id(poly):
    scene, pos, vel, radius = scrambled_bed(poly)
    sorted_, plain = solver(scene, pos, vel, radius, 1), solver(scene, pos, vel, radius, 0)
    assert sorted_.m.sorts and not plain.m.sorts
    run(sorted_, 30)
    run(plain, 30)
    a, b = sorted_.state_arrays(), plain.state_arrays()
    order = a["grain_order"]
    assert (order != np.arange(N)).mean() > 0.9  # really re-ordered ...
    assert sorted_.nlist.builds >= 10  # ... many times over
    assert sorted_.nlist.builds == plain.nlist.builds  # the list is carried over a sort, not rebuilt
    for key, scale in (("position", 0.01), ("velocity", np.abs(b["velocity"]).max()),
                       ("omega", np.abs(b["omega"]).max())):
        assert np.abs(a[key] - b[key]).max() < 1e-9 * scale, key
    np.testing.assert_array_equal(a["alive"], b["alive"])
    # the same pairs in each grain's row, named by grain id
    np.testing.assert_array_equal(a["nl_count"], b["nl_count"])
    for i in range(N):
        c = a["nl_count"][i]
        np.testing.assert_array_equal(np.sort(a["nl_partner"][:c, i]), np.sort(b["nl_partner"][:c, i]))
    # the springs of each grain, whatever history slot each contact took
    for key in ("tangential", "rolling", "wall_tangential", "wall_rolling"):
        sa, sb = (np.sort(np.linalg.norm(x[key], axis=-1), axis=0) for x in (a, b))
        assert sb.max() > 0 and np.abs(sa - sb).max() < 1e-9 * sb.max(), key
    # every reader outside the DEM sees grain-id order
    np.testing.assert_array_equal(sorted_.read("position"), a["position"])
    np.testing.assert_array_equal(sorted_.read("omega"), a["omega"])
    np.testing.assert_array_equal(sorted_.radii(), radius)
    np.testing.assert_array_equal(sorted_.masses(), plain.masses())
    da, db = sorted_.diagnostics(), plain.diagnostics()
    assert da["contacts"] == db["contacts"] > 0
    assert abs(da["kinetic_energy"] - db["kinetic_energy"]) < 1e-9 * db["kinetic_energy"]


def test_sorted_checkpoint_round_trips_and_resumes_bit_for_bit():
    scene, pos, vel, radius = scrambled_bed(True)
    straight = solver(scene, pos, vel, radius, 2)
    run(straight, 12)
    saved = straight.state_arrays()
    assert (saved["grain_order"] != np.arange(N)).any()
    resumed = DemSolver(straight.m)
    resumed.load_state_arrays(saved)
    again = resumed.state_arrays()  # what was saved comes back, every array
    assert set(again) == set(saved)
    assert not [k for k in saved if not np.array_equal(saved[k], again[k])]
    run(straight, 15)
    run(resumed, 15)
    a, b = straight.state_arrays(), resumed.state_arrays()
    assert (a["grain_order"] != saved["grain_order"]).any()  # sorted again after the checkpoint
    assert not [k for k in a if not np.array_equal(a[k], b[k])]


def test_set_grains_takes_grain_id_order_after_a_sort():
    scene, pos, vel, radius = scrambled_bed(False)
    dem = solver(scene, pos, vel, radius, 1)
    run(dem, 3)
    x = dem.read("position")
    dem.set_grains(x, np.zeros((N, 3)), radius)
    np.testing.assert_array_equal(dem.read("position"), x)
    dem.advance(1)  # sorted again at once: still by id
    assert np.abs(dem.read("position") - x).max() < 1e-4


@pytest.mark.parametrize("poly", [False, True], ids=["monodisperse", "tri-disperse"])
def test_rows_run_nearest_first_and_keep_that_order_through_sorts(poly):
    """Each row is built in ascending d^2 - (r_i + r_j)^2 at the build's positions (x_ref), so a row's touching
    pairs lead it (what makes the pair loop's touching test predictable); a sort by cell keeps the order. The
    kernels compute the key in float32: 1e-5 of (r_i + r_j)^2 is over 100 of its roundings (6e-8 each)."""
    scene, pos, vel, radius = scrambled_bed(poly)
    dem = solver(scene, pos, vel, radius, 1)
    run(dem, 12)
    a = dem.state_arrays()
    assert dem.nlist.builds >= 4 and (a["grain_order"] != np.arange(N)).mean() > 0.9
    x, r = a["nl_x_ref"].astype(np.float64), a["radius"]
    rows = 0
    for i in range(N):
        row = a["nl_partner"][: a["nl_count"][i], i]
        rs2 = (r[i] + r[row]) ** 2
        key = ((x[row] - x[i]) ** 2).sum(axis=1) - rs2
        assert (np.diff(key) >= -1e-5 * rs2[1:]).all(), (i, key)
        rows += len(row) > 1
    assert rows >= 40  # rows with an order to check: 52 and 82 (in cell order, as built before, 37 and 49 of them fail)


def test_tracked_cells_are_the_rcfd_probes_floors_by_grain_id_after_sorts():
    """``DemSolver.tracked_cells`` (the rCFD probe's frame on the device) against the probe's own numpy floors
    (``RcfdRecorder.cells_and_octants``) and tag (``tag_mask``) on the positions read back, for a tracked subset
    of the grains in a scrambled order, after the DEM has re-ordered them by cell: the same integers. Cells of 1.3 mm
    (a few grains each, and grains above the grid clip to its top layer); a third of the grains placed exactly on
    half-cell faces, where a floor taken in another precision or by a reciprocal would land one off; a grain
    removed reads alive False."""
    from app.rcfd.database import parse_tag, tag_mask
    from app.rcfd_probe import RcfdRecorder

    scene, pos, vel, radius = scrambled_bed(True)
    dem = solver(scene, pos, vel, radius, 1)
    run(dem, 6)
    assert (dem.state_arrays()["grain_order"] != np.arange(N)).mean() > 0.9
    rec = RcfdRecorder.__new__(RcfdRecorder)
    rec.origin, rec.h, rec.shape = np.array([-0.012, -0.0117, -0.0106]), 1.3e-3, (18, 18, 12)
    x = dem.read("position")
    on_face = np.arange(N) % 3 == 0  # exactly on a half-cell face along z (in the run's precision)
    x[on_face, 2] = rec.origin[2] + 0.5 * rec.h * (np.arange(N)[on_face] % 30)
    alive = np.ones(N, bool)
    alive[5] = False
    dem.set_grains(x, radius=radius, alive=alive)
    dem.advance(1)  # sorted again at once
    x = dem.read("position")
    ids = np.random.default_rng(3).permutation(N)[: N - 40]
    assert 5 in ids
    for tag in ("z<0.0", "x>=0.001"):
        dem.track(ids)
        cells, octant, live, now = dem.tracked_cells(rec.origin, rec.h, rec.shape, parse_tag(tag))
        want_cells, want_octant = rec.cells_and_octants(x[ids])
        np.testing.assert_array_equal(cells, want_cells)
        np.testing.assert_array_equal(octant, want_octant)
        np.testing.assert_array_equal(now, tag_mask(tag, x[ids]))
        np.testing.assert_array_equal(live, dem.read("alive").astype(bool)[ids])
        assert 0 < now.sum() < ids.size and (~live).sum() == 1 and not live[list(ids).index(5)]
    assert (want_cells // 12 % 18 == 17).any() or (want_cells % 12 == 11).any()  # some clipped to the grid's edge

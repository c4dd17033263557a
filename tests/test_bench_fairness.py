"""The fbed / LIGGGHTS benchmark's fairness helpers (app/bench/common.py, liggghts_pour.py).

The contact count both codes are judged by is checked against a brute-force count; the run order is
the documented A B A B; and, where LIGGGHTS is installed, a small poured bed checks that the helper
counts what LIGGGHTS itself counts and that float32 rounding of a settled bed loses no contact (the
touching lattice the benchmark used before lost half of them).
"""
import pathlib
import sys

import numpy as np
import pytest

from app.bench.common import count_contacts, interleaved, median_ratio

pytestmark = pytest.mark.bench

BENCH = pathlib.Path(__file__).resolve().parents[1] / "benchmarks"
sys.path.insert(0, str(BENCH / "liggghts"))  # liggghts_pour: a script of benchmarks/liggghts/


def brute_force(pos, r, R, floor_z):
    n = len(pos)
    pairs = sum(1 for i in range(n) for j in range(i + 1, n)
                if np.linalg.norm(pos[i] - pos[j]) < r[i] + r[j])
    floor = int(np.sum(pos[:, 2] - r < floor_z))
    cyl = int(np.sum(np.hypot(pos[:, 0], pos[:, 1]) + r > R))
    return pairs, floor, cyl


def test_count_contacts_known_configuration():
    # a: b overlaps by 1 um, b: c are 1 um apart, a touches the floor (by 1 um), c the cylinder (R = 10 mm)
    r = 1e-3
    a = [0.0, 0.0, r - 1e-6]
    b = [2 * r - 1e-6, 0.0, r - 1e-6]
    c = [4 * r, 0.0, r + 0.5e-3]
    c[0] = b[0] + np.sqrt((2 * r + 1e-6) ** 2 - (c[2] - b[2]) ** 2)
    R = c[0] + r - 1e-7
    got = count_contacts(np.array([a, b, c]), r, cylinder_radius=R, floor_z=0.0)
    assert got == {"pairs": 1, "floor": 2, "cylinder": 1, "walls": 3, "total": 4}


def test_count_contacts_matches_brute_force_polydisperse():
    rng = np.random.default_rng(3)
    n = 300
    r = rng.uniform(0.8e-3, 1.2e-3, n)
    R = 8e-3
    rad = rng.uniform(0, R, n) ** 0.5 * R ** 0.5
    phi = rng.uniform(0, 2 * np.pi, n)
    pos = np.column_stack([rad * np.cos(phi), rad * np.sin(phi), rng.uniform(0, 20e-3, n)])
    pairs, floor, cyl = brute_force(pos, r, R, 0.0)
    assert pairs > 100 and floor > 5 and cyl > 5  # a test with contacts of every kind
    got = count_contacts(pos, r, cylinder_radius=R, floor_z=0.0)
    assert (got["pairs"], got["floor"], got["cylinder"]) == (pairs, floor, cyl)


def test_interleaved_order_and_pair_ratios():
    assert interleaved("fbed", "liggghts", 3) == [(0, "fbed"), (0, "liggghts"), (1, "fbed"), (1, "liggghts"),
                                                  (2, "fbed"), (2, "liggghts")]
    # ratios are taken pair by pair: a drift that slows one pair's both runs cancels
    assert median_ratio([2.0, 4.0, 6.0], [1.0, 2.0, 2.0]) == (2.0, 2.0, 3.0)
    with pytest.raises(ValueError):
        median_ratio([1.0], [1.0, 2.0])


def test_settled_bed_counts_agree_with_liggghts_and_survive_float32(tmp_path):
    import liggghts_pour

    if not liggghts_pour.available():
        pytest.skip("LIGGGHTS 3.8 is not installed here (the CI image has none; apt-get install -y liggghts "
                    "to run this check)")
    d = 2e-3
    bed = liggghts_pour.pour_bed(300, d, 2500.0, 5e6, 0.3, 0.5, 0.5, cache_dir=str(tmp_path))
    pos, R = bed["position"], bed["cylinder_radius"]
    c64 = count_contacts(pos, d / 2, cylinder_radius=R, floor_z=0.0)
    assert c64["pairs"] == bed["contacts"]  # LIGGGHTS's compute contact/atom, from the same positions
    assert c64["pairs"] > 300  # settled: more than one pair contact per grain
    c32 = count_contacts(pos.astype(np.float32), d / 2, cylinder_radius=R, floor_z=0.0)
    assert c32 == c64
    again = liggghts_pour.pour_bed(300, d, 2500.0, 5e6, 0.3, 0.5, 0.5, cache_dir=str(tmp_path))
    assert again["cached"] and np.array_equal(again["position"], pos)

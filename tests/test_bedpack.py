"""The packed bed (app/io/bedpack.py, `fbed pack`): its codes against hand values, the bed it gives back against the
bed it was given (to half the resolution, sizes exact), its size against the entropy of its gaps, and the command's
answers to bad input."""
import gzip
import os
import pathlib
import subprocess
import sys

import h5py
import numpy as np
import pytest
from scipy.spatial import cKDTree

from app.beds import load_bed
from app.io import bedpack, store

ROOT = pathlib.Path(__file__).resolve().parents[1]


@pytest.mark.unit
def test_morton_codes_interleave_x_y_z_and_invert():
    q = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [2, 0, 0], [3, 3, 3], [(1 << 21) - 1] * 3])
    assert bedpack.morton(q).tolist() == [4, 2, 1, 32, 63, (1 << 63) - 1]
    r = np.random.default_rng(0).integers(0, 1 << 21, (1000, 3))
    assert np.array_equal(bedpack.unmorton(bedpack.morton(r)).astype(np.int64), r)


@pytest.mark.unit
def test_varints_are_leb128():
    v = np.array([0, 1, 127, 128, 300, (1 << 64) - 1], np.uint64)
    b = bedpack.varints(v)
    assert b[:7].tolist() == [0, 1, 127, 0x80, 0x01, 0xAC, 0x02]  # 300 = 0b10_0101100
    assert b[7:].tolist() == [0xFF] * 9 + [0x01]  # 64 bits: ten groups of 7
    assert np.array_equal(bedpack.unvarints(b), v)


@pytest.mark.unit
def test_rice_coding_inverts():
    gaps = np.random.default_rng(1).geometric(1 / 5000.0, 777).astype(np.uint64)
    for bits in (0, 1, 11, 12, 40):
        low, high = bedpack.rice(gaps, bits)
        assert low.size == (gaps.size * bits + 7) // 8
        assert np.array_equal(bedpack.unrice(low, high, bits, gaps.size), gaps)


def _matched(x, r, back, res, origin):
    """Both beds sorted by (size, rounded position): the grains' order is not kept."""
    key = lambda p, s: np.lexsort((*np.rint((p - origin) / res).T[::-1], s))  # noqa: E731
    i, j = key(x, r), key(back["position"], back["radius"])
    return x[i], r[i], back["position"][j], back["radius"][j]


@pytest.mark.unit
@pytest.mark.parametrize("sizes", [3, 70000])
def test_a_packed_bed_is_the_bed_to_half_the_resolution(tmp_path, sizes):
    """Three size classes (their radii kept as classes), or a size per grain (over MAX_CLASSES: float32 radii per
    grain); read back through the store, as particles.initial_state reads it."""
    rng = np.random.default_rng(3)
    n = 70000
    x = np.stack([rng.uniform(-0.048, 0.048, n), rng.uniform(-0.048, 0.048, n), rng.uniform(0, 0.13, n)], 1)
    r = (rng.choice([4.6e-4, 5.25e-4, 6.35e-4], n) if sizes == 3 else rng.uniform(4e-4, 6e-4, n)).astype(np.float32)
    info = store.write_packed_bed(tmp_path / "bed.h5", x.astype(np.float32), r, time=0.5, resolution=1e-7)
    grains, gas, meta = store.read_checkpoint(tmp_path / "bed.h5")
    assert gas is None and meta["time"] == 0.5 and set(grains) == {"position", "radius"}
    assert info["resolution"] == 1e-7 and info["grains"] == n
    x32 = x.astype(np.float32).astype(np.float64)
    a, ra, b, rb = _matched(x32, r.astype(np.float64), grains, 1e-7, meta["origin"])
    assert np.array_equal(ra, rb)  # sizes exact
    assert np.abs(a - b).max() <= 0.5e-7 * (1 + 1e-6)  # rounding to the grid: half a step (float64 arithmetic)
    with h5py.File(tmp_path / "bed.h5") as f:
        assert ("count" in f) == (sizes == 3)


@pytest.mark.unit
def test_the_resolution_is_raised_where_the_bed_spans_more_than_21_bits():
    x = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # 1 m tall: 0.1 um would need 24 bits
    arrays, attrs = bedpack.pack(x, np.full(2, 1e-3), 1e-7)
    assert attrs["resolution"] == pytest.approx(1.0 / ((1 << 21) - 1))
    back = bedpack.unpack(arrays, attrs)
    assert np.abs(back["position"] - x).max() <= 0.5 * attrs["resolution"] * (1 + 1e-9)


@pytest.mark.unit
def test_a_grain_costs_the_entropy_of_its_gap_and_little_more(tmp_path):
    """Uniform grains in a cube of 2^18 steps an axis: the sorted codes' gaps are near geometric with mean Q / N,
    entropy log2(Q / N) + log2(e) bits. Bound: that plus 2 bits (0.25 B) a grain: the Rice parameter rounded down
    (a few hundredths of a bit for geometric gaps), the high parts' varints under gzip and the file's fixed part
    (about 4 kB, 0.02 B a grain here). Measured 0.15 B over it (2026-12-07)."""
    n = 200000
    x = np.random.default_rng(4).random((n, 3)) * ((1 << 18) * 1e-7)
    info = store.write_packed_bed(tmp_path / "cube.h5", x, np.full(n, 5e-4), resolution=1e-7)
    entropy = (np.log2((1 << 18) ** 3 / n) + np.log2(np.e)) / 8
    assert info["bytes"] / n <= entropy + 0.25
    assert info["bytes"] / n < 12.0 * 0.45  # against float32 positions


@pytest.mark.unit
def test_zigzag_orders_signed_integers_by_magnitude_and_inverts():
    q = np.array([0, -1, 1, -2, 2, -(1 << 52), 1 << 52])
    assert bedpack.zigzag(q).tolist() == [0, 1, 2, 3, 4, (1 << 53) - 1, 1 << 53]
    assert np.array_equal(bedpack.unzigzag(bedpack.zigzag(q)), q)


@pytest.mark.unit
def test_a_moving_bed_keeps_its_velocities_and_spins_to_half_the_speed_resolution(tmp_path):
    """Velocities and spins (their surface speeds omega r) come back to +-q/2 a component, each with its own grain
    (the positions are re-ordered by class and Morton code, the speeds with them); a bed packed without a speed
    resolution has neither (it restarts at rest)."""
    rng = np.random.default_rng(6)
    n, q = 50000, 1e-3
    x = np.stack([rng.uniform(-0.048, 0.048, n), rng.uniform(-0.048, 0.048, n), rng.uniform(0, 0.13, n)], 1)
    r = rng.choice([4.6e-4, 5.25e-4, 6.35e-4], n)
    v = rng.laplace(0.0, 0.05, (n, 3)) + np.array([0.0, 0.0, 0.02])
    w = rng.laplace(0.0, 0.03, (n, 3)) / r[:, None]  # spins of 0.03 m/s surface speed [rad/s]
    v[0] = [3.0, -2.5, 1e-9]  # a fast grain and a tiny component
    store.write_packed_bed(tmp_path / "bed.h5", x, r, resolution=1e-7, velocity=v, omega=w, speed_resolution=q)
    grains, _, meta = store.read_checkpoint(tmp_path / "bed.h5")
    assert set(grains) == {"position", "radius", "velocity", "omega"} and meta["speed_resolution"] == q
    dist, j = cKDTree(grains["position"]).query(x)  # each grain's packed self: the nearest
    assert dist.max() <= np.sqrt(3) * 0.5e-7 * (1 + 1e-6) and len(set(j)) == n
    assert np.array_equal(grains["radius"][j], r)
    assert np.abs(grains["velocity"][j] - v).max() <= 0.5 * q * (1 + 1e-9)
    assert np.abs((grains["omega"][j] - w) * r[:, None]).max() <= 0.5 * q * (1 + 1e-9)
    # without: positions and sizes only, as before
    store.write_packed_bed(tmp_path / "rest.h5", x, r, resolution=1e-7, velocity=v, omega=w)
    assert set(store.read_checkpoint(tmp_path / "rest.h5")[0]) == {"position", "radius"}


@pytest.mark.unit
def test_a_speed_costs_about_the_entropy_of_its_rounded_spread():
    """Laplace speeds of scale s rounded to q: entropy about log2(2 e s / q) bits a component (s >> q). Six Rice-
    coded components cost that plus at most 0.6 bit each: measured 0.48 (2026-12-07), nearly all of it deflate's
    Huffman codes on the high parts' small alphabet (their entropy 2.1 bits, 2.6 under gzip; LZMA would give 2.4,
    not worth a format of our own)."""
    rng = np.random.default_rng(7)
    n, s, q = 100000, 0.05, 2e-3
    x = rng.random((n, 3)) * 0.05
    v, spin = rng.laplace(0, s, (n, 3)), rng.laplace(0, s, (n, 3))
    arrays, _ = bedpack.pack(x, np.full(n, 5e-4), 1e-6, v, spin / 5e-4, q)
    motion = sum(arrays[k].nbytes for k in ("motion_low", "motion_bits")) + len(gzip.compress(
        arrays["motion_high"].tobytes(), 9))
    entropy = 6 * np.log2(2 * np.e * s / q) / 8  # B a grain
    assert entropy < motion / n <= entropy + 6 * 0.6 / 8


def fbed(*args):
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.run([sys.executable, "-m", "app", *map(str, args)], capture_output=True, text=True, cwd=ROOT,
                          env=env, timeout=120)


@pytest.mark.smoke
def test_fbed_pack_writes_a_bed_and_refuses_bad_input_naming_it(tmp_path):
    rng = np.random.default_rng(5)
    n = 500
    grains = {"position": rng.random((n, 3)).astype(np.float32) * 0.01, "radius": np.full(n, 5e-4, np.float32),
              "velocity": np.zeros((n, 3), np.float32), "alive": np.r_[np.ones(n - 1), 0].astype(np.int32)}
    store.write_checkpoint(tmp_path / "bed.h5", grains, None, 0.2, 200, "")
    r = fbed("pack", tmp_path / "bed.h5", tmp_path / "packed.h5")
    assert r.returncode == 0, r.stderr
    assert f"packed {n - 1} grains" in r.stderr and "B a grain" in r.stderr and "left out" in r.stderr
    back, _, meta = store.read_checkpoint(tmp_path / "packed.h5")
    assert len(back["radius"]) == n - 1 and meta["time"] == 0.2  # the removed grain left out
    # a moving bed, to go on with: particles.initial_state (app.beds.load_bed) gets its velocities and spins
    grains["velocity"] = rng.normal(0.0, 0.1, (n, 3)).astype(np.float32)
    grains["omega"] = rng.normal(0.0, 50.0, (n, 3)).astype(np.float32)
    store.write_checkpoint(tmp_path / "moving.h5", grains, None, 0.2, 200, "")
    r = fbed("pack", tmp_path / "moving.h5", tmp_path / "moving_packed.h5", "--speed-resolution", "1e-3")
    assert r.returncode == 0 and "spins' surface speeds to +-0.0005 m/s" in r.stderr, r.stderr
    src, got = load_bed(tmp_path / "moving.h5"), load_bed(tmp_path / "moving_packed.h5")
    dist, j = cKDTree(got["position"]).query(src["position"])  # each grain's packed self: the nearest
    assert dist.max() <= 1e-7 and len(set(j)) == n - 1
    assert np.abs(got["velocity"][j] - src["velocity"]).max() <= 0.5e-3 * (1 + 1e-6)
    assert np.abs((got["omega"][j] - src["omega"]) * 5e-4).max() <= 0.5e-3 * (1 + 1e-6)
    before = (tmp_path / "bed.h5").read_bytes()
    for args, needles in [(("nope.h5", "o.h5"), ("nope.h5", "no such file")),
                          ((tmp_path / "packed.h5", tmp_path / "no" / "o.h5"), ("no such folder",)),
                          ((tmp_path / "bed.h5", tmp_path / "bed.h5"), ("OUT is BED itself",)),
                          ((tmp_path / "bed.h5", tmp_path), ("is a folder, not a file", "bed.h5")),
                          ((tmp_path / "bed.h5", tmp_path / "o.h5", "--resolution", "-1"), ("--resolution",)),
                          ((tmp_path / "bed.h5", tmp_path / "o.h5", "--speed-resolution", "-1"),
                           ("--speed-resolution", "0 for a bed at rest")),
                          ((tmp_path / "moving.h5", tmp_path / "o.h5", "--speed-resolution", "1e-20"),
                           ("--speed-resolution", "beyond 2^52 steps", "a coarser --speed-resolution")),
                          # coarser than 1% of the 1 mm grains (1e9 m had packed every grain onto one point)
                          ((tmp_path / "bed.h5", tmp_path / "o.h5", "--resolution", "1.1e-5"),
                           ("--resolution", "0.011 of the smallest grain", "at most 0.01 of it, 1e-05 m")),
                          ((ROOT / "README.md", tmp_path / "o.h5"), ("README.md", "not an HDF5 file"))]:
        r = fbed("pack", *args)
        assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
        assert all(s in r.stderr for s in needles), (args, r.stderr)
    assert (tmp_path / "bed.h5").read_bytes() == before and not (tmp_path / "o.h5").exists()


@pytest.mark.unit
def test_fbed_pack_where_it_may_not_write_is_an_error_naming_out(tmp_path, monkeypatch, capsys):
    """A folder it may not write to (injected: this test may run as root, whom no mode stops): exit 2, OUT named."""
    import errno

    from app.cli import main as cli_main

    def denied(path, *args, **kwargs):
        raise PermissionError(errno.EACCES, "Permission denied", str(path))

    store.write_checkpoint(tmp_path / "bed.h5", {"position": np.zeros((1, 3)), "radius": np.ones(1) * 1e-3}, None,
                           0.0, 0, "")
    monkeypatch.setattr(store, "write_packed_bed", denied)
    assert cli_main(["pack", str(tmp_path / "bed.h5"), str(tmp_path / "o.h5")]) == 2
    err = capsys.readouterr().err
    assert "o.h5: OUT: cannot write there (Permission denied)" in err and "Traceback" not in err

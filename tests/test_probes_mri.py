"""Synthetic MRI probe (app/probes_mri.py): the slab volume of a sphere, the open area of a cylinder's slab,
volume conservation of the binning; and a coupled run with every probe on (each record keeps its attributes)."""
import json
import math

import h5py
import numpy as np
import pytest

from app.config import load_text
from app.probes_mri import MriImage, slab_volume
from dem_helpers import make, merged, toml_text
from test_cli import fbed

pytestmark = pytest.mark.unit


def test_slab_volume_of_a_sphere():
    r = np.array([1e-3])
    full = 4.0 / 3.0 * math.pi * 1e-9
    assert slab_volume(np.array([0.0]), r, 5e-3) == pytest.approx(full, rel=1e-12)
    assert slab_volume(np.array([5e-3]), r, 5e-3) == pytest.approx(0.5 * full, rel=1e-12)   # centred on a face
    assert slab_volume(np.array([-6.01e-3]), r, 5e-3) == pytest.approx(0.0, abs=1e-30)      # outside
    # a cap of height h = 0.5 mm: pi h^2 (3r - h) / 3
    h = 0.5e-3
    assert slab_volume(np.array([5.5e-3]), r, 5e-3) == pytest.approx(math.pi * h * h * (3e-3 - h) / 3, rel=1e-12)
    # a sphere wider than the slab: the slice of height 2 * half through its middle
    half = 0.2e-3
    assert slab_volume(np.array([0.0]), r, half) == pytest.approx(math.pi * (1e-6 * 2 * half - 2 * half ** 3 / 3),
                                                                 rel=1e-12)


def image(**probes):
    cfg = load_text(toml_text(merged(
        domain={"lo": [-0.048, -0.048, 0.0], "hi": [0.048, 0.048, 0.24]},
        vessel={"shape": "cylinder", "radius": 0.048},
        gas={"cell_size": 0.006}, probes={"slab_width": 0.01, **probes})), "t.toml")
    return MriImage(cfg)


def test_image_grid_and_open_area_of_the_cylinder_slab():
    im = image()
    assert (im.nx, im.nz) == (24, 30) and im.x0 == pytest.approx(-0.048) and im.z0 == 0.0
    # the slab's cross-section inside the circle: integral of 2 min(half, sqrt(R^2 - x^2)) dx
    R, half = 0.048, 0.005
    x = np.linspace(-R, R, 200001)
    exact = np.trapezoid(2 * np.minimum(half, np.sqrt(np.maximum(R * R - x * x, 0))), x)
    assert np.sum(im.open_fraction) * im.dx * im.width == pytest.approx(exact, rel=2e-3)
    assert im.open_fraction[12] == 1.0 and im.open_fraction[0] < 1.0
    fine = image(mri_pixel=[0.001, 0.001])
    assert (fine.nx, fine.nz) == (96, 240)


def test_an_image_of_too_many_pixels_is_refused_at_load():
    """probes.mri_pixel = [1e-6, 1e-6] in fluidize's column asked Taichi for an array beyond int32 indices and ran
    the host out of memory (the process was killed): the image is now limited to MRI_MAX_PIXELS, checked at load
    on the same grid the probe records."""
    from app.config import ConfigError
    from app.config.derived import MRI_MAX_PIXELS

    with pytest.raises(ConfigError, match=r"probes.mri_pixel.*9,600 x 24,000 pixels an image; at most 1,048,576"):
        image(mri_pixel=[1e-5, 1e-5], mri_interval=4e-3)
    im = image(mri_pixel=[2.5e-4, 2.5e-4], mri_interval=4e-3)  # 384 x 960: finer than the MRI's, still taken
    assert (im.nx, im.nz) == (384, 960) and im.nx * im.nz <= MRI_MAX_PIXELS


def test_binning_keeps_the_grains_volume():
    im = image()
    rng = np.random.default_rng(3)
    n = 4000
    r = rng.choice([0.46e-3, 0.525e-3, 0.635e-3], n)
    x = np.column_stack([rng.uniform(-0.03, 0.03, n), rng.uniform(-0.0044, 0.0044, n), rng.uniform(0, 0.2, n)])
    inside = np.abs(x[:, 1]) + r < 0.005
    void = im.void(x, r)
    cell = im.dx * im.dz * im.width * im.open_fraction[:, None]
    binned = np.sum((1.0 - void) * cell * im.mask)
    expect = np.sum(slab_volume(x[:, 1], r, 0.005))
    assert binned == pytest.approx(expect, rel=1e-9)
    assert expect > np.sum(4 / 3 * math.pi * r[inside] ** 3)  # the grains that straddle a face count in part
    # a grain in the pixel (i, k) fills it by its volume over the pixel's open volume
    one = im.void(np.array([[0.001, 0.0, 0.013]]), np.array([1e-3]))
    i, k = int((0.001 + 0.048) / 0.004), int(0.013 / 0.008)
    assert 1.0 - one[i, k] == pytest.approx(4 / 3 * math.pi * 1e-9 / (0.004 * 0.008 * 0.01), rel=1e-12)
    assert np.count_nonzero(one < 1.0) == 1


@pytest.mark.parametrize("precision", ["float64", "float32"])
def test_the_device_binning_is_numpys(precision, session_runtime_after):
    """``DemSolver.slab_volumes`` (the probe's frame, binned on the device in float64 whatever the run's precision)
    against ``MriImage.volumes`` (numpy) on the same grains, the DEM's own positions read back: a tri-disperse bed of
    4,000 grains in the 96 mm cylinder, many straddling the slab's faces, some beyond the pixel grid's top (z over
    0.24 m: nothing), a tenth of them dead (nothing). Equal to rounding (the sums in another order: 1e-12 relative);
    in float32 too, where a constant taken in the run's precision (pi: 2.8e-8) would show."""
    from app.sim import runtime

    runtime.init("cpu", precision, 1)
    im = image()
    rng = np.random.default_rng(5)
    n = 4000
    r = rng.choice([0.46e-3, 0.525e-3, 0.635e-3], n)
    x = np.column_stack([rng.uniform(-0.03, 0.03, n), rng.uniform(-0.007, 0.007, n), rng.uniform(0.0, 0.3, n)])
    alive = rng.uniform(size=n) > 0.1
    _, dem = make(x, radius=r, domain={"lo": [-0.048, -0.048, 0.0], "hi": [0.048, 0.048, 0.3]},
                  vessel={"shape": "cylinder", "radius": 0.048},
                  particles={"count": n, "diameter": 0.0, "diameters": [0.92e-3, 1.05e-3, 1.27e-3],
                             "fractions": [0.34, 0.33, 0.33]})
    dem.set_grains(x, radius=r, alive=alive)
    got = dem.slab_volumes(im.yc, 0.5 * im.width, (im.x0, im.z0), (im.dx, im.dz), (im.nx, im.nz))
    pos = dem.read("position").astype(np.float64)
    rad = dem.radii().astype(np.float64)  # as stored: float32 in a float32 run
    live = dem.read("alive").astype(bool)
    want = im.volumes(pos[live], rad[live])
    assert got.shape == (im.nx, im.nz) and got.dtype == np.float64
    assert np.allclose(got, want, rtol=1e-12, atol=1e-22) and want.sum() > 0
    assert not np.allclose(want, im.volumes(pos, rad), rtol=1e-3, atol=0.0)  # the dead grains would have counted
    assert np.any(pos[live, 2] > im.z0 + im.nz * im.dz)  # live grains above the grid, which count nowhere


def test_every_probe_on_keeps_each_records_attributes(tmp_path):
    """Regression: with slab and volume probes both on, /slab got the 3-D probe's attributes (a closure read
    `attrs` after it was reassigned)."""
    preset = merged(run={"duration": 0.004, "step": 1e-3},
                    domain={"lo": [-0.012, -0.012, 0.0], "hi": [0.012, 0.012, 0.048], "gravity": [0.0, 0.0, -9.81]},
                    vessel={"shape": "cylinder", "radius": 0.012},
                    particles={"count": 300, "diameter": 1.5e-3, "density": 1015.0},
                    gas={"cell_size": 0.004},
                    boundary={"bottom": {"kind": "velocity_inlet", "velocity": [0.0, 0.0, 0.2]},
                              "top": {"kind": "pressure_outlet"}},
                    probes={"slab_interval": 2e-3, "slab_width": 0.01, "volume_interval": 2e-3,
                            "mri_interval": 2e-3, "mri_pixel": [0.004, 0.008]})
    (tmp_path / "p.toml").write_text(toml_text(preset))
    r = fbed("run", tmp_path / "p.toml", "--arch", "cpu", "--out", tmp_path / "o")
    assert r.returncode == 0, r.stderr
    with h5py.File(tmp_path / "o" / "run.h5") as f:
        slab, vol, mri = f["slab"], f["porosity3d"], f["mri"]
        assert len(slab.attrs["origin"]) == 2 and "y_cells" in slab.attrs
        assert slab.attrs["mask"].shape == slab["porosity"].shape[1:] == (6, 12)
        assert len(vol.attrs["origin"]) == 3 and "y_cells" not in vol.attrs
        assert mri["porosity"].shape[1:] == (6, 6) and tuple(mri.attrs["pixel"]) == (0.004, 0.008)
        assert mri["porosity"].shape[0] == slab["porosity"].shape[0] >= 2
        # the grains' volume in the slab is what the MRI image holds
        void = mri["porosity"][-1]
        assert np.all(void <= 1.0) and np.min(void) < 0.9
    assert json.loads((tmp_path / "o" / "summary.json").read_text())["status"] == "finished"

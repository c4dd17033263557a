"""Both slab images of one known bubble: a bed of grains with a spherical void, imaged as the synthetic MRI
(app.probes_mri: the grains' volume binned on pixels) and as the gas grid's own slab (app.probes: fbed's deposit,
smoothing and slab average), then put through app/analysis/mri.py.

The bed: the poppy seeds' three size classes (by mass) at solid fraction 0.60, one grain per cell of a cubic
lattice at a uniformly random place in its cell (a stratified random bed: its noise on the 2 x 4 mm pixels,
std 0.037 in solid fraction, is above the 0.021 of fbed's settled mri_small bed, so the test is not easier than a
real packing). Grains may overlap: the images only add volumes. The void: every grain whose centre lies within
R = 15 mm of the bubble's centre is removed, so the removed volume is on average the bed's 0.60 of the sphere.

What each image should give. A slab of width w through the sphere's centre holds at distance rho from it the
gas fraction c = min(1, 2 sqrt(R^2 - rho^2) / w) of the void; at the threshold 0.30 (half the bed's 0.60, where a
symmetrically blurred edge digitises without bias) a pixel is gas where c > 1/2, i.e. inside the disc of
diameter 2 sqrt(R^2 - w^2 / 16): 29.58 mm for the MRI's 10 mm slab, 29.39 mm for the grid's four 3 mm layers
(12 mm; ``slab_layers`` takes the layers whose centres lie within 5 mm). Tolerances, from the digitisation of a
30 mm disc: on 2 x 4 mm pixels about 33 boundary pixels, each off by up to half its area at random, give a
standard deviation of about 1% in the diameter, on 3 mm cells about 1.2%; a disc centred on a cell centre is
worse, its area a lattice-point count (4.9 cells of radius: 69 cells for 75.4, -4.3% in the diameter). So each
placement within 5%. Both images also read the disc a little small on average, as their blur predicts: a blur of
variance s^2 moves the half-level contour of a disc of radius a inward by s^2 / (2 a), and it averages the slab
section's edge profile (the void fills the slab fully out to 13.4 mm, half of it at 14.7 mm, none at 15 mm),
whose mean edge lies inside its half-level point: about -0.7% on the MRI's pixels, -1.7% on the grid (its
trilinear deposit, variance h^2/6 per axis, and one smoothing pass, 2 h^2/7: s = 2.0 mm). Measured over nine
placements: MRI -2.3 ... +0.1%, mean -1.0%; grid -4.3 ... +0.4%, mean -2.7%. So the mean of the four placements
within 2.5% (MRI) and 4% (grid): the predicted bias plus three standard deviations of a mean of four.

At the other thresholds the images blur the edge (the grid: trilinear deposit, variance h^2/6 per axis, and one
smoothing pass, 2 h^2/7: sigma 2.0 mm; the MRI: the 2 x 4 mm pixels, sigma 0.6 and 1.2 mm), which moves the
contour at a quarter of the bed's fraction (0.15) inward by 0.67 sigma and the one at two thirds (0.40) outward
by 0.43 sigma; with the slab geometry (c > 3/4 and c > 1/3) that predicts -12% and +7% on the grid less the
bias above (measured -11 ... -17% and +2 ... +5%) and about -5% and +3% on the MRI (measured -4 ... -8% and
0 ... +4%). So over the six thresholds one resolved, empty bubble's diameter grows with the threshold by less
than 30% in either image (a predicted 19% on the grid plus the lattice count at both ends; measured at most
24%), and at every threshold each image finds that one bubble and nothing else: no noisy pixel of the packed
emulsion counts as a bubble. A sharp image's bubble hardly moves with the solid-fraction scale (a 15% error in
the MRI's normalisation moves it by about 1%), so the scale is checked on its own: the emulsion under the void
reads the bed's 0.60 in both images."""
import math

import numpy as np
import pytest

from app.analysis import mri
from app.probes import Probes
from app.probes_mri import MriImage
from app.config import load_text
from app.scene import Scene, build_simulation
from dem_helpers import merged, toml_text

pytestmark = pytest.mark.verification

CLASSES = np.array([0.919e-3, 1.050e-3, 1.269e-3])   # m: the poppy seeds (seed 002, Table 3)
MASS = np.array([0.35, 0.32, 0.33])
ALPHA = 0.60
HX, HY, TOP, BED = 0.030, 0.009, 0.066, 0.060        # m: box half-widths, domain top, bed height
R = 0.015                                             # m: the void's radius


def stratified_bed(centre, seed):
    rng = np.random.default_rng(seed)
    num = MASS / CLASSES ** 3
    num /= num.sum()
    a = (np.sum(num * math.pi / 6 * CLASSES ** 3) / ALPHA) ** (1 / 3)
    axes = [np.arange(-HX, HX, a) + 0.5 * a, np.arange(-HY, HY, a) + 0.5 * a, np.arange(0.0, BED, a) + 0.5 * a]
    p = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    p += rng.uniform(-0.5 * a, 0.5 * a, p.shape)  # each grain anywhere in its lattice cell
    r = 0.5 * rng.choice(CLASSES, size=len(p), p=num)
    keep = (np.linalg.norm(p - centre, axis=1) >= R) & (np.abs(p[:, 0]) < HX) & (np.abs(p[:, 1]) < HY) \
        & (p[:, 2] > 0.0)
    return p[keep], r[keep]


def slab_images(p, r):
    """(MRI solid fraction on 2 x 4 mm pixels, grid slab solid fraction on 3 mm cells) of grains p, r."""
    sections = merged(domain={"lo": [-HX, -HY, 0.0], "hi": [HX, HY, TOP], "gravity": [0.0, 0.0, -9.81]},
                      vessel={"shape": "box"},
                      particles={"diameters": [float(d) for d in CLASSES], "fractions": [float(f) for f in MASS],
                                 "fractions_by": "mass", "density": 1015.0, "count": 10},
                      gas={"cell_size": 0.003},
                      coupling={"drag": "koch_hill", "smoothing_width": 1.5e-3, "eps_min": 0.35},  # as presets/mri_*
                      boundary={"bottom": {"kind": "velocity_inlet", "velocity": [0.0, 0.0, 0.45]},
                                "top": "pressure_outlet"},
                      probes={"slab_width": 0.01, "mri_pixel": [0.002, 0.004]})
    del sections["particles"]["diameter"]  # polydisperse, so the DEM keeps each grain's radius
    scene = Scene(load_text(toml_text(sections), "test.toml"), "test.toml", initial={"position": p, "radius": r})
    sim = build_simulation(scene)
    assert np.array_equal(sim.dem.radii(), r)
    flow = sim.flow
    sim.coupler.deposit(1e-3)
    probes = Probes(scene.cfg, flow, flow.fields.active.to_numpy())
    assert list(probes.y_cells) == [1, 2, 3, 4]  # four 3 mm layers: a 12 mm slab
    return 1.0 - MriImage(scene.cfg).void(p, r), 1.0 - probes.slab()


def section(w, q=0.5):
    """Diameter of the slab section where the void fills more than q of a slab of width w."""
    return 2.0 * math.sqrt(R * R - (0.5 * q * w) ** 2)


MEAN_TOL = {"mri": 0.025, "grid": 0.04}  # the mean error at 0.30 over the placements (see the module doc)
PLACEMENTS = (((0.0, 0.0, 0.030), 0), ((0.0013, -0.0007, 0.0317), 1), ((-0.0021, 0.0011, 0.0284), 2),
              ((0.0023, 0.0005, 0.0301), 3))  # m: bubble centres (x, y, z) and the beds' seeds


def test_both_slab_images_recover_a_known_spherical_void():
    at_half = {"mri": [], "grid": []}
    for centre, seed in PLACEMENTS:
        p, r = stratified_bed(np.array(centre), seed)
        mri_alpha, grid_alpha = slab_images(p, r)
        for name, alpha, dx, dz, w in (("mri", mri_alpha, 0.002, 0.004, 0.010),
                                       ("grid", grid_alpha, 0.003, 0.003, 0.012)):
            # the scale: the emulsion below the void (4-8 mm up) reads the bed's 0.60 (the MRI's 30 pixels of one
            # row, std 0.037 each: 0.007 on the mean; 0.02 is three of those)
            zc = (np.arange(alpha.shape[1]) + 0.5) * dz
            below = alpha[:, (zc > 0.003) & (zc < 0.008)]
            assert below.mean() == pytest.approx(ALPHA, abs=0.02), (name, centre, below.mean())
            d = []
            for thr in mri.THRESHOLDS:
                solid = mri.binarise(alpha, thr)
                bs = mri.bubbles(solid, dx, dz, surface=mri.bed_height(solid, dz))
                assert len(bs) == 1, (name, centre, thr, [round(1e3 * b["diameter"], 2) for b in bs])
                d.append(bs[0]["diameter"])
                assert bs[0]["x"] == pytest.approx(centre[0] + HX, abs=dx) and \
                    bs[0]["z"] == pytest.approx(centre[2], abs=dz), (name, centre, thr)
            err = d[mri.THRESHOLDS.index(0.30)] / section(w) - 1.0
            assert abs(err) < 0.05, (name, centre, err)
            at_half[name].append(err)
            assert all(b >= a for a, b in zip(d, d[1:])) and d[-1] / d[0] - 1.0 < 0.30, (name, centre, d)
    for name, errs in at_half.items():
        assert abs(np.mean(errs)) < MEAN_TOL[name], (name, errs)

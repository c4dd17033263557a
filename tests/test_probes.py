"""Probe tier: where the slab and the planes sample the gas grid (hand values)."""
import numpy as np
import pytest

from app.probes import plane_weights, slab_layers

pytestmark = pytest.mark.unit


def test_slab_takes_the_layers_within_half_its_width_or_the_two_that_straddle_the_midplane():
    # 32 cells of 6 mm from -0.096 m: centres at +-3 mm, +-9 mm, ...; the mid-plane y = 0 is a cell face
    assert list(slab_layers(32, 0.006, -0.096, 0.0, 0.010)) == [15, 16]   # |y| <= 5 mm: the centres at +-3 mm
    assert list(slab_layers(32, 0.006, -0.096, 0.0, 0.020)) == [14, 15, 16, 17]  # |y| <= 10 mm: +-3, +-9 mm
    assert list(slab_layers(32, 0.006, -0.096, 0.0, 0.001)) == [15, 16]   # thinner than a cell: the straddling two
    assert list(slab_layers(11, 0.01, 0.0, 0.055, 0.001)) == [5]          # odd count: the middle cell


def test_plane_interpolates_linearly_between_cell_centres():
    # cells of 3.125 mm from z = 0: centres at 1.5625, 4.6875, ... mm
    k0, k1, w = plane_weights(116, 3.125e-3, 0.0, 0.05)
    assert (k0, k1) == (15, 16)
    assert w == pytest.approx((0.05 / 3.125e-3 - 0.5) - 15)
    eps = np.zeros((2, 2, 116))
    eps[..., 15], eps[..., 16] = 0.4, 0.8
    assert ((1 - w) * eps[..., k0] + w * eps[..., k1]) == pytest.approx(np.full((2, 2), 0.4 + 0.4 * w))
    assert plane_weights(10, 1.0, 0.0, 0.2) == (0, 1, 0.0)  # below the first centre: clamped to it

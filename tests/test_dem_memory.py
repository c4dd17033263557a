"""Lean contact storage: the bytes per grain a run reports in summary.json stay within the targets of a
monodisperse frictional bed with walls (350 B) and a tri-disperse bed with elastic-plastic rolling friction
(600 B), in float32 as on a GPU; and a grain's springs are kept only for the contacts it owns."""
import json

import numpy as np

from dem_helpers import make
from test_cli import ROOT, fbed
import pytest

pytestmark = pytest.mark.verification

BASE = ["--set", "particles.count=2500", "--set", "run.duration=0.004", "--set", "run.precision=\"float32\"",
        "--arch", "cpu"]


def summary(tmp_path, *sets):
    r = fbed("run", ROOT / "presets" / "settle.toml", *BASE, *sets, "--out", tmp_path)
    assert r.returncode == 0, r.stderr
    return json.loads((tmp_path / "summary.json").read_text())


def test_monodisperse_frictional_bed_with_walls_within_350_bytes(tmp_path):
    # settle.toml: 2500 grains of 2 mm, friction 0.3, in a cylinder with a floor (its cell list: 12 B/grain)
    s = summary(tmp_path)
    assert s["bytes_per_grain"] <= 350, s


def test_tridisperse_rolling_bed_within_600_bytes(tmp_path):
    s = summary(tmp_path, "--set", "particles.diameter=0", "--set", "particles.diameters=[0.919e-3,1.050e-3,1.269e-3]",
                "--set", "particles.fractions=[0.34,0.33,0.33]", "--set", "contact.rolling_friction=0.1",
                "--set", "contact.rolling_model=\"epsd\"")
    assert s["bytes_per_grain"] <= 600, s


def test_springs_follow_their_contacts():
    """Two grains pressed together then pulled apart: the contact takes one history slot while touching,
    gives it back on separation (the next contact starts from a zero spring)."""
    r = 1e-3
    scene, dem = make(positions=[[-r * 0.999, 0, 0], [r * 0.999, 0, 0]], velocities=[[0, 0.01, 0], [0, -0.01, 0]],
                      contact={"friction": 0.5})
    dem.advance(20)
    a = dem.state_arrays()
    assert bin(int(a["nl_springs_used"][0])).count("1") == 1 and a["nl_spring_slot"][0, 0] == 0
    h = int(a["nl_spring_slot"][0, 0])
    assert np.abs(a["tangential"][h, 0]).max() > 0  # the spring holds the slip
    # pull them apart: the slot is freed
    dem.set_grains(a["position"] * 1.01, np.zeros((2, 3)), np.full(2, r), alive=a["alive"])
    dem.advance(5)
    b = dem.state_arrays()
    assert int(b["nl_springs_used"][0]) == 0 and b["nl_spring_slot"][0, 0] == 255

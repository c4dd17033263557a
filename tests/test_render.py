"""Renderer tier: offscreen GGUI frames show grains where they are, videos decode, the viewer's
controls drive the simulation through the same methods a script uses.

GGUI needs a Vulkan device; on CI (no GPU) Mesa's software rasterizer (mesa-vulkan-drivers,
installed by .ci/run) provides it.
"""
import json
import pathlib
import sys

import numpy as np
import pytest

from dem_helpers import make, merged, toml_text
from test_cli import fbed

pytestmark = pytest.mark.smoke

ti = pytest.importorskip("taichi")


@pytest.fixture(autouse=True)
def _needs_gui(gui):
    return gui


def renderer_for(dem, scene, **settings):
    from app.gui.render import Renderer, ViewSettings

    st = ViewSettings(**{"width": 320, "height": 240, **settings})
    return Renderer(dem, None, scene.walls, scene.cfg.domain.lo, scene.cfg.domain.hi, st, title="test")


def ink(frame):
    """Mask of coloured pixels: the grains (colour map), not the grey outline, white background or black text."""
    f = frame.astype(int)
    return f.max(axis=-1) - f.min(axis=-1) > 40


def grid(n_side, x0, x1, z):
    xs = np.linspace(x0, x1, n_side)
    X, Y = np.meshgrid(xs, np.linspace(-0.01, 0.01, n_side), indexing="ij")
    return np.stack([X.ravel(), Y.ravel(), np.full(X.size, z)], -1)


@pytest.fixture(scope="module")
def scene_dem():
    return make(particles={"count": 100, "diameter": 4e-3})


def test_frame_shows_grains_where_they_are_and_changes_when_they_move(scene_dem):
    scene, dem = scene_dem
    left = grid(10, -0.04, -0.02, 0.0)
    dem.set_grains(left, radius=np.full(100, 2e-3))
    r = renderer_for(dem, scene, view="slab", slab_width=0.05, void_panel=False)
    try:
        f1 = r.frame(0.0)
        assert f1.shape == (240, 320, 3) and f1.dtype == np.uint8
        body = ink(f1)
        body[:60] = False  # the text stamp
        cols = np.nonzero(body.any(axis=0))[0]
        # the domain (x in [-0.05, 0.05]) spans the frame's middle; the grains sit in its left fifth
        assert body.sum() > 200, "frame is blank"
        mid = f1.shape[1] // 2
        assert cols.max() < mid, "grains drawn right of the centre although all sit left of it"
        dem.set_grains(left + [0.06, 0.0, 0.0], radius=np.full(100, 2e-3))  # now right of centre
        f2 = r.frame(0.1)
        body2 = ink(f2)
        body2[:60] = False
        cols2 = np.nonzero(body2.any(axis=0))[0]
        assert cols2.min() > mid, "grains did not move to the right half"
        assert np.abs(f1.astype(int) - f2.astype(int)).sum() > 0
    finally:
        r.close()


def test_slab_view_draws_only_the_central_slab_and_colours_by_speed(scene_dem):
    scene, dem = scene_dem
    rng = np.random.default_rng(3)
    pos = rng.uniform(-0.04, 0.04, (100, 3))
    vel = np.zeros((100, 3))
    vel[:, 0] = np.linspace(0.0, 1.0, 100)
    dem.set_grains(pos, vel, np.full(100, 2e-3))
    r = renderer_for(dem, scene, view="slab", slab_width=0.02, color="speed", color_range=(0.0, 1.0))
    try:
        n = r.update_snapshot()
        inside = np.abs(pos[:, 1]) < 0.01
        assert n == inside.sum()
        drawn = r.snapshot.position.to_numpy()[:n]
        assert np.all(np.abs(drawn[:, 1]) < 0.01 + 1e-6)
        # colours: the map sampled at speed / 1 m/s (nearest lower table entry)
        lut = r.snapshot.lut.to_numpy()
        colours = r.snapshot.color.to_numpy()[:n]
        order = {tuple(np.round(p, 5)): k for k, p in enumerate(pos[:, :3].astype(np.float32))}
        for p, c in zip(drawn, colours):
            k = order[tuple(np.round(p, 5))]
            assert np.allclose(c, lut[int(vel[k, 0] * (len(lut) - 1))], atol=1e-6)
    finally:
        r.close()


def test_every_colouring_compiles_and_spans_the_map(scene_dem):
    scene, dem = scene_dem
    pos = grid(10, -0.04, 0.04, 0.0)
    pos[:, 2] = np.linspace(-0.04, 0.04, 100)
    dem.set_grains(pos, radius=np.full(100, 2e-3))
    r = renderer_for(dem, scene, color="height")
    try:
        r.update_snapshot()
        c = r.snapshot.color.to_numpy()[:100]
        assert len(np.unique(np.round(c, 3), axis=0)) > 20  # heights spread over the map
        for mode in ("size", "tracer", "speed"):
            r.settings = type(r.settings)(**{**r.settings.__dict__, "color": mode})
            assert r.update_snapshot() == 100
            assert np.all(np.isfinite(r.snapshot.color.to_numpy()[:100]))
    finally:
        r.close()


def test_video_of_a_short_run_decodes_to_the_expected_frames(tmp_path):
    import imageio.v2 as iio

    preset = tmp_path / "drop.toml"
    preset.write_text(toml_text(merged(
        run={"duration": 0.02, "step": 1e-3},
        domain={"lo": [-0.02, -0.02, 0.0], "hi": [0.02, 0.02, 0.06], "gravity": [0.0, 0.0, -9.81]},
        vessel={"shape": "cylinder", "radius": 0.018},
        particles={"count": 300, "diameter": 3e-3, "density": 2500.0},
        video={"width": 160, "height": 120, "interval": 0.005, "fps": 10.0})))
    r = fbed("run", preset, "--video", "--arch", "cpu", "--out", tmp_path / "o")
    assert r.returncode == 0, r.stderr
    s = json.loads((tmp_path / "o" / "summary.json").read_text())
    # frames at t = 0 and every 5 ms up to 20 ms
    assert s["frames"] == 5
    reader = iio.get_reader(tmp_path / "o" / "video.mp4")
    meta = reader.get_meta_data()
    frames = [f for f in reader]
    assert len(frames) == 5
    assert frames[0].shape == (120, 160, 3)
    assert meta["codec"] == "h264" and meta["fps"] == pytest.approx(10.0)
    assert s["video_encoder"] == "ffmpeg/libx264"
    # grains fall: successive frames differ
    assert np.abs(frames[0].astype(int) - frames[-1].astype(int)).mean() > 0.1


def test_a_resumed_run_goes_on_with_the_same_video(tmp_path):
    """A run to 60 ms resumed to 120 ms makes one video of the same 5 frames, at the same times (run.h5's /video),
    as a run straight to 120 ms; before, the resume wrote over video.mp4 with its own 2 frames and the first part
    was gone. Each joined frame is nearest (mean absolute difference) to the straight run's frame of the same
    index: the grains fall for 30 ms between frames, which changes a frame more than re-encoding the kept ones does
    (and the title is the same: before, a resumed run took its folder's name). Then a
    video that lost frames (restored to its 3-frame state, as a killed run's would be) goes on after them with a
    note and run.h5 says which times it holds; and a resume at another frame size starts a new video, the earlier
    one kept aside."""
    import h5py
    import imageio.v2 as iio

    preset = tmp_path / "drop.toml"
    preset.write_text(toml_text(merged(
        run={"duration": 0.12, "step": 1e-3, "threads": 1},
        domain={"lo": [-0.02, -0.02, 0.0], "hi": [0.02, 0.02, 0.06], "gravity": [0.0, 0.0, -9.81]},
        vessel={"shape": "cylinder", "radius": 0.018},
        particles={"count": 300, "diameter": 3e-3, "density": 2500.0},
        video={"width": 160, "height": 120, "interval": 0.03, "fps": 10.0})))

    def frames(d, name="video.mp4"):
        return [f.astype(int) for f in iio.get_reader(d / name)]

    def times(d):
        with h5py.File(d / "run.h5", "r") as f:
            assert list(f["video/frame"][...]) == list(range(f["video/time"].shape[0]))
            return list(np.round(f["video/time"][...], 6))

    straight, parts = tmp_path / "straight", tmp_path / "parts"
    assert fbed("run", preset, "--video", "--arch", "cpu", "--out", straight).returncode == 0
    r = fbed("run", preset, "--video", "--arch", "cpu", "--out", parts, "--set", "run.duration=0.06")
    assert r.returncode == 0, r.stderr
    first_part = (parts / "video.mp4").read_bytes()
    r = fbed("run", "--resume", parts, "--set", "run.duration=0.12")
    assert r.returncode == 0, r.stderr
    a, b = frames(straight), frames(parts)
    assert len(a) == len(b) == 5 and times(parts) == times(straight) == [0.0, 0.03, 0.06, 0.09, 0.12]
    distance = np.array([[np.abs(frame - other).mean() for other in a] for frame in b])  # diagonal ~0.4, others > 1
    assert list(np.argmin(distance, axis=1)) == list(range(5)), distance
    # the resumed run keeps the name it started with (the preset's, drawn in each frame), not its folder's ("parts")
    assert json.loads((parts / "summary.json").read_text())["preset"] == "drop"
    assert json.loads((parts / "summary.json").read_text())["video_frames"] == 5
    assert not list(parts.glob("*.tmp*"))

    (parts / "video.mp4").write_bytes(first_part)  # frames 0.09 and 0.12 lost, as with a run killed at 0.12
    (parts / "video.tmp.mp4").write_bytes(b"\0" * 4096)  # and the torn file that run left
    r = fbed("run", "--resume", parts, "--set", "run.duration=0.18")
    assert r.returncode == 0 and "video.mp4 holds 3 of the 5 frames recorded up to the checkpoint" in r.stderr
    assert len(frames(parts)) == 5 and times(parts) == [0.0, 0.03, 0.06, 0.15, 0.18]
    assert not (parts / "video.tmp.mp4").exists()

    r = fbed("run", "--resume", parts, "--set", "run.duration=0.21", "--set", "video.width=200")
    assert r.returncode == 0 and "kept as video.before_resume.mp4" in r.stderr, r.stderr
    assert len(frames(parts, "video.before_resume.mp4")) == 5
    assert len(frames(parts)) == 1 and frames(parts)[0].shape == (120, 200, 3) and times(parts) == [0.21]


def test_video_writer_falls_back_to_png_frames_and_says_so_once(tmp_path, monkeypatch):
    from app.gui.video import VideoWriter

    monkeypatch.setitem(sys.modules, "imageio_ffmpeg", None)  # import fails
    monkeypatch.setitem(sys.modules, "cv2", None)
    said = []
    w = VideoWriter(tmp_path / "v.mp4", 10, notify=said.append)
    for k in range(3):
        w.write(np.full((31, 41, 3), 40 * k, np.uint8))  # odd sizes are padded to even
    w.close()
    assert w.encoder == "png" and len(said) == 1 and "imageio-ffmpeg" in said[0]
    pngs = sorted((tmp_path / "v").glob("*.png"))
    assert len(pngs) == 3
    # a resume that keeps 2 of them: its frames follow them, and the third (past its checkpoint) is replaced
    w = VideoWriter(tmp_path / "v.mp4", 10, notify=said.append, keep_frames=2)
    w.write(np.full((31, 41, 3), 200, np.uint8))
    w.close()
    import imageio.v2 as iio

    pngs = sorted((tmp_path / "v").glob("*.png"))
    assert w.kept == 2 and [p.name for p in pngs] == ["frame_00000.png", "frame_00001.png", "frame_00002.png"]
    assert iio.imread(pngs[1])[0, 0, 0] == 40 and iio.imread(pngs[2])[0, 0, 0] == 200


def test_void_panel_with_gas_and_the_viewer_controls(tmp_path):
    """A coupled run driven by a scripted viewer controller: pause, single steps, gas factor, jet,
    colour and view changes, a screenshot, then stop: the run ends 'interrupted' with a checkpoint."""
    from app.gui.viewer import ViewerController
    from app.run import run

    preset = tmp_path / "bed.toml"
    preset.write_text(toml_text(merged(
        run={"duration": 0.05, "step": 1e-3, "precision": "float64"},  # as conftest: no Taichi restart
        domain={"lo": [-0.012, -0.012, 0.0], "hi": [0.012, 0.012, 0.048], "gravity": [0.0, 0.0, -9.81]},
        vessel={"shape": "box"},
        particles={"count": 400, "diameter": 2e-3, "density": 1000.0},
        gas={"cell_size": 4e-3},
        boundary={"bottom": {"kind": "velocity_inlet", "velocity": [0.0, 0.0, 0.3], "jet_velocity": [0.0, 0.0, 3.0],
                             "jet_radius": 3e-3, "jet_start": 0.0},
                  "top": {"kind": "pressure_outlet"}},
        video={"width": 200, "height": 150})))
    log = {}

    class Script(ViewerController):
        show_window = False  # offscreen: a headless test machine has no screen

        def __init__(self, renderer, schedule, out_dir):
            super().__init__(renderer, schedule, out_dir, handle_events=False)
            self.calls = 0

        def __call__(self, sim):
            self.calls += 1
            if self.calls == 1:
                assert self.toggle_pause() is True
            elif self.calls == 2:
                self.step_once()
                self.step_once()
            elif self.calls == 6:
                log["steps_after_two_singles"] = sim.step_count
                log["gas"] = self.set_gas_factor(2.0)
                log["jet"] = self.toggle_jet()
                log["colour"] = self.cycle_colour()
                log["view"] = self.toggle_view()
                self.orbit(30.0, 10.0)
                self.zoom(1.5)
                log["shot"] = self.screenshot()
                self.toggle_pause()
            elif sim.step_count >= 5:
                self.quit()
            action = super().__call__(sim)
            log.setdefault("actions", []).append(action)
            return action

    rc = run(str(preset), [], out=str(tmp_path / "o"), arch="cpu", viewer=Script)
    assert rc == 130  # stopped from the window: a clean interruption
    assert log["steps_after_two_singles"] == 2
    assert log["actions"][:5] == ["wait", "step", "step", "wait", "wait"]
    assert log["gas"] == 2.0 and log["jet"] is False
    assert log["colour"] != "speed" and log["view"] == "slab"
    shot = __import__("imageio.v2", fromlist=["x"]).imread(log["shot"])
    assert shot.shape[0] == 150 and shot.shape[1] > 200  # the void-fraction panel is beside the view
    s = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert s["status"] == "interrupted" and s["steps"] == 5
    assert (tmp_path / "o" / "checkpoint.h5").exists()


def test_view_without_a_display_points_to_video(tmp_path, monkeypatch):
    env_preset = pathlib.Path(__file__).resolve().parents[1] / "presets" / "settle.toml"
    import os
    import subprocess

    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    env["PYTHONPATH"] = str(pathlib.Path(__file__).resolve().parents[1])
    r = subprocess.run([sys.executable, "-m", "app", "view", str(env_preset)], capture_output=True, text=True,
                       env=env, timeout=120)
    assert r.returncode == 2
    assert "no display" in r.stderr and "--video" in r.stderr and "Traceback" not in r.stderr

"""Video frames: the renderer's frame appended to the mp4 every video.interval; the renderer itself."""
from __future__ import annotations

from ..config import ConfigError
from ..gui.video import VideoWriter
from .progress import log


def make_renderer(cfg, scene, dem, flow, name: str, show_window: bool = False):
    """The GGUI renderer for this scene, or a clear error when no Vulkan device is present."""
    try:
        from ..gui.render import Renderer, ViewSettings  # GGUI (Vulkan): loaded only when a video or window is asked

        return Renderer(dem, flow, scene.walls, cfg.domain.lo, cfg.domain.hi, ViewSettings.from_config(cfg.video),
                        title=name, show_window=show_window)
    except RuntimeError as err:
        raise ConfigError(f"the renderer could not start: {str(err).splitlines()[0] if str(err) else err}",
                          "", "--video", hint="it needs a Vulkan driver (a GPU driver, or Debian's "
                          "mesa-vulkan-drivers on the CPU); run without --video / video.enabled") from None


def renderer_for(sim, scene, name: str, viewer=None):
    """The renderer a run needs (a video, or the window of ``viewer``), or None; a window without grains to
    draw is refused."""
    if viewer is not None and sim.dem is None:
        raise ConfigError("the viewer draws grains: this scene has none", scene.file, "particles")
    if sim.dem is None or not (scene.cfg.video.enabled or viewer is not None):
        return None
    return make_renderer(scene.cfg, scene, sim.dem, sim.flow, name,
                         show_window=viewer is not None and getattr(viewer, "show_window", True))


class VideoFrames:
    """One frame per firing into the video file, its time in run.h5's /video (``time``, and ``frame``: its index
    in the file); at the end the file is closed (and the renderer, unless a window still uses it).

    A resumed run goes on with the same video: run.h5, cut back to the checkpoint, says how many of the earlier
    video's frames came before it, and those are kept ahead of the new ones (app.gui.video.VideoWriter)."""

    def __init__(self, renderer, path, fps: float, runfile, close_renderer: bool = True):
        self.renderer, self.runfile, self.close_renderer = renderer, runfile, close_renderer
        self.recorded = runfile.frame_count("video")  # frames up to the checkpoint (0 for a new run)
        self.writer = VideoWriter(path, fps, notify=log, keep_frames=self.recorded)

    @classmethod
    def attach(cls, sim, cfg, renderer, out_dir, runfile, guard, close_renderer: bool = True):
        """Frames every video.interval behind the guard when [video] is enabled (and a renderer runs); the
        VideoFrames, or None."""
        if renderer is None or not cfg.video.enabled:
            return None
        video = cls(renderer, out_dir / (cfg.video.file or "video.mp4"), cfg.video.fps, runfile, close_renderer)
        # with gas, the first frame waits for the first step: before it no void fraction is deposited
        sim.add(guard.guarded(video), cfg.video.interval, at_start=sim.flow is None, finish=video.finish)
        return video

    def __call__(self, sim) -> None:
        self.writer.write(self.renderer.frame(sim.time))
        if self.recorded is not None:  # the first frame: the earlier video's frames are in (or not)
            if self.writer.kept < self.recorded:
                self.runfile.keep_frames("video", self.writer.kept)
            self.recorded = None
        self.runfile.frame("video", sim.time, self.writer.frames - 1, dtype="i4", name="frame")

    def finish(self, sim, reason: str) -> None:
        self.writer.close()
        if self.close_renderer:
            self.renderer.close()

"""`fbed view`: the running scene in a window, with live controls.

Owns: the key bindings and the controller that turns them into calls on the run's
objects (renderer, inlet schedule, simulation clock). Every control is a plain method
(``toggle_pause``, ``step_once``, ``set_gas_factor``, ``toggle_jet``, ``cycle_colour``,
``toggle_view``, ``orbit``, ``zoom``, ``screenshot``), so a script or a test drives the
simulation exactly as the keys do. The command line composes the run with this controller
(`fbed view` is ``app.run.run`` given a ViewerController factory), so the GUI never drives the runner:
headless and windowed runs share one code path (outputs, guard, checkpoints included).

Keys: space pause/resume · n one step · up/down gas velocity x1.1 / /1.1 · j jet on/off ·
c colour mode · v slab/perspective view · left/right orbit · page up/down tilt ·
= / - zoom · right-drag orbit · p screenshot · Esc quit.
"""
import dataclasses
import os
import pathlib
import sys

import numpy as np
import taichi as ti

from .render import COLOURINGS

HELP = ("space pause/resume | n step | up/down gas x1.1 | j jet | c colour | v view | "
        "left/right orbit | pgup/pgdn tilt | =/- zoom | right-drag orbit | p screenshot | esc quit")


def display_available() -> bool:
    if sys.platform.startswith("linux"):
        return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
    return True


class ViewerController:
    """Drives a run from a window (or from a script): returns 'step', 'wait' or 'stop' to the loop."""

    def __init__(self, renderer, schedule, out_dir: pathlib.Path, handle_events: bool = True):
        self.renderer = renderer
        self.schedule = schedule
        self.out_dir = pathlib.Path(out_dir)
        self.handle_events = handle_events
        self.paused = False
        self._pending_steps = 0
        self._quit = False
        self._cursor = None
        self.sim = None
        self.screenshots = 0
        self.messages: list[str] = []

    # -- controls (the keys call these; so can a script) ----------------------------------
    def toggle_pause(self) -> bool:
        self.paused = not self.paused
        return self.paused

    def step_once(self) -> None:
        """Advance exactly one step, paused or not (pauses)."""
        self.paused = True
        self._pending_steps += 1

    def set_gas_factor(self, factor: float) -> float:
        """Scale every inlet's velocity (1 = the preset's)."""
        if self.schedule is None or not self.schedule.faces:
            self.messages.append("this scene has no velocity inlet")
            return 1.0
        self.schedule.gas_factor = max(0.0, float(factor))
        return self.schedule.gas_factor

    def toggle_jet(self) -> bool | None:
        """Open/close the jets (None where the scene has none)."""
        if self.schedule is None or not self.schedule.has_jet:
            self.messages.append("this scene has no jet")
            return None
        self.schedule.jet_enabled = not self.schedule.jet_enabled
        return self.schedule.jet_enabled

    def cycle_colour(self) -> str:
        r = self.renderer
        names = [c for c in COLOURINGS if c != "void_fraction" or r.flow is not None]
        nxt = names[(names.index(r.settings.color) + 1) % len(names)] if r.settings.color in names else names[0]
        r.settings = dataclasses.replace(r.settings, color=nxt)
        return nxt

    def toggle_view(self) -> str:
        r = self.renderer
        r.settings = dataclasses.replace(r.settings, view="slab" if r.settings.view == "perspective" else "perspective")
        return r.settings.view

    def orbit(self, d_azimuth: float, d_elevation: float = 0.0) -> None:
        self.renderer.orbit(d_azimuth, d_elevation)

    def zoom(self, factor: float) -> None:
        self.renderer.zoom_by(factor)

    def screenshot(self, path=None) -> pathlib.Path:
        import imageio.v2 as iio

        self.screenshots += 1
        path = pathlib.Path(path) if path else self.out_dir / f"screenshot-{self.screenshots:03d}.png"
        path.parent.mkdir(parents=True, exist_ok=True)
        iio.imwrite(path, self.renderer.frame(self.sim.time if self.sim else 0.0))
        self.messages.append(f"saved {path}")
        return path

    def quit(self) -> None:
        self._quit = True

    # -- the loop's side --------------------------------------------------------------------
    def _events(self) -> None:
        w = self.renderer.window
        keys = {
            " ": self.toggle_pause, "n": self.step_once, "j": self.toggle_jet, "c": self.cycle_colour,
            "v": self.toggle_view, "p": self.screenshot, "=": lambda: self.zoom(1.15), "-": lambda: self.zoom(1 / 1.15),
            ti.ui.UP: lambda: self.set_gas_factor(self.schedule.gas_factor * 1.1 if self.schedule else 1.0),
            ti.ui.DOWN: lambda: self.set_gas_factor(self.schedule.gas_factor / 1.1 if self.schedule else 1.0),
            ti.ui.LEFT: lambda: self.orbit(-5.0), ti.ui.RIGHT: lambda: self.orbit(5.0),
            "Prior": lambda: self.orbit(0.0, 5.0), "Next": lambda: self.orbit(0.0, -5.0), ti.ui.ESCAPE: self.quit,
        }
        for e in w.get_events(ti.ui.PRESS):
            fn = keys.get(e.key)
            if fn is not None:
                fn()
        if w.is_pressed(ti.ui.RMB):
            c = np.asarray(w.get_cursor_pos())
            if self._cursor is not None:
                d = c - self._cursor
                self.orbit(180.0 * d[0], -90.0 * d[1])
            self._cursor = c
        else:
            self._cursor = None
        if not w.running:
            self._quit = True

    def __call__(self, sim) -> str:
        self.sim = sim
        if self.handle_events:
            self._events()
            self.renderer.draw()
            gui = self.renderer.window.get_gui()
            with gui.sub_window("fbed", 0.01, 0.01, 0.42, 0.12) as g:
                g.text(f"t = {sim.time:.3f} s  {'paused' if self.paused else 'running'}"
                       + (f"  gas x{self.schedule.gas_factor:.2f}" if self.schedule and self.schedule.faces else "")
                       + ("" if not (self.schedule and self.schedule.has_jet)
                          else f"  jet {'on' if self.schedule.jet_enabled else 'off'}"))
                g.text(HELP)
                if self.messages:
                    g.text(self.messages[-1])
            self.renderer.show()
        if self._quit:
            return "stop"
        if self._pending_steps:
            self._pending_steps -= 1
            return "step"
        return "wait" if self.paused else "step"

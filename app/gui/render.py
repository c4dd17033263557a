"""The renderer: draws a render snapshot with Taichi's GGUI, offscreen or in a window.

Owns: the render snapshot (positions, radii and colours of the grains to draw, copied
from the DEM's field bundle by one kernel on the device, so a frame never round-trips the
grains through the host), colour maps, camera presets, the vessel outline, the
void-fraction panel and the text stamp. It only reads the simulation's fields.

Views:
- ``perspective``: the whole bed from a preset camera (azimuth, elevation, distance).
- ``slab``: grains with |y - y_c| < w/2 seen from -y through a distant, nearly orthographic camera: the
  view in which bubbles show as holes, like the MRI and X-ray slices.
With gas, a second panel shows the void fraction on the central vertical plane (x-z at
the middle y cell) as a colour map, at the same height scale as the slab view.

Frames come back as (height, width, 3) uint8 arrays; the caller writes them to a video
or a PNG. GGUI needs a Vulkan device: a GPU driver, or Mesa's software rasterizer
(Debian ``mesa-vulkan-drivers``) on machines without one.
"""
import dataclasses
import enum
import math
import time as wallclock

import numpy as np
import taichi as ti

from ..sim.dem import grain_id, grain_radius


class Colouring(enum.IntEnum):
    SPEED = 0
    HEIGHT = 1
    VOID_FRACTION = 2
    SIZE = 3
    TRACER = 4


COLOURINGS = {"speed": Colouring.SPEED, "height": Colouring.HEIGHT, "void_fraction": Colouring.VOID_FRACTION,
              "size": Colouring.SIZE, "tracer": Colouring.TRACER}
LABELS = {Colouring.SPEED: ("speed", "m/s"), Colouring.HEIGHT: ("height", "m"),
          Colouring.VOID_FRACTION: ("void fraction", ""), Colouring.SIZE: ("radius", "m"),
          Colouring.TRACER: ("initial height band", "")}
LUT_SIZE = 256


def colour_table(name: str = "viridis", n: int = LUT_SIZE) -> np.ndarray:
    """(n, 3) float32 RGB samples of a matplotlib colour map."""
    from matplotlib import colormaps

    return colormaps[name](np.linspace(0.0, 1.0, n))[:, :3].astype(np.float32)


@ti.data_oriented
class _Absent:
    """Stands in for the gas fields in a grains-only scene (kernels never read it)."""


@ti.data_oriented
class RenderSnapshot:
    """What a frame draws: the visible grains (compacted to the first ``count`` slots)."""

    def __init__(self, n: int, tracer: bool):
        self.position = ti.Vector.field(3, ti.f32, max(n, 1))
        self.color = ti.Vector.field(3, ti.f32, max(n, 1))
        self.radius = ti.field(ti.f32, max(n, 1))
        self.count = ti.field(ti.i32, ())
        self.lut = ti.Vector.field(3, ti.f32, LUT_SIZE)
        self.lut.from_numpy(colour_table())
        if tracer:  # initial height of every grain, recorded on the first frame
            self.tracer = ti.field(ti.f32, max(n, 1))


@ti.kernel
def record_tracer(m: ti.template(), g: ti.template(), s: ti.template(), out: ti.template()):
    for i in range(m.n):  # by grain id: the DEM may re-order its grains in memory
        out.tracer[grain_id(m, g, i)] = ti.cast(s.x[i][2], ti.f32)


@ti.kernel
def take_snapshot(m: ti.template(), g: ti.template(), s: ti.template(), gas: ti.template(),
                  gas_eps: ti.types.ndarray(), mode: ti.template(), slab: ti.template(), y_centre: ti.f32,
                  half_width: ti.f32, lo: ti.f32, hi: ti.f32, band: ti.f32, out: ti.template()):
    """Copy the visible grains of the DEM state into ``out`` with their colours (inputs first)."""
    out.count[None] = 0
    for i in range(m.n):
        x = s.x[i]
        keep = s.alive[i] != 0
        if ti.static(slab):
            keep = keep and ti.abs(ti.cast(x[1], ti.f32) - y_centre) < half_width
        if keep:
            r = grain_radius(m, g, i)
            value = ti.f32(0.0)
            if ti.static(mode == Colouring.SPEED):
                value = ti.cast(s.v[i].norm(), ti.f32)
            if ti.static(mode == Colouring.HEIGHT):
                value = ti.cast(x[2], ti.f32)
            if ti.static(mode == Colouring.VOID_FRACTION):
                value = ti.cast(gas_eps[gas.cell_of(x)], ti.f32)
            if ti.static(mode == Colouring.SIZE):
                value = ti.cast(r, ti.f32)
            if ti.static(mode == Colouring.TRACER):
                # alternate bands of initial height: mixing shows as the bands break up
                value = lo if (out.tracer[grain_id(m, g, i)] / band) % 2.0 < 1.0 else hi
            t = ti.min(ti.max((value - lo) / ti.max(hi - lo, 1e-30), 0.0), 1.0)
            k = ti.atomic_add(out.count[None], 1)
            out.position[k] = ti.cast(x, ti.f32)
            out.radius[k] = ti.cast(r, ti.f32)
            out.color[k] = out.lut[ti.cast(t * (LUT_SIZE - 1), ti.i32)]


@dataclasses.dataclass(frozen=True)
class ViewSettings:
    """How frames look: plain values from the preset's [video] table (see app/config/schema.py)."""

    width: int = 1280
    height: int = 720
    view: str = "perspective"
    color: str = "speed"
    color_range: tuple = (0.0, 0.0)
    slab_width: float = 0.0
    void_panel: bool = True
    camera_azimuth: float = -60.0
    camera_elevation: float = 20.0
    camera_distance: float = 0.0

    @classmethod
    def from_config(cls, video) -> "ViewSettings":
        return cls(**{f.name: getattr(video, f.name) for f in dataclasses.fields(cls)})


def vessel_outline(walls, lo, hi, segments: int = 64) -> np.ndarray:
    """Line segments (2k, 3) [m] outlining the vessel: a cylinder's rims and four sides, or the domain box."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    cyl = next((w for w in walls if type(w).__name__ == "CylinderWall"), None)
    segs = []
    if cyl is not None:
        cx, cy = cyl.center
        a = np.linspace(0.0, 2 * math.pi, segments + 1)
        for z in (lo[2], hi[2]):
            ring = np.stack([cx + cyl.radius * np.cos(a), cy + cyl.radius * np.sin(a), np.full_like(a, z)], -1)
            segs += [p for k in range(segments) for p in (ring[k], ring[k + 1])]
        for ang in (0.0, math.pi):  # the sides seen from -y (the slab view's walls)
            x, y = cx + cyl.radius * math.cos(ang), cy + cyl.radius * math.sin(ang)
            segs += [(x, y, lo[2]), (x, y, hi[2])]
    else:
        corners = [np.array([(hi if (c >> a) & 1 else lo)[a] for a in range(3)]) for c in range(8)]
        for c in range(8):
            for a in range(3):
                if not (c >> a) & 1:
                    segs += [corners[c], corners[c | (1 << a)]]
    return np.asarray(segs, np.float32)


class Renderer:
    """Draws frames of a running scene. ``dem`` is the DemSolver, ``flow`` the FlowSolver or None.

    ``show_window``: a real window (``fbed view``) instead of an offscreen surface. Either way
    ``frame()`` returns the picture as an array, so headless and windowed runs share this path."""

    def __init__(self, dem, flow, walls, lo, hi, settings: ViewSettings, title: str = "fbed",
                 show_window: bool = False):
        self.dem, self.flow = dem, flow
        self.settings = settings
        self.title = title
        self.lo, self.hi = np.asarray(lo, float), np.asarray(hi, float)
        self.show_window = show_window
        m = dem.m
        self.grain_diameter = 2.0 * float(dem.radii().max()) if m.n else 0.0
        self.snapshot = RenderSnapshot(m.n, tracer=True)
        self._tracer_recorded = False
        self._band = 1.0  # [m] width of the tracer bands (set from the bed when the tracer is recorded)
        self._gas = flow.fields if flow is not None else _Absent()
        self._gas_eps = flow.fields.eps if flow is not None else ti.ndarray(ti.f32, (1, 1, 1))  # the gas's own array
        self.window = ti.ui.Window(title, (settings.width, settings.height), show_window=show_window, vsync=False)
        self.canvas = self.window.get_canvas()
        self.scene = self.window.get_scene()
        self.camera = ti.ui.Camera()
        outline = vessel_outline(walls, self.lo, self.hi)
        self.outline = ti.Vector.field(3, ti.f32, len(outline))
        self.outline.from_numpy(outline)
        self.azimuth = settings.camera_azimuth
        self.elevation = settings.camera_elevation
        self.zoom = 1.0
        self.render_seconds = 0.0  # wall time spent in frame(), for the cost report
        self.frames = 0

    # -- what is drawn ------------------------------------------------------------------
    @property
    def colouring(self) -> Colouring:
        c = COLOURINGS[self.settings.color]
        if c == Colouring.VOID_FRACTION and self.flow is None:
            return Colouring.SPEED
        return c

    def colour_range(self) -> tuple[float, float]:
        lo, hi = self.settings.color_range
        if (lo, hi) != (0.0, 0.0):
            return float(lo), float(hi)
        c = self.colouring
        if c == Colouring.SPEED:
            return 0.0, 1.0
        if c == Colouring.HEIGHT:
            return float(self.lo[2]), float(self.hi[2])
        if c == Colouring.VOID_FRACTION:
            return 0.35, 1.0
        if c == Colouring.SIZE:
            r = self.dem.radii()
            return float(r.min()) * 0.999, float(r.max()) * 1.001
        return 0.25, 0.75

    def slab_half_width(self) -> float:
        w = self.settings.slab_width
        if w <= 0:
            w = max(3.0 * self.grain_diameter, 0.05 * (self.hi[1] - self.lo[1]))
        return 0.5 * w

    def update_snapshot(self) -> int:
        """Copy the visible grains into the render snapshot; returns how many are drawn."""
        m, s = self.dem.m, self.dem.state
        c = self.colouring
        if c == Colouring.TRACER and not self._tracer_recorded:
            record_tracer(m, self.dem.fixed, s, self.snapshot)
            z = self.snapshot.tracer.to_numpy()[: m.n]
            self._band = max(float(np.percentile(z, 95) - self.lo[2]) / 8.0, 1e-9) if m.n else 1.0
            self._tracer_recorded = True
        lo, hi = self.colour_range()
        slab = self.settings.view == "slab"
        yc = 0.5 * (self.lo[1] + self.hi[1])
        take_snapshot(m, self.dem.fixed, s, self._gas, self._gas_eps, c, slab, yc, self.slab_half_width(), lo, hi,
                      self._band, self.snapshot)
        return int(self.snapshot.count[None])

    # -- cameras --------------------------------------------------------------------------
    def _place_camera(self) -> None:
        cam, st = self.camera, self.settings
        centre = 0.5 * (self.lo + self.hi)
        ext = self.hi - self.lo
        aspect = st.width / st.height
        if st.view == "slab":
            # from -y, the domain's x-z rectangle fitted to the frame. A telephoto perspective
            # (5 degree field, camera far away) stands in for an orthographic camera: GGUI 1.7.4's
            # orthographic mode draws particles with a radius that ignores the zoom, and
            # upside down. The slab is thin, so the parallax is below a percent.
            half_h = 0.52 * max(ext[2], ext[0] / aspect) / self.zoom
            fov = 5.0
            dist = half_h / math.tan(math.radians(fov / 2))
            cam.projection_mode(ti.ui.ProjectionMode.Perspective)
            cam.position(centre[0], centre[1] - dist, centre[2])
            cam.lookat(centre[0], centre[1], centre[2])
            cam.up(0.0, 0.0, 1.0)
            cam.fov(fov)
            cam.z_near(max(1e-4, dist - ext.max()))
            cam.z_far(dist + ext.max())
            return
        fov = 35.0
        dist = st.camera_distance
        if dist <= 0:
            radius = 0.5 * float(np.linalg.norm(ext))
            dist = 1.1 * radius / math.sin(math.radians(fov / 2) * min(1.0, aspect))
        dist /= self.zoom
        az, el = math.radians(self.azimuth), math.radians(self.elevation)
        eye = centre + dist * np.array([math.sin(az) * math.cos(el), -math.cos(az) * math.cos(el), math.sin(el)])
        cam.projection_mode(ti.ui.ProjectionMode.Perspective)
        cam.position(*eye)
        cam.lookat(*centre)
        cam.up(0.0, 0.0, 1.0)
        cam.fov(fov)
        cam.z_near(max(1e-4, 0.01 * dist))
        cam.z_far(10.0 * dist)

    def orbit(self, d_azimuth: float, d_elevation: float) -> None:
        """Turn the perspective camera [deg]."""
        self.azimuth += d_azimuth
        self.elevation = min(89.0, max(-89.0, self.elevation + d_elevation))

    def zoom_by(self, factor: float) -> None:
        self.zoom = min(20.0, max(0.05, self.zoom * factor))

    # -- frames ---------------------------------------------------------------------------
    def draw(self) -> None:
        """Draw the scene into the window's surface (no read-back)."""
        n = self.update_snapshot()
        self._place_camera()
        sc = self.scene
        sc.set_camera(self.camera)
        sc.ambient_light((0.45, 0.45, 0.45))
        centre = 0.5 * (self.lo + self.hi)
        sc.point_light(tuple(centre + np.array([0.0, -3.0, 3.0]) * float((self.hi - self.lo).max())), (0.8, 0.8, 0.8))
        if n:
            sc.particles(self.snapshot.position, radius=0.0, per_vertex_color=self.snapshot.color,
                         per_vertex_radius=self.snapshot.radius, index_count=n)
        sc.lines(self.outline, width=2.0, color=(0.35, 0.35, 0.35))
        self.canvas.set_background_color((1.0, 1.0, 1.0))
        self.canvas.scene(sc)

    def frame(self, time: float) -> np.ndarray:
        """The current frame as (H, W, 3) uint8: the 3-D view, the void-fraction panel, the stamp."""
        t0 = wallclock.perf_counter()
        self.draw()
        img = self.window.get_image_buffer_as_numpy()  # (W, H, 4) float, origin bottom-left
        view = (np.clip(img[..., :3], 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8).transpose(1, 0, 2)[::-1]
        parts = [view]
        if self.flow is not None and self.settings.void_panel:
            parts.append(void_panel(self.flow, self.settings.height, self.lo, self.hi, self.settings.view == "slab",
                                    self.snapshot.lut.to_numpy()))
        out = np.ascontiguousarray(np.concatenate(parts, axis=1))
        lo, hi = self.colour_range()
        label, unit = LABELS[self.colouring]
        stamp(out, [f"{self.title}", f"t = {time:.3f} s",
                    f"colour: {label} {lo:.3g}-{hi:.3g} {unit}".rstrip() if self.colouring != Colouring.TRACER
                    else f"colour: {label}"])
        self.render_seconds += wallclock.perf_counter() - t0
        self.frames += 1
        return out

    def show(self) -> None:
        """Present the drawn frame in the window (windowed mode only)."""
        self.window.show()

    def close(self) -> None:
        try:
            self.window.destroy()
        except Exception:  # noqa: BLE001 - a GGUI teardown error must not lose the run's outputs
            pass


def void_panel(flow, height: int, lo, hi, match_slab: bool, lut: np.ndarray) -> np.ndarray:
    """Void fraction on the central vertical x-z plane, (height, w, 3) uint8 with a colour bar.

    Cells outside the vessel are grey. With ``match_slab`` the panel uses the slab view's
    vertical scale (the domain's height fills the frame the same way), so the two panels line up."""
    eps = flow.fields.eps.to_numpy()
    active = flow.fields.active.to_numpy()
    jc = eps.shape[1] // 2
    plane = eps[:, jc, :].T[::-1]  # rows top to bottom = z high to low, columns = x
    mask = active[:, jc, :].T[::-1] > 0
    nz, nx = plane.shape
    t = np.clip((plane - 0.35) / 0.65, 0.0, 1.0)
    rgb = (lut[(t * (len(lut) - 1)).astype(int)] * 255).astype(np.uint8)
    rgb[~mask] = 200
    # integer cell size in pixels so the grid stays crisp (nearest neighbour)
    scale = max(1, int(0.95 * height / nz)) if not match_slab else max(1, int(height / (1.04 * nz)))
    img = np.repeat(np.repeat(rgb, scale, axis=0), scale, axis=1)
    bar_w = max(8, height // 40)
    bar = (lut[np.linspace(len(lut) - 1, 0, img.shape[0]).astype(int)] * 255).astype(np.uint8)
    bar = np.repeat(bar[:, None, :], bar_w, axis=1)
    margin = max(8, height // 50)
    panel = np.full((height, img.shape[1] + bar_w + 6 * margin, 3), 255, np.uint8)
    top = (height - img.shape[0]) // 2
    panel[top:top + img.shape[0], margin:margin + img.shape[1]] = img
    x0 = 2 * margin + img.shape[1]
    panel[top:top + img.shape[0], x0:x0 + bar_w] = bar
    stamp(panel, ["eps (y = centre)"], origin=(margin, 2))
    stamp(panel, ["1.0"], origin=(x0 + bar_w + 2, top))
    stamp(panel, ["0.35"], origin=(x0 + bar_w + 2, top + img.shape[0] - 14))
    return panel


_FONT = {}


def stamp(img: np.ndarray, lines: list[str], origin: tuple[int, int] = (10, 8)) -> None:
    """Write text lines onto an (H, W, 3) uint8 image in place (Pillow's built-in font)."""
    from PIL import Image, ImageDraw, ImageFont

    size = max(12, img.shape[0] // 45)
    if size not in _FONT:
        try:
            _FONT[size] = ImageFont.load_default(size=size)
        except TypeError:  # Pillow < 10.1: fixed-size bitmap font
            _FONT[size] = ImageFont.load_default()
    pil = Image.fromarray(img)
    d = ImageDraw.Draw(pil)
    x, y = origin
    for line in lines:
        d.text((x, y), line, fill=(0, 0, 0), font=_FONT[size])
        y += int(size * 1.3)
    img[...] = np.asarray(pil)

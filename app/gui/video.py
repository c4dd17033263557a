"""Video files: frames (H, W, 3) uint8 in, an H.264 mp4 out.

Owns: the choice of encoder. First choice is imageio with imageio-ffmpeg (libx264,
yuv420p: plays in browsers and common players). Where imageio-ffmpeg is missing (the GPU
machine has no ffmpeg binary) it falls back to OpenCV's writer ('avc1' = H.264 where OpenCV's
FFmpeg has it, else 'mp4v' = MPEG-4 Part 2, which plays in VLC/ffplay but not in every browser),
and as a last resort writes numbered PNG frames into a folder. The fallback is reported once
through ``notify``. No Taichi here.

A video file is written under a temporary name beside its own (``video.tmp.mp4``) and takes its name only when
it is whole (:func:`mp4_complete`), so a run killed while recording leaves the earlier video as it was. A resumed
run keeps the first ``keep_frames`` frames of that earlier video ahead of its own (re-encoded: one file, as an
unbroken run would have made).
"""
from __future__ import annotations

import pathlib
from typing import Callable


class VideoWriter:
    def __init__(self, path: pathlib.Path, fps: float, notify: Callable[[str], None] = print, keep_frames: int = 0):
        """``keep_frames``: how many first frames of the video already at ``path`` to keep ahead of the new ones
        (a resumed run: those up to its checkpoint); ``kept`` says how many were, once the first frame is in."""
        self.path = pathlib.Path(path)
        self.fps = float(fps)
        self.notify = notify
        self.keep_frames, self.kept = keep_frames, 0
        self.frames = 0
        self.encoder = ""
        self._writer = None
        self._size = None
        self.writing.unlink(missing_ok=True)  # a torn one left by a killed run

    @property
    def writing(self) -> pathlib.Path:
        """Where the file is written until it is whole."""
        return self.path.with_name(f"{self.path.stem}.tmp{self.path.suffix}")

    def _open(self, shape) -> None:
        h, w = shape[:2]
        self._size = (h, w)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        try:
            import imageio.v2 as iio
            import imageio_ffmpeg  # noqa: F401  (present: the H.264 path works)

            self._writer = iio.get_writer(str(self.writing), format="FFMPEG", mode="I", fps=self.fps,
                                          codec="libx264", pixelformat="yuv420p", quality=8, macro_block_size=1,
                                          ffmpeg_log_level="error")
            self.encoder = "ffmpeg/libx264"
            self._keep(shape)
            return
        except ImportError:
            pass
        try:
            import cv2

            for fourcc in ("avc1", "mp4v"):
                wr = cv2.VideoWriter(str(self.writing), cv2.VideoWriter_fourcc(*fourcc), self.fps, (w, h))
                if wr.isOpened():
                    self._writer, self.encoder = wr, f"opencv/{fourcc}"
                    self.notify(f"fbed: imageio-ffmpeg is not installed; writing {self.path.name} with OpenCV "
                                f"({fourcc}{'' if fourcc == 'avc1' else ', MPEG-4 part 2: VLC and ffplay play it'})")
                    self._keep(shape)
                    return
                wr.release()
        except ImportError:
            pass
        self.path = self.path.with_suffix("")
        self.path.mkdir(parents=True, exist_ok=True)
        self.encoder = "png"
        self.notify(f"fbed: no video encoder found (pip install imageio-ffmpeg); writing PNG frames into {self.path}/")
        self.kept = self.frames = min(self.keep_frames, len(list(self.path.glob("frame_*.png"))))
        for stale in self.path.glob("frame_*.png"):  # frames past the checkpoint: written again, or not at all
            if int(stale.stem.split("_")[1]) >= self.kept:
                stale.unlink()

    def _keep(self, shape) -> None:
        """The first ``keep_frames`` frames of the earlier video, ahead of the new ones: read back (imageio-ffmpeg)
        only from a whole file of the same frame size; otherwise the video starts again, and ``notify`` says why
        (an earlier file of another size is kept aside)."""
        old, n = self.path, self.keep_frames
        if n <= 0:
            return
        if not (old.is_file() and mp4_complete(old)):
            self.notify(f"fbed: {old.name} is missing or unfinished (its run was killed while recording): the video "
                        "starts again at this run's first frame")
            return
        aside = old.with_name(f"{old.stem}.before_resume{old.suffix}")
        try:
            import imageio.v2 as iio
            import imageio_ffmpeg  # noqa: F401
        except ImportError:
            old.replace(aside)
            self.notify(f"fbed: reading {old.name} back needs imageio-ffmpeg: it is kept as {aside.name}, and the "
                        "video starts again")
            return
        try:
            with iio.get_reader(str(old), format="FFMPEG") as reader:
                for frame in reader:
                    if self.kept == n or frame.shape[:2] != shape[:2]:
                        break
                    self._append(frame)
                    self.kept += 1
        except (OSError, RuntimeError, ValueError):  # a file that decodes only so far: its frames up to there
            pass
        if self.kept == 0:
            old.replace(aside)
            self.notify(f"fbed: {old.name}'s frames are not {shape[1]} x {shape[0]} px like this run's (video.width, "
                        f"video.height): it is kept as {aside.name}, and the video starts again")
        elif self.kept < n:
            self.notify(f"fbed: {old.name} holds {self.kept} of the {n} frames recorded up to the checkpoint (the "
                        "others were lost with a killed run): the video goes on after them, with a gap")
        self.frames = self.kept

    def write(self, frame) -> None:
        import numpy as np

        frame = np.asarray(frame, np.uint8)
        # yuv420p needs even sizes: pad by one row/column of white where needed
        h, w = frame.shape[:2]
        if h % 2 or w % 2:
            frame = np.pad(frame, ((0, h % 2), (0, w % 2), (0, 0)), constant_values=255)
        if self._size is None:
            self._open(frame.shape)
        if frame.shape[:2] != self._size:
            raise ValueError(f"video frames must keep one size: {self._size}, got {frame.shape[:2]}")
        self._append(frame)
        self.frames += 1

    def _append(self, frame) -> None:
        import numpy as np

        if self.encoder.startswith("ffmpeg"):
            try:
                self._writer.append_data(frame)
            except OSError as err:  # ffmpeg gone: a full disk is named as every writer of a run names it
                self._failed(err, frame.nbytes)
        elif self.encoder.startswith("opencv"):
            self._writer.write(np.ascontiguousarray(frame[..., ::-1]))
        else:
            import imageio.v2 as iio

            iio.imwrite(self.path / f"frame_{self.frames:05d}.png", frame)

    def close(self) -> None:
        if self._writer is not None:
            writer, self._writer = self._writer, None
            if self.encoder.startswith("ffmpeg"):
                try:
                    writer.close()
                except OSError as err:  # the trailer, written last, may be what finds the disk full
                    self._failed(err, None)
            else:
                writer.release()
            if not self.writing.parent.is_dir():  # the run's folder removed or moved while it recorded
                from ..io import store

                raise store.FolderGone(self.path)
            # neither imageio-ffmpeg nor OpenCV reports an encoder that failed at its end (ffmpeg's exit status is
            # not read): the file itself says whether its index was written
            if not mp4_complete(self.writing):
                self._failed(OSError(f"{self.path.name}: the encoder ({self.encoder}) ended without finishing it "
                                     "(no index at its end)"), None)
            self.writing.replace(self.path)

    def _failed(self, err: OSError, nbytes: int | None) -> None:
        """ffmpeg stopped: the torn file goes; where the disk is full (its message says so, or the folder has no
        room left) a :class:`~app.io.store.DiskFull` is raised (the run then stops cleanly with its last
        checkpoint, exit 3); any other failure as it came."""
        from ..io import store

        free = store.free_bytes(self.path.parent)
        writer, self._writer = self._writer, None
        if writer is not None:
            try:
                writer.close()
            except OSError:
                pass
        written = self.writing.stat().st_size if self.writing.is_file() else 0
        self.writing.unlink(missing_ok=True)  # the earlier video, if any, stays as it was
        if not (store.is_disk_full(err) or free < store.SPACE_MARGIN):
            raise err
        raise store.DiskFull(self.path, nbytes, free, written) from None


def mp4_complete(path: pathlib.Path) -> bool:
    """Whether an mp4 file is whole: its top-level boxes (ISO/IEC 14496-12: a 32-bit size, or 1 and a 64-bit size
    after the type; 0: to the end of the file) tile the file exactly and include the index ('moov'), which
    encoders write last. A file cut short by a full disk has an 'mdat' whose size was never filled in (0) or runs
    past the end, and no index. Other containers than .mp4, .m4v, .mov are not checked (True)."""
    import struct

    if path.suffix.lower() not in (".mp4", ".m4v", ".mov"):
        return True
    size, at, boxes = path.stat().st_size, 0, set()
    with open(path, "rb") as f:
        while at + 8 <= size:
            f.seek(at)
            length, kind = struct.unpack(">I4s", f.read(8))
            if length == 1:
                length = struct.unpack(">Q", f.read(8))[0]
            boxes.add(kind)
            if length == 0:  # "to the end of the file": what an unfinished 'mdat' holds; the index must be before it
                at = size
            elif length < 8:
                return False
            else:
                at += length
    return at == size and b"moov" in boxes


"""The one drive-video renderer (ROS-free): camera frames + what the car knew and did -> an H.264 MP4.

Used by `msfsu-benchmark --video`, the demo's closed-loop route and `msfsu-bag-video` alike. A video
frame is the front RGB with

- the segmentation overlaid on the rows it covers (the network sees the bottom part of the image:
  `segmentation_top` = the checkpoint's crop_top_fraction; ground truth covers the whole image),
- text in the sky band: time, command, speed and target speed, steer (number and bar), throttle/brake,
  and a status line (the episode outcome at its end),
- a top-down inset: the route (grey), the path driven so far (yellow), the car (red dot + heading).

Encoding: imageio-ffmpeg's bundled ffmpeg (libx264, yuv420p, faststart), which every browser and
player opens; frames are streamed to ffmpeg, nothing is held in memory.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from msfsu_common.road_option import RoadOption
from msfsu_common.semantic_classes import colourise

FPS = 10  # the simulator's rate
SEGMENTATION_ALPHA = 0.45
TEXT_COLOUR = (255, 255, 255)
ROUTE_COLOUR = (170, 170, 170)
PATH_COLOUR = (255, 210, 0)
INTERVENTION_COLOUR = (220, 30, 30)  # the emergency brake's band while it intervenes
CAR_COLOUR = (255, 40, 40)
ENCODER_PARAMS = ["-preset", "veryfast", "-crf", "26", "-movflags", "+faststart", "-threads", "1"]


@dataclass(frozen=True)
class DriveState:
    """Everything written over one camera frame; None = not known (left out of the frame)."""

    time_s: float
    speed_mps: float | None = None
    command: int | None = None  # RoadOption value
    steer: float | None = None  # the driver's steer, [-1, 1] positive right
    action_source: str = ""  # who chose steer and target speed, when it is not the network ("expert")
    target_speed_mps: float | None = None
    throttle: float | None = None
    brake: float | None = None
    segmentation: np.ndarray | None = None  # (h, w) uint8 class ids
    segmentation_top: float = 0.0  # fraction of image rows above the segmentation (crop of the network)
    segmentation_label: str = "predicted"
    pose: tuple[float, float, float] | None = None  # x, y, yaw (map frame)
    status: str = ""  # e.g. the outcome of the episode on its last frame
    intervention: str = ""  # the emergency brake's, while it intervenes ("AEB BRAKE: ... 3.1 m, TTC 0.9 s")


def command_name(value: int | None) -> str:
    if value is None:
        return "-"
    try:
        return RoadOption(int(value)).name
    except ValueError:
        return f"command {value}"


class DriveRenderer:
    """Turns (RGB, DriveState) into video frames; remembers the route and the path driven since it was set."""

    def __init__(self) -> None:
        self.route_xy: np.ndarray | None = None
        self.path: list[tuple[float, float]] = []

    def set_route(self, route_xy: np.ndarray | None) -> None:
        """A new route (N, 2) map-frame points, or None; the path driven starts again."""
        self.route_xy = None if route_xy is None or len(route_xy) == 0 else np.asarray(route_xy, np.float64)[:, :2]
        self.path = []

    def render(self, rgb: np.ndarray, state: DriveState) -> np.ndarray:
        """(H, W, 3) uint8 RGB -> a new (H, W, 3) uint8 video frame."""
        frame = np.array(rgb[..., :3], np.uint8, copy=True, order="C")
        height, width = frame.shape[:2]
        pose = state.pose if state.pose is not None and all(map(math.isfinite, state.pose)) else None
        if pose is not None:
            self.path.append((pose[0], pose[1]))
        if state.segmentation is not None:
            self._overlay_segmentation(frame, state.segmentation, state.segmentation_top)
        scale = max(height / 300.0, 0.5)
        self._draw_text(frame, state, scale)
        if state.intervention:
            self._draw_intervention(frame, state.intervention, scale)
        if self.route_xy is not None or self.path:
            self._draw_inset(frame, pose, int(round(min(height, width) * 0.36)))
        return frame

    # ----- layers -----
    @staticmethod
    def _overlay_segmentation(frame: np.ndarray, class_ids: np.ndarray, top: float) -> None:
        height, width = frame.shape[:2]
        first = int(round(height * min(max(top, 0.0), 1.0)))
        if first >= height:
            return
        ids = cv2.resize(np.ascontiguousarray(class_ids, np.uint8), (width, height - first),
                         interpolation=cv2.INTER_NEAREST)
        region = frame[first:]
        cv2.addWeighted(colourise(ids), SEGMENTATION_ALPHA, region, 1.0 - SEGMENTATION_ALPHA, 0.0, dst=region)

    @staticmethod
    def _draw_text(frame: np.ndarray, state: DriveState, scale: float) -> None:
        lines = [f"t {state.time_s:6.1f} s   {command_name(state.command)}"]
        speed = "-" if state.speed_mps is None else f"{state.speed_mps:4.1f}"
        target = "" if state.target_speed_mps is None else f"  target {state.target_speed_mps:4.1f}"
        lines.append(f"speed {speed} m/s{target}")
        steer = "-" if state.steer is None else f"{state.steer:+.2f}"
        pedals = ""
        if state.throttle is not None and state.brake is not None:
            pedals = f"  thr {state.throttle:.2f} brk {state.brake:.2f}"
        source = f"  ({state.action_source})" if state.action_source else ""
        lines.append(f"steer {steer}{pedals}{source}")
        if state.segmentation is not None:
            lines.append(f"segmentation: {state.segmentation_label}")
        if state.status:
            lines.append(state.status)
        font, size, thickness = cv2.FONT_HERSHEY_SIMPLEX, 0.42 * scale, max(1, int(round(scale)))
        line_px = int(round(17 * scale))
        band = line_px * len(lines) + int(8 * scale)
        panel_w = int(round(250 * scale))
        region = frame[:band, :panel_w]
        region[:] = (region.astype(np.uint16) * 2 // 5).astype(np.uint8)  # darken behind the text
        for index, text in enumerate(lines):
            origin = (int(6 * scale), int(round(line_px * (index + 1))))
            cv2.putText(frame, text, origin, font, size, TEXT_COLOUR, thickness, cv2.LINE_AA)
        if state.steer is not None:  # steer bar under the text: centre tick, filled to the steer value
            y0, y1 = band, band + int(6 * scale)
            x0, x1 = int(6 * scale), panel_w - int(6 * scale)
            centre = (x0 + x1) // 2
            frame[y0:y1, x0:x1] = (frame[y0:y1, x0:x1].astype(np.uint16) * 2 // 5).astype(np.uint8)
            end = centre + int(round(float(np.clip(state.steer, -1, 1)) * (x1 - x0) / 2))
            frame[y0:y1, min(centre, end):max(centre, end) + 1] = PATH_COLOUR
            frame[y0 - 1:y1 + 1, centre] = TEXT_COLOUR

    @staticmethod
    def _draw_intervention(frame: np.ndarray, text: str, scale: float) -> None:
        """A red band across the bottom of the frame with the emergency brake's decision."""
        height, width = frame.shape[:2]
        band = int(round(22 * scale))
        region = frame[height - band:]
        region[:] = (region.astype(np.uint16) * 2 // 5 + np.array(INTERVENTION_COLOUR, np.uint16) * 3 // 5).astype(
            np.uint8)
        cv2.putText(frame, text, (int(6 * scale), height - int(7 * scale)), cv2.FONT_HERSHEY_SIMPLEX, 0.45 * scale,
                    TEXT_COLOUR, max(1, int(round(scale))), cv2.LINE_AA)

    def _draw_inset(self, frame: np.ndarray, pose: tuple[float, float, float] | None, side: int) -> None:
        height, width = frame.shape[:2]
        margin = max(4, side // 20)
        x0, y0 = width - side - margin, margin
        inset = frame[y0:y0 + side, x0:x0 + side]
        inset[:] = (inset.astype(np.uint16) // 3).astype(np.uint8)
        path = np.asarray(self.path, np.float64).reshape(-1, 2)
        everything = np.concatenate([p for p in (self.route_xy, path) if p is not None and len(p)])
        everything = everything[np.isfinite(everything).all(axis=1)]
        if len(everything) == 0:
            return
        low, high = everything.min(axis=0), everything.max(axis=0)
        span = max(float((high - low).max()), 20.0)  # at least 20 m across, so a short path is not a blob
        centre = (low + high) / 2
        pad = side * 0.08
        pixels_per_m = (side - 2 * pad) / span

        def to_pixels(xy: np.ndarray) -> np.ndarray:
            # map x right, map y up (counter-clockwise yaw): image rows grow downwards
            u = side / 2 + (xy[:, 0] - centre[0]) * pixels_per_m
            v = side / 2 - (xy[:, 1] - centre[1]) * pixels_per_m
            return np.round(np.stack([u, v], axis=1) * 16).astype(np.int32)  # 4 fractional bits

        line = max(1, side // 60)
        if self.route_xy is not None and np.isfinite(self.route_xy).all():
            cv2.polylines(inset, [to_pixels(self.route_xy)], False, ROUTE_COLOUR, line, cv2.LINE_AA, shift=4)
        if len(path) > 1:
            cv2.polylines(inset, [to_pixels(path)], False, PATH_COLOUR, line, cv2.LINE_AA, shift=4)
        if pose is not None:
            x, y, yaw = pose
            car = to_pixels(np.array([[x, y]]))[0]
            nose = to_pixels(np.array([[x + math.cos(yaw) * 0.08 * span, y + math.sin(yaw) * 0.08 * span]]))[0]
            cv2.line(inset, tuple(car), tuple(nose), CAR_COLOUR, line + 1, cv2.LINE_AA, shift=4)
            cv2.circle(inset, tuple(car), max(2, side // 30) * 16, CAR_COLOUR, -1, cv2.LINE_AA, shift=4)
        cv2.rectangle(inset, (0, 0), (side - 1, side - 1), ROUTE_COLOUR, 1)


class VideoWriter:
    """Streams frames into an MP4 (H.264) through imageio-ffmpeg's bundled ffmpeg.

    Written to `<name>.partial.mp4` and renamed on `close()`, so a file named `path` is always complete;
    `discard()` removes it instead. Frames of odd width/height lose their last column/row (yuv420p).
    """

    def __init__(self, path: Path | str, fps: float = FPS) -> None:
        self.path = Path(path)
        self.partial = self.path.with_name(self.path.stem + ".partial.mp4")
        self.fps = fps
        self.frames = 0
        self._size: tuple[int, int] | None = None
        self._writer = None

    def write(self, frame: np.ndarray) -> None:
        height, width = frame.shape[0] & ~1, frame.shape[1] & ~1
        if self._writer is None:
            import imageio_ffmpeg

            if width < 2 or height < 2:
                raise ValueError(f"frame {frame.shape[1]}x{frame.shape[0]} is too small for a video")
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._size = (width, height)
            self._writer = imageio_ffmpeg.write_frames(
                str(self.partial), self._size, fps=self.fps, codec="libx264", pix_fmt_out="yuv420p", quality=None,
                macro_block_size=1, ffmpeg_log_level="error", output_params=ENCODER_PARAMS)
            self._writer.send(None)  # starts ffmpeg
        if (width, height) != self._size:
            raise ValueError(f"frame size {width}x{height} differs from the video's {self._size[0]}x{self._size[1]}")
        self._writer.send(np.ascontiguousarray(frame[:height, :width, :3]))
        self.frames += 1

    @property
    def size(self) -> tuple[int, int] | None:
        """(width, height) of the video once the first frame was written."""
        return self._size

    def close(self) -> Path | None:
        """Finish the file; its path, or None when no frame was written (no file then)."""
        if self._writer is None:
            return None
        self._writer.close()
        self._writer = None
        os.replace(self.partial, self.path)
        return self.path

    def discard(self) -> None:
        if self._writer is not None:
            self._writer.close()
            self._writer = None
        self.partial.unlink(missing_ok=True)

    def __enter__(self) -> VideoWriter:
        return self

    def __exit__(self, kind, error, traceback) -> None:
        if kind is None:
            self.close()
        else:
            self.discard()


def read_video(path: Path | str) -> tuple[dict, list[np.ndarray]]:
    """Decode a video back (checks, stills): (ffmpeg's metadata: size, fps, codec, ...; RGB frames)."""
    import imageio_ffmpeg

    reader = imageio_ffmpeg.read_frames(str(path))
    meta = next(reader)
    width, height = meta["size"]
    frames = [np.frombuffer(raw, np.uint8).reshape(height, width, 3) for raw in reader]
    return meta, frames

"""Soak: the perception and control nodes, each its own process as deployed, fed 800x600 RGB + depth at 30 Hz.

    python benchmarks/soak.py                      # 10 minutes, the shipped default model, results beside this file
    python benchmarks/soak.py --minutes 1 --out-dir /tmp/soak --checkpoint runs/cpu/best.pt
    python benchmarks/soak.py --minutes 1 --out-dir /tmp/soak_bf16 --precision bf16   # one path against another

A camera process (this one) publishes rgb8 + 32FC1 frames (metric depth with a 3 % hole in every fifth
frame, as a real depth camera has), odometry at the camera rate and a navigation command every second,
all stamped with the wall clock, on a private ROS domain (LOCALHOST discovery). The nodes run with their
defaults (backend auto, precision auto unless --precision). Measured, per window of `--window-s`:
  - latency camera stamp -> DrivingAction and -> VehicleControl received here (p50/p95/max),
  - frames published, answered (a VehicleControl with the frame's stamp), processed and skipped
    (the perception node's diagnostics: skipped = a newer frame arrived during inference),
  - resident memory (VmRSS) of the perception and control processes.
Written: <out>.json (everything), <out>.md (tables), <out>.png (latency and RSS over time). RSS growth
is taken from the end of the first window (warm-up: model load, first inferences) to the end.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

REPOSITORY = Path(__file__).resolve().parents[1]
DEFAULT_CHECKPOINT = REPOSITORY / "models" / "msfsu_default.pt"
DEFAULT_OUT = Path(__file__).resolve().parent / "soak_results"
CAMERA = (800, 600)
STARTUP_TIMEOUT_S = 180.0


@dataclass
class Window:
    """One window of the soak."""

    end_s: float  # since the first frame
    published: int
    answered: int  # frames of this window with a VehicleControl
    action_latency_ms: dict[str, float]  # p50, p95, max (empty without samples)
    control_latency_ms: dict[str, float]
    processed: int  # perception diagnostics, cumulative at the window's end
    skipped: int
    dropped: int
    rss_mb: dict[str, float]  # process -> VmRSS at the window's end


@dataclass
class SoakResult:
    started_utc: str
    minutes: float
    camera: str
    rate_hz: float
    checkpoint: str
    inference: str  # backend/precision the perception node chose
    machine: str
    load_average_end: str
    windows: list[Window] = field(default_factory=list)
    totals: dict[str, object] = field(default_factory=dict)
    diagnostics: dict[str, dict[str, str]] = field(default_factory=dict)  # last status per name


def rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    return float("nan")


def percentiles(samples: Sequence[float]) -> dict[str, float]:
    if not samples:
        return {}
    p50, p95 = np.percentile(samples, [50, 95])
    return {"p50": float(p50), "p95": float(p95), "max": float(max(samples))}


def camera_frames(count: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """A few distinct scenes at camera size (the synthetic road of the tests), depth with holes in some."""
    from msfsu_common.semantic_classes import CLASS_COLOURS
    from msfsu_perception.synthetic import render_scene

    width, height = CAMERA
    rng = np.random.default_rng(0)
    frames = []
    for index in range(count):
        class_ids, depth = render_scene(np.sin(index / count * 2 * np.pi) * 0.5, index % 7 == 6, height, width)
        rgb = np.clip(CLASS_COLOURS[class_ids].astype(np.int16) + rng.integers(-12, 13, class_ids.shape + (3,)), 0, 255)
        depth = np.minimum(depth, 80.0).astype(np.float32)
        if index % 5 == 0:
            depth[height - 60:, :240] = np.nan  # 3 % of the frame: a real depth camera's hole
        frames.append((rgb.astype(np.uint8), depth))
    return frames


def start_node(executable: str, parameters: dict[str, str], log: Path, domain: int) -> subprocess.Popen:
    from msfsu_common.processes import die_with_parent
    from msfsu_common.ros_env import configure_ros_environment

    command = [str(Path(sys.executable).parent / executable), "--ros-args"]
    for name, value in parameters.items():
        command += ["-p", f"{name}:={value}"]
    env = configure_ros_environment(dict(os.environ, ROS_DOMAIN_ID=str(domain)))
    with log.open("w") as output:
        return subprocess.Popen(command, stdout=output, stderr=subprocess.STDOUT, env=env,
                                preexec_fn=die_with_parent())


def soak(checkpoint: Path, minutes: float, rate_hz: float, window_s: float, work_dir: Path,
         precision: str = "auto") -> SoakResult:
    from domain_coordinator import domain_id

    from msfsu_common.ros_env import configure_ros_environment

    configure_ros_environment()
    with domain_id() as domain:
        return _soak_on_domain(domain, checkpoint, minutes, rate_hz, window_s, work_dir, precision)


def _soak_on_domain(domain: int, checkpoint: Path, minutes: float, rate_hz: float, window_s: float,
                    work_dir: Path, precision: str) -> SoakResult:
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from nav_msgs.msg import Odometry
    from rclpy.executors import MultiThreadedExecutor
    from rclpy.node import Node
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Image

    from msfsu_common import topics
    from msfsu_common.image_codec import encode_image
    from msfsu_common.message_types import stamp_ns
    from msfsu_interfaces.msg import DrivingAction, NavigationCommand, VehicleControl

    logs = {name: work_dir / f"{name}.log" for name in ("perception", "control")}
    processes = {
        "perception": start_node("perception", {"checkpoint": str(checkpoint), "precision": precision},
                                 logs["perception"], domain),
        "control": start_node("control", {}, logs["control"], domain),
    }
    qos = QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE)
    frames = [(Image(**encode_image(rgb, "rgb8")), Image(**encode_image(depth, "32FC1")))
              for rgb, depth in camera_frames(30)]

    class Camera(Node):
        def __init__(self) -> None:
            super().__init__("soak_camera")
            self.rgb_pub = self.create_publisher(Image, topics.RGB, qos)
            self.depth_pub = self.create_publisher(Image, topics.DEPTH, qos)
            self.odometry_pub = self.create_publisher(Odometry, topics.ODOMETRY, qos)
            self.command_pub = self.create_publisher(NavigationCommand, topics.NAVIGATION_COMMAND, 10)
            self.create_subscription(DrivingAction, topics.DRIVING_ACTION, self.on_action, 50)
            self.create_subscription(VehicleControl, topics.VEHICLE_CONTROL, self.on_control, 50)
            self.create_subscription(DiagnosticArray, topics.DIAGNOSTICS, self.on_diagnostics, 50)
            self.lock = threading.Lock()
            self.sent: list[int] = []
            self.action_ms: dict[int, float] = {}
            self.control_ms: dict[int, float] = {}
            self.diagnostics: dict[str, dict[str, str]] = {}
            self.index = 0
            self.odometry = Odometry()
            self.odometry.twist.twist.linear.x = 6.0

        def send(self) -> None:
            stamp = self.get_clock().now()
            rgb, depth = frames[self.index % len(frames)]
            self.index += 1
            for msg in (rgb, depth, self.odometry):
                msg.header.stamp = stamp.to_msg()
            self.odometry_pub.publish(self.odometry)
            self.rgb_pub.publish(rgb)
            self.depth_pub.publish(depth)
            if self.index % int(rate_hz) == 0:
                self.command_pub.publish(NavigationCommand(command=NavigationCommand.LANE_FOLLOW))
            with self.lock:
                self.sent.append(stamp.nanoseconds)

        def on_action(self, msg: DrivingAction) -> None:
            received = self.get_clock().now().nanoseconds
            with self.lock:
                self.action_ms.setdefault(stamp_ns(msg.header), (received - stamp_ns(msg.header)) * 1e-6)

        def on_control(self, msg: VehicleControl) -> None:
            received = self.get_clock().now().nanoseconds
            with self.lock:  # watchdog brakes carry other stamps: only frames sent here count
                self.control_ms.setdefault(stamp_ns(msg.header), (received - stamp_ns(msg.header)) * 1e-6)

        def on_diagnostics(self, msg: DiagnosticArray) -> None:
            with self.lock:
                for status in msg.status:
                    self.diagnostics[status.name] = {pair.key: pair.value for pair in status.values}

    rclpy.init(domain_id=domain)
    camera = Camera()
    executor = MultiThreadedExecutor(num_threads=2)
    executor.add_node(camera)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    result = SoakResult(
        started_utc=datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC"), minutes=minutes,
        camera=f"{CAMERA[0]}x{CAMERA[1]} rgb8 + 32FC1", rate_hz=rate_hz, checkpoint=str(checkpoint), inference="?",
        machine=f"{platform.processor() or platform.machine()}, {os.cpu_count()} logical CPUs", load_average_end="")
    try:
        deadline = time.monotonic() + STARTUP_TIMEOUT_S
        while "msfsu/perception" not in camera.diagnostics or camera.count_subscribers(topics.DEPTH) == 0:
            for name, process in processes.items():
                if process.poll() is not None:
                    raise RuntimeError(f"{name} exited with code {process.returncode}:\n{logs[name].read_text()[-2000:]}")
            if time.monotonic() > deadline:
                raise RuntimeError("the nodes did not come up")
            time.sleep(0.2)
        result.inference = next((line.rsplit("backend ", 1)[1].strip() for line in logs["perception"].read_text()
                                 .splitlines() if "loaded" in line and "backend " in line), "?")
        period = 1.0 / rate_hz
        started = time.monotonic()
        next_send, next_window = started, started + window_s
        end = started + minutes * 60.0
        window_start = 0
        while True:
            now = time.monotonic()
            if now >= next_window or now >= end:
                time.sleep(0.5)  # the window's last frames get their answers
                result.windows.append(window(camera, window_start, next_window - started, processes))
                window_start = len(camera.sent)
                print(f"[soak] {format_window(result.windows[-1])}", flush=True)
                next_window += window_s
                if now >= end:
                    break
                next_send = time.monotonic()
            camera.send()
            next_send += period
            time.sleep(max(0.0, next_send - time.monotonic()))
        result.diagnostics = dict(camera.diagnostics)
        result.totals = totals(camera, result.windows)
        result.load_average_end = " ".join(f"{load:.2f}" for load in os.getloadavg())
        return result
    finally:
        executor.shutdown(timeout_sec=10.0)
        spinner.join(timeout=10.0)
        camera.destroy_node()
        rclpy.shutdown()
        for process in processes.values():
            process.send_signal(signal.SIGINT)
        for process in processes.values():
            try:
                process.wait(timeout=30)
            except subprocess.TimeoutExpired:
                process.kill()


def window(camera, first: int, end_s: float, processes: dict[str, subprocess.Popen]) -> Window:
    with camera.lock:
        sent = camera.sent[first:]
        actions = [camera.action_ms[s] for s in sent if s in camera.action_ms]
        controls = [camera.control_ms[s] for s in sent if s in camera.control_ms]
        perception = dict(camera.diagnostics.get("msfsu/perception", {}))
    dropped = sum(int(value) for key, value in perception.items() if key.startswith("dropped_"))
    return Window(end_s=round(end_s, 1), published=len(sent), answered=len(controls),
                  action_latency_ms=percentiles(actions), control_latency_ms=percentiles(controls),
                  processed=int(perception.get("processed", 0)), skipped=int(perception.get("skipped_newer_frame", 0)),
                  dropped=dropped, rss_mb={name: round(rss_mb(p.pid), 1) for name, p in processes.items()})


def totals(camera, windows: list[Window]) -> dict[str, object]:
    with camera.lock:
        sent = list(camera.sent)
        actions = [camera.action_ms[s] for s in sent if s in camera.action_ms]
        controls = [camera.control_ms[s] for s in sent if s in camera.control_ms]
    first, last = windows[0], windows[-1]
    minutes_after_warmup = max((last.end_s - first.end_s) / 60.0, 1e-9)
    return {
        "published": len(sent), "answered": len(controls),
        "processed": last.processed, "skipped": last.skipped, "dropped": last.dropped,
        "action_latency_ms": percentiles(actions), "control_latency_ms": percentiles(controls),
        "rss_mb_after_warmup": first.rss_mb, "rss_mb_end": last.rss_mb,
        "rss_growth_mb": {name: round(last.rss_mb[name] - first.rss_mb[name], 1) for name in last.rss_mb},
        "rss_growth_mb_per_min": {name: round((last.rss_mb[name] - first.rss_mb[name]) / minutes_after_warmup, 2)
                                  for name in last.rss_mb},
    }


def format_window(w: Window) -> str:
    latency = w.control_latency_ms
    p = f"p50 {latency['p50']:.1f} p95 {latency['p95']:.1f} ms" if latency else "no controls"
    rss = ", ".join(f"{name} {value:.0f} MB" for name, value in w.rss_mb.items())
    return (f"{w.end_s:6.0f} s: {w.answered}/{w.published} answered, {p}; processed {w.processed}, "
            f"skipped {w.skipped}, dropped {w.dropped}; RSS {rss}")


def markdown(result: SoakResult, command: str) -> str:
    t = result.totals
    lines = [
        f"# Soak: perception + control, {result.camera} at {result.rate_hz:g} Hz for {result.minutes:g} min",
        "",
        f"`{command}` on {result.started_utc}; {result.machine}; load average at the end {result.load_average_end} "
        f"(other jobs share the machine). Checkpoint `{Path(result.checkpoint).name}`, perception on "
        f"**{result.inference}**; each node its own process, camera stamp (wall clock) -> message received here.",
        "",
        "| frames published | answered (VehicleControl) | processed | skipped (newer frame) | dropped (unpaired, bad input) |",
        "| --- | --- | --- | --- | --- |",
        f"| {t['published']} | {t['answered']} | {t['processed']} | {t['skipped']} | {t['dropped']} |",
        "",
        "| latency, ms | p50 | p95 | max |",
        "| --- | --- | --- | --- |",
    ]
    for name, key in (("camera -> DrivingAction", "action_latency_ms"), ("camera -> VehicleControl", "control_latency_ms")):
        values = t[key]
        lines.append(f"| {name} | {values.get('p50', float('nan')):.1f} | {values.get('p95', float('nan')):.1f} | "
                     f"{values.get('max', float('nan')):.1f} |")
    lines += ["", "| process | RSS after warm-up (MB) | RSS at the end (MB) | growth (MB) | growth (MB/min) |",
              "| --- | --- | --- | --- | --- |"]
    for name in t["rss_mb_end"]:
        lines.append(f"| {name} | {t['rss_mb_after_warmup'][name]:.1f} | {t['rss_mb_end'][name]:.1f} | "
                     f"{t['rss_growth_mb'][name]:+.1f} | {t['rss_growth_mb_per_min'][name]:+.2f} |")
    lines += ["", "Per window (cumulative processed/skipped/dropped from the perception node's diagnostics):", "",
              "| end, s | published | answered | control p50 ms | control p95 ms | processed | skipped | dropped | "
              "RSS perception MB | RSS control MB |",
              "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for w in result.windows:
        c = w.control_latency_ms
        lines.append(f"| {w.end_s:.0f} | {w.published} | {w.answered} | {c.get('p50', float('nan')):.1f} | "
                     f"{c.get('p95', float('nan')):.1f} | {w.processed} | {w.skipped} | {w.dropped} | "
                     f"{w.rss_mb['perception']:.1f} | {w.rss_mb['control']:.1f} |")
    perception = result.diagnostics.get("msfsu/perception", {})
    control = result.diagnostics.get("msfsu/control", {})
    lines += ["", "Last diagnostics: perception " + ", ".join(f"{k} {v}" for k, v in perception.items()),
              "", "control " + ", ".join(f"{k} {v}" for k, v in control.items()), ""]
    return "\n".join(lines)


def plot(result: SoakResult, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    minutes = [w.end_s / 60.0 for w in result.windows]
    figure, (latency_axes, rss_axes) = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    for key, style in (("p50", "-o"), ("p95", "-s")):
        latency_axes.plot(minutes, [w.control_latency_ms.get(key, np.nan) for w in result.windows], style,
                          label=f"camera -> VehicleControl {key}", markersize=3)
    latency_axes.set_ylabel("latency, ms")
    latency_axes.legend()
    latency_axes.grid(alpha=0.3)
    for name in result.windows[0].rss_mb:
        rss_axes.plot(minutes, [w.rss_mb[name] for w in result.windows], "-o", label=f"{name} RSS", markersize=3)
    rss_axes.set_ylabel("resident memory, MB")
    rss_axes.set_xlabel("minutes")
    rss_axes.legend()
    rss_axes.grid(alpha=0.3)
    figure.suptitle(f"Soak: {result.camera} at {result.rate_hz:g} Hz, perception on {result.inference}")
    figure.tight_layout()
    figure.savefig(path, dpi=100)
    plt.close(figure)


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--minutes", type=float, default=10.0, help="length of the soak")
    parser.add_argument("--rate", type=float, default=30.0, help="camera frames per second")
    parser.add_argument("--window-s", type=float, default=30.0, help="statistics window, s")
    parser.add_argument("--checkpoint", type=Path, default=DEFAULT_CHECKPOINT)
    parser.add_argument("--precision", choices=("auto", "fp32", "bf16", "int8"), default="auto",
                        help="the perception node's precision (auto: the fastest gated one this CPU runs)")
    parser.add_argument("--out-dir", type=Path, help=f"where soak_results.{{json,md,png}} go (default {DEFAULT_OUT.parent})")
    args = parser.parse_args(argv)
    if args.minutes <= 0 or args.rate <= 0 or args.window_s <= 0:
        parser.error("--minutes, --rate and --window-s must be positive")
    args.window_s = min(args.window_s, args.minutes * 60.0)
    return args


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(argv)
    out = (args.out_dir / DEFAULT_OUT.name) if args.out_dir else DEFAULT_OUT
    out.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="msfsu_soak_") as work_dir:
        result = soak(args.checkpoint, args.minutes, args.rate, args.window_s, Path(work_dir), args.precision)
    command = "python benchmarks/soak.py" + ("" if argv is None and len(sys.argv) == 1 else
                                             " " + " ".join(sys.argv[1:] if argv is None else argv))
    out.with_suffix(".json").write_text(json.dumps(asdict(result), indent=1))
    out.with_suffix(".md").write_text(markdown(result, command))
    plot(result, out.with_suffix(".png"))
    print(markdown(result, command))
    print(f"[soak] wrote {out}.json, .md, .png")
    return 0


if __name__ == "__main__":
    sys.exit(main())

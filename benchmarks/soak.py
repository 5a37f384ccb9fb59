"""Soak: the perception and control nodes, each its own process as deployed, fed RGB + depth by a camera process.

    python benchmarks/soak.py --size 800x600 --rate 30          # 10 minutes -> benchmarks/soak/800x600_30hz.*
    python benchmarks/soak.py --minutes 1 --size 1280x720 --rate 30 --out-dir /tmp/soak
    python benchmarks/soak.py --minutes 1 --precision bf16 --out-dir /tmp/soak_bf16   # one path against another
    python benchmarks/soak.py --minutes 3 --rate 20 --aeb --out-dir benchmarks/soak/aeb/with   # with the corridor brake
    python benchmarks/soak.py --minutes 3 --rate 20 --aeb-crossing --out-dir benchmarks/soak/aeb/crossing   # predicting crossings
    python benchmarks/soak.py --minutes 3 --rate 20 --aeb-composed --out-dir benchmarks/soak/aeb/composed  # brake and control, one process

Four processes on a private ROS domain (LOCALHOST discovery, the stack's transport profile), nothing else:
  - camera: rgb8 + 32FC1 frames (metric depth, a 3 % hole in every fifth frame, as a real depth camera has),
    odometry at the camera rate and a navigation command every second, on a steady clock; each frame stamped
    with the wall clock when its publishing starts. It records how late each send was against its schedule.
  - perception and control: the nodes with their defaults (backend and precision auto unless --precision) and
    `publish_stage_times`, so every answered frame's path through them is known (msfsu_common.stage_times);
    perception, a managed node, brought to active through its lifecycle services (msfsu_bringup.lifecycle); with
    --aeb the emergency brake (aeb node) between them, as the profiles place it, judging its corridor only
    (predict_crossing off); --aeb-crossing: predicting crossings too, the profiles' default; --aeb-composed: the
    corridor brake with the aeb and control nodes composed in one process, msfsu_control.aeb_control).
  - measurer: receives the VehicleControl (and DrivingAction) of every frame, the stage times and /diagnostics.
The camera and the measurer are single-threaded (no executor thread beside the publisher, no GIL convoy in the
measuring itself). End to end = camera stamp -> the VehicleControl in the measurer's middleware (rmw reception
time): what an actuator interface would see, before any Python of the measurer.

Per frame, the stages: camera -> DDS (message conversion), DDS transport, wait for the receiving executor, pairing,
wait for inference, preprocessing, network, and the same for the action and the control (benchmarks/soak/README.md
names them). Written, for `<W>x<H>_<R>hz`: .json (per-stage percentiles, windows, causes, diagnostics), .md
(tables), .png (latency over time and the stage shares per window). Every answered frame slower than
--slow-ms gets its cause named: the stage that took longest on its critical path. The record, its page and the goals
of each camera size and rate are msfsu_evaluation.records.soak's; the run prints whether it met its goal.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from msfsu_bringup.product import load_product
from msfsu_common.benchmark_run import BenchmarkRun, load_text
from msfsu_evaluation.records.soak import SLOW_MS, SoakRecord
from msfsu_evaluation.soak_analysis import analyse, plot

REPOSITORY = Path(__file__).resolve().parents[1]
DEFAULT_CHECKPOINT = REPOSITORY / load_product().checkpoint  # the product's network (msfsu_bringup/product.yaml)
DEFAULT_OUT_DIR = Path(__file__).resolve().parent / "soak"
STARTUP_TIMEOUT_S = 180.0
SETTLE_S = 1.0  # after discovery, before the first frame
DRAIN_S = 1.0  # after the last frame, before the measurer stops (the last answers)
DISTINCT_FRAMES = 30

def parse_size(text: str) -> tuple[int, int]:
    width, separator, height = text.partition("x")
    try:
        size = int(width), int(height)
    except ValueError:
        raise argparse.ArgumentTypeError(f"size must be WIDTHxHEIGHT, got {text!r}") from None
    from msfsu_common.transport import MAX_CAMERA_HEIGHT, MAX_CAMERA_WIDTH

    if not separator or not (16 <= size[0] <= MAX_CAMERA_WIDTH and 16 <= size[1] <= MAX_CAMERA_HEIGHT):
        raise argparse.ArgumentTypeError(f"size must be WIDTHxHEIGHT up to {MAX_CAMERA_WIDTH}x{MAX_CAMERA_HEIGHT}")
    return size


def result_name(size: tuple[int, int], rate_hz: float) -> str:
    return f"{size[0]}x{size[1]}_{rate_hz:g}hz"


# ----- camera process ------------------------------------------------------------------------------------------
def camera_frames(size: tuple[int, int], count: int = DISTINCT_FRAMES) -> list[tuple[np.ndarray, np.ndarray]]:
    """A few distinct scenes at camera size (the synthetic road of the tests), depth with holes in some."""
    from msfsu_common.semantic_classes import CLASS_COLOURS
    from msfsu_perception.synthetic import render_scene

    width, height = size
    rng = np.random.default_rng(0)
    frames = []
    for index in range(count):
        class_ids, depth = render_scene(np.sin(index / count * 2 * np.pi) * 0.5, index % 7 == 6, height, width)
        rgb = np.clip(CLASS_COLOURS[class_ids].astype(np.int16) + rng.integers(-12, 13, class_ids.shape + (3,)), 0, 255)
        depth = np.minimum(depth, 80.0).astype(np.float32)
        if index % 5 == 0:
            depth[height - height // 10:, : width * 3 // 10] = np.nan  # 3 % of the frame: a real depth camera's hole
        frames.append((rgb.astype(np.uint8), depth))
    return frames


def run_camera(args: argparse.Namespace) -> int:
    """Publish frames on a steady clock once the graph and the measurer are up; write camera.json."""
    import rclpy
    from nav_msgs.msg import Odometry
    from rclpy.node import Node
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Image

    from msfsu_common import topics
    from msfsu_common.image_codec import encode_image
    from msfsu_common.node_runner import init_ros
    from msfsu_common.transport import SENSOR_QUEUE_DEPTH
    from msfsu_interfaces.msg import NavigationCommand

    frames = [(Image(**encode_image(rgb, "rgb8")), Image(**encode_image(depth, "32FC1")))
              for rgb, depth in camera_frames(args.size)]
    init_ros()
    node = Node("soak_camera")
    qos = QoSProfile(depth=SENSOR_QUEUE_DEPTH, reliability=ReliabilityPolicy.RELIABLE)
    rgb_pub = node.create_publisher(Image, topics.RGB, qos)
    depth_pub = node.create_publisher(Image, topics.DEPTH, qos)
    odometry_pub = node.create_publisher(Odometry, topics.ODOMETRY, qos)
    command_pub = node.create_publisher(NavigationCommand, topics.NAVIGATION_COMMAND, 10)
    odometry = Odometry()
    odometry.twist.twist.linear.x = 6.0
    deadline = time.monotonic() + STARTUP_TIMEOUT_S
    while not (node.count_subscribers(topics.DEPTH) and node.count_publishers(topics.VEHICLE_CONTROL)
               and node.count_subscribers(topics.STAGE_TIMES)  # perception (model loaded), control, the measurer
               and (not args.aeb or node.count_subscribers(topics.NETWORK_ACTION))):  # and the emergency brake
        if time.monotonic() > deadline:
            print("[camera] the graph did not come up", file=sys.stderr, flush=True)
            return 1
        time.sleep(0.1)
    time.sleep(SETTLE_S)
    period = 1.0 / args.rate
    count = round(args.minutes * 60.0 * args.rate)
    stamps, late_ms, send_ms = np.zeros(count, np.int64), np.zeros(count), np.zeros(count)
    started = time.monotonic()
    try:
        for index in range(count):
            scheduled = started + index * period
            time.sleep(max(0.0, scheduled - time.monotonic()))
            begin = time.monotonic()
            stamp_ns = time.time_ns()
            rgb, depth = frames[index % len(frames)]
            stamp = divmod(stamp_ns, 1_000_000_000)
            for msg in (rgb, depth, odometry):
                msg.header.stamp.sec, msg.header.stamp.nanosec = stamp
            odometry_pub.publish(odometry)
            rgb_pub.publish(rgb)
            depth_pub.publish(depth)
            if index % max(1, round(args.rate)) == 0:
                command_pub.publish(NavigationCommand(command=NavigationCommand.LANE_FOLLOW))
            stamps[index], late_ms[index] = stamp_ns, (begin - scheduled) * 1e3
            send_ms[index] = (time.monotonic() - begin) * 1e3
    except KeyboardInterrupt:
        count = int(np.count_nonzero(stamps))
    Path(args.work_dir, "camera.json").write_text(json.dumps(
        {"stamps_ns": stamps[:count].tolist(), "late_ms": late_ms[:count].round(3).tolist(),
         "send_ms": send_ms[:count].round(3).tolist()}))
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


# ----- measurer process ----------------------------------------------------------------------------------------
def run_measurer(args: argparse.Namespace) -> int:
    """Record every frame's VehicleControl, DrivingAction and stage times until SIGINT/SIGTERM; write measurer.json."""
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node

    from msfsu_common import topics
    from msfsu_common.message_types import stamp_ns
    from msfsu_common.node_runner import init_ros, spin
    from msfsu_common.stage_times import received
    from msfsu_interfaces.msg import DrivingAction, StageTimes, VehicleControl

    init_ros()
    node = Node("soak_measurer")
    marks: dict[int, dict[str, int]] = {}  # frame stamp -> mark -> wall ns
    diagnostics: list[dict] = []  # (receipt time, name, values)

    def on_control(msg: VehicleControl, info) -> None:
        frame = marks.setdefault(stamp_ns(msg.header), {})  # a watchdog brake has a stamp of its own
        if "control_dds" not in frame:
            frame.update(received("control", info))
            frame["control_brake"] = int(msg.brake >= 1.0 and msg.throttle == 0.0)

    def on_action(msg: DrivingAction, info) -> None:
        marks.setdefault(stamp_ns(msg.header), {}).setdefault("action_heard", time.time_ns())

    def on_stage_times(msg: StageTimes) -> None:
        frame = marks.setdefault(stamp_ns(msg.header), {})
        for stage, t in zip(msg.stages, msg.times_ns):
            frame.setdefault(stage, int(t))

    def on_diagnostics(msg: DiagnosticArray) -> None:
        for status in msg.status:
            diagnostics.append({"t_ns": time.time_ns(), "name": status.name,
                                "values": {pair.key: pair.value for pair in status.values}})

    node.create_subscription(VehicleControl, topics.VEHICLE_CONTROL, on_control, 100)
    node.create_subscription(DrivingAction, topics.DRIVING_ACTION, on_action, 100)
    node.create_subscription(StageTimes, topics.STAGE_TIMES, on_stage_times, 200)
    node.create_subscription(DiagnosticArray, topics.DIAGNOSTICS, on_diagnostics, 50)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    try:
        spin(executor)
    except KeyboardInterrupt:
        pass
    Path(args.work_dir, "measurer.json").write_text(json.dumps(
        {"marks": {str(k): v for k, v in marks.items()}, "diagnostics": diagnostics}))
    executor.shutdown(timeout_sec=5.0)
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


# ----- orchestration -------------------------------------------------------------------------------------------
def private_rss_mb(pid: int) -> float:
    """RssAnon: the process's own resident memory (VmRSS also counts the Fast DDS segments of every participant it
    talks to, 84 MB each, shared and fixed in size)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("RssAnon:"):
            return int(line.split()[1]) / 1024.0
    return float("nan")


def start(command: list[str], log: Path, env: dict[str, str]) -> subprocess.Popen:
    from msfsu_common.processes import die_with_parent

    with log.open("w") as output:
        return subprocess.Popen(command, stdout=output, stderr=subprocess.STDOUT, env=env, preexec_fn=die_with_parent())


# the perception node's line once configured: "... segmentation=True, cpu openvino/int8, warm-up inference 17 ms"
CONFIGURED = re.compile(r"configured: loaded .*, (\S+ \S+/\S+), warm-up inference")


def inference_of(perception_log: str) -> str:
    """Device, backend and precision the perception node configured (its log's line), "?" if it never did."""
    found = CONFIGURED.search(perception_log)
    return found.group(1) if found else "?"


def aeb_parameters(args: argparse.Namespace) -> list[str]:
    """The aeb node's `-p` arguments: the soak camera's size, predicting crossings with --aeb-crossing only (said
    either way: the node's default predicts them, the soaks of --aeb judge the corridor alone; named for the aeb node:
    in the composed process the control node takes its own)."""
    width, height = args.size
    return ["-p", f"aeb:camera_width_px:={width}", "-p", f"aeb:camera_height_px:={height}",
            "-p", f"aeb:predict_crossing:={str(args.aeb_crossing).lower()}"]


def soak(args: argparse.Namespace, work_dir: Path, run: BenchmarkRun) -> tuple[SoakRecord, np.ndarray, np.ndarray]:
    from domain_coordinator import domain_id

    from msfsu_common.ros_env import configure_ros_environment

    configure_ros_environment()
    width, height = args.size
    result = SoakRecord(
        started_utc=run.date_start, minutes=args.minutes,
        size=f"{width}x{height}", camera=f"{width}x{height} rgb8 + 32FC1", rate_hz=args.rate,
        checkpoint=str(args.checkpoint), inference="?",
        machine=run.machine,
        load_average_start=load_text(), load_average_end="", command=run.command.strip(), slow_ms=args.slow_ms)
    bin_dir = Path(sys.executable).parent
    this = [sys.executable, str(Path(__file__).resolve())]
    role_args = ["--work-dir", str(work_dir), "--minutes", str(args.minutes), "--rate", str(args.rate),
                 "--size", f"{width}x{height}", *(["--aeb"] if args.aeb else [])]
    with domain_id() as domain:
        env = dict(os.environ, ROS_DOMAIN_ID=str(domain))
        from msfsu_bringup.lifecycle import LifecycleManager
        from msfsu_common import topics

        remap = ["-r", f"{topics.DRIVING_ACTION}:={topics.NETWORK_ACTION}"] if args.aeb else []
        processes = {
            "perception": start([str(bin_dir / "perception"), "--ros-args", "-p", f"checkpoint:={args.checkpoint}",
                                 "-p", f"precision:={args.precision}", "-p", "publish_stage_times:=true", *remap],
                                work_dir / "perception.log", env),
            "control": start([str(bin_dir / ("aeb_control" if args.aeb_composed else "control")), "--ros-args",
                              "-p", "publish_stage_times:=true", *(aeb_parameters(args) if args.aeb_composed else [])],
                             work_dir / "control.log", env),
            "measurer": start(this + ["--role", "measurer"] + role_args, work_dir / "measurer.log", env),
            "camera": start(this + ["--role", "camera"] + role_args, work_dir / "camera.log", env),
        }
        if args.aeb and not args.aeb_composed:
            processes["aeb"] = start([str(bin_dir / "aeb"), "--ros-args", "-p", "publish_stage_times:=true",
                                      *aeb_parameters(args)], work_dir / "aeb.log", env)
        os.environ["ROS_DOMAIN_ID"] = str(domain)  # the lifecycle manager's participant joins the soak's domain
        lifecycle = LifecycleManager(["perception"], "active")
        rss: list[dict] = []
        try:
            camera_started = None
            next_sample = time.monotonic() + args.window_s
            while processes["camera"].poll() is None:
                for name, process in processes.items():
                    if process.poll() is not None and name != "camera":
                        log = (work_dir / f"{name}.log").read_text()[-2000:]
                        raise RuntimeError(f"{name} exited with code {process.returncode}:\n{log}")
                if not lifecycle.done:
                    for line in lifecycle.poll(0.0):
                        print(f"[soak] {line}", flush=True)
                    if lifecycle.done:
                        lifecycle.close()
                if camera_started is None and "loaded" in (work_dir / "perception.log").read_text():
                    camera_started = time.monotonic()
                    next_sample = camera_started + args.window_s
                if camera_started is not None and time.monotonic() >= next_sample:
                    rss.append({"t_s": round(time.monotonic() - camera_started, 1),
                                **{name: round(private_rss_mb(processes[name].pid), 1) for name in ("perception", "control")}})
                    print(f"[soak] {rss[-1]['t_s']:.0f} s, load {load_text()}, RSS perception "
                          f"{rss[-1]['perception']} MB, control {rss[-1]['control']} MB (private)", flush=True)
                    next_sample += args.window_s
                time.sleep(0.5)
            if processes["camera"].returncode != 0:
                raise RuntimeError(f"camera exited with code {processes['camera'].returncode}:\n"
                                   f"{(work_dir / 'camera.log').read_text()[-2000:]}")
            rss.append({"t_s": round(time.monotonic() - (camera_started or time.monotonic()), 1),
                        **{name: round(private_rss_mb(processes[name].pid), 1) for name in ("perception", "control")}})
            time.sleep(DRAIN_S)
            result.load_average_end = load_text()
        finally:
            lifecycle.close()
            for process in processes.values():
                if process.poll() is None:
                    process.send_signal(signal.SIGINT)
            for process in processes.values():
                try:
                    process.wait(timeout=30)
                except subprocess.TimeoutExpired:
                    process.kill()
    result.inference = inference_of((work_dir / "perception.log").read_text())
    frames_s, end_to_end_ms = analyse(result, json.loads((work_dir / "camera.json").read_text()),
                                      json.loads((work_dir / "measurer.json").read_text()), args.window_s, rss)
    return result, frames_s, end_to_end_ms


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--minutes", type=float, default=10.0, help="length of the soak")
    parser.add_argument("--rate", type=float, default=30.0, help="camera frames per second")
    parser.add_argument("--size", type=parse_size, default=(800, 600), help="camera WIDTHxHEIGHT (default 800x600)")
    parser.add_argument("--window-s", type=float, default=30.0, help="statistics window, s")
    parser.add_argument("--slow-ms", type=float, default=SLOW_MS, help="frames slower than this get a named cause")
    parser.add_argument("--checkpoint", type=Path, default=DEFAULT_CHECKPOINT)
    parser.add_argument("--precision", choices=("auto", "fp32", "bf16", "int8"), default="auto",
                        help="the perception node's precision (auto: the fastest gated one this CPU runs)")
    parser.add_argument("--aeb", action="store_true",
                        help="put the emergency brake (aeb node) between perception and control, as the profiles do, "
                             "judging its corridor only (its predict_crossing parameter off)")
    parser.add_argument("--aeb-crossing", action="store_true",
                        help="--aeb with the brake predicting crossings too (predict_crossing on: the profiles' default)")
    parser.add_argument("--aeb-composed", action="store_true",
                        help="--aeb with the aeb and control nodes composed in one process (aeb_control)")
    parser.add_argument("--out-dir", type=Path, default=DEFAULT_OUT_DIR,
                        help=f"where <W>x<H>_<R>hz.{{json,md,png}} go (default {DEFAULT_OUT_DIR.relative_to(REPOSITORY)})")
    parser.add_argument("--role", choices=("camera", "measurer"), help=argparse.SUPPRESS)
    parser.add_argument("--work-dir", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.minutes <= 0 or args.rate <= 0 or args.window_s <= 0:
        parser.error("--minutes, --rate and --window-s must be positive")
    args.window_s = min(args.window_s, args.minutes * 60.0)
    args.aeb = args.aeb or args.aeb_crossing or args.aeb_composed
    return args


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(argv)
    if args.role is not None:
        from msfsu_common.ros_env import configure_ros_environment

        configure_ros_environment()
        return run_camera(args) if args.role == "camera" else run_measurer(args)
    run = BenchmarkRun.start("python benchmarks/soak.py", argv)
    args.out_dir.mkdir(parents=True, exist_ok=True)
    out = args.out_dir / result_name(args.size, args.rate)
    with tempfile.TemporaryDirectory(prefix="msfsu_soak_") as work_dir:
        try:
            result, frames_s, end_to_end_ms = soak(args, Path(work_dir), run)
        except RuntimeError as error:
            print(f"[soak] failed: {error}", file=sys.stderr)
            return 1
    plot(result, frames_s, end_to_end_ms, out.with_suffix(".png"))
    out.with_suffix(".json").write_text(result.to_json())
    out.with_suffix(".md").write_text(result.page())
    print(result.page())
    print(f"[soak] goal: {result.goal_text()}")
    print(f"[soak] wrote {out}.json, .md, .png (load average {load_text()})")
    return 0


if __name__ == "__main__":
    sys.exit(main())

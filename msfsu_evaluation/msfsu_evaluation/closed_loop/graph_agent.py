"""The network as a benchmark driver: the real node graph, in lockstep with the benchmark's simulator.

route, perception and control run as their own processes (bringup profile `agent`) in the ROS domain
of the calling worker process; this process publishes each frame through msfsu_sim.lockstep (the
sim_bridge node's code) from an in-process node and waits for the VehicleControl stamped with it. The
nodes stay up across episodes, and each episode starts them fresh: every node's `~/reset` (msfsu_common.reset) is
called before its first frame, so no state of the episode before (the PID, the brake's tracks, the route's
progress) carries over; then the episode publishes a new latched route and /clock runs on.
The simulator's own command goes to topics.SIM_NAVIGATION_COMMAND, as in the `sim` profile: the
graph's command comes from the route node. The graph's DrivingAction and segmentation of each frame
are heard too, for the episode's video (`decision`).

With a real-time factor the simulator runs free instead (msfsu_sim.pacing, CARLA's asynchronous mode): each
step is taken when it is due on the wall clock, with the control that arrived last, and the episode records
the factor achieved and the age of every control applied.
"""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from msfsu_common import topics
from msfsu_common.image_codec import decode_mono8
from msfsu_common.processes import die_with_parent
from msfsu_evaluation.closed_loop.telemetry import DriverStep
from msfsu_evaluation.video import DriveState
from msfsu_perception.checkpoint import CheckpointError, read_configs
from msfsu_common.camera_geometry import CameraView
from msfsu_sim.environment import STEP_S, Observation, SimEnvironment
from msfsu_sim.pacing import RealTimePacer
from msfsu_sim.timing import StageClock

STARTUP_TIMEOUT_S = 180.0  # importing torch and loading the checkpoint on a busy 2-core machine
MATCH_DELAY_S = 1.0  # endpoints discovered: let the publishers match before the first frame
STOP_TIMEOUT_S = 30.0
RESET_TIMEOUT_S = 10.0  # every node answers its reset within this (wall) time
OUTPUTS_TIMEOUT_S = 0.5  # the graph's outputs of a frame arrive right after its control; wait at most this
LOG_TAIL_LINES = 20
MAX_SILENT_FRAMES = 12  # frames in a row without an answer (a minute at the default timeout): the graph is stuck


class GraphError(RuntimeError):
    """The node graph did not start or died; the message ends with its log."""


class GraphStalled(GraphError):
    """The graph runs but answered none of MAX_SILENT_FRAMES frames in a row (seen twice: both workers' graphs went
    silent at once, their nodes idle, after hundreds of episodes); a fresh graph drives the episode again."""


def log_tail(log: Path) -> str:
    lines = log.read_text(errors="replace").splitlines()[-LOG_TAIL_LINES:] if log.exists() else []
    return f"last lines of {log}:\n" + "\n".join(lines)


def graph_processes(launcher: int) -> dict[str, Any]:
    """The graph's processes by name (psutil.Process): the launcher and each node it started (its `__node:=` name)."""
    import psutil

    root = psutil.Process(launcher)
    found = {"launcher": root}
    for child in root.children(recursive=True):
        try:
            node = next((arg.split(":=", 1)[1] for arg in child.cmdline() if arg.startswith("__node:=")), None)
        except psutil.Error:
            continue
        if node is not None:
            found[node] = child
    return found


def cpu_seconds(processes: Mapping[str, Any]) -> dict[str, float]:
    """User + system CPU seconds each process used so far (a process gone: left out)."""
    import psutil

    used = {}
    for name, process in processes.items():
        try:
            times = process.cpu_times()
        except psutil.Error:
            continue
        used[name] = times.user + times.system
    return used


class GraphAgent:
    """Driver (see episode.Driver) backed by the node graph; `close()` stops the graph."""

    needs_images = True  # the network sees the cameras

    def __init__(self, name: str, checkpoint: Path, environment: SimEnvironment, log: Path,
                 control_timeout_s: float = 5.0, real_time_factor: float | None = None,
                 stage_times: bool = False, backend: str = "auto", precision: str = "auto", aeb: bool = False,
                 aeb_crossing: bool = False, aeb_parameters: Mapping[str, Any] | None = None) -> None:
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node
        from sensor_msgs.msg import Image

        from msfsu_interfaces.msg import AebIntervention, DrivingAction
        from msfsu_sim.lockstep import LockstepLink

        self.name, self.log, self.control_timeout_s = name, log, control_timeout_s
        self.pacer = None if real_time_factor is None else RealTimePacer(real_time_factor)
        self.unanswered_frames = 0
        self.clock = StageClock()  # this episode's wall time in publishing frames and waiting for the graph
        self._cpu_started: dict[str, float] = {}
        try:
            model_config, preprocess = read_configs(checkpoint)
        except CheckpointError as error:
            raise GraphError(str(error)) from error
        self.has_segmentation, self.crop_top = model_config.has_segmentation, preprocess.crop_top_fraction
        self.preprocess = preprocess
        self.aeb = aeb
        if aeb and not (model_config.has_segmentation and preprocess.use_depth):
            raise GraphError(f"{checkpoint} has no segmentation or reads no depth: the emergency brake sees with the "
                             "network's segmentation and the depth perception samples at its pixels")
        # by frame stamp, ns; "action" is the network's own (before the emergency brake), "aeb" what the brake sent on
        self.outputs: dict[str, dict[int, object]] = {"action": {}, "segmentation": {}, "aeb": {}, "intervention": {}}
        self.outputs_received = 0
        self.context = Context()
        rclpy.init(context=self.context, domain_id=int(os.environ["ROS_DOMAIN_ID"]))
        self.node = Node("benchmark_sim", context=self.context,
                         cli_args=["--ros-args", "-r", f"{topics.NAVIGATION_COMMAND}:={topics.SIM_NAVIGATION_COMMAND}"])
        # no expert labels: nothing in the agent graph reads them, and computing them would compete with the network
        self.link = LockstepLink(self.node, environment, expert_actions=False)
        heard = [("action", DrivingAction, topics.NETWORK_ACTION if aeb else topics.DRIVING_ACTION),
                 ("segmentation", Image, topics.SEGMENTATION)]
        if aeb:
            heard += [("aeb", DrivingAction, topics.DRIVING_ACTION), ("intervention", AebIntervention,
                                                                       topics.AEB_INTERVENTION)]
        for kind, message_type, topic in heard:
            self.node.create_subscription(message_type, topic, lambda msg, kind=kind: self._on_output(kind, msg), 10)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        log.parent.mkdir(parents=True, exist_ok=True)
        with log.open("a") as output:
            self.process = subprocess.Popen(
                [sys.executable, "-m", "msfsu_bringup", "agent", "--arg", f"checkpoint={checkpoint}",
                 "--arg", f"stage_times={str(stage_times).lower()}", "--arg", f"backend={backend}",
                 "--arg", f"precision={precision}", "--arg", f"aeb={str(aeb).lower()}",
                 "--arg", f"aeb_crop_top={preprocess.crop_top_fraction}",
                 "--arg", f"aeb_parameters={json.dumps({**(aeb_parameters or {}), 'predict_crossing': aeb_crossing})}"],
                stdout=output, stderr=subprocess.STDOUT, preexec_fn=die_with_parent())  # worker dies: launcher stops
        try:
            self._wait_until_ready()
        except BaseException:
            self.close()
            raise

    def _ready(self) -> bool:
        node = self.node
        return (node.count_subscribers(topics.RGB) > 0 and node.count_subscribers(topics.ROUTE) > 0
                and node.count_subscribers(topics.ODOMETRY) > 1 and node.count_publishers(topics.VEHICLE_CONTROL) > 0
                and (not self.aeb or node.count_subscribers(topics.NETWORK_ACTION) > 0))  # the brake, when it drives

    def _wait_until_ready(self) -> None:
        deadline = time.monotonic() + STARTUP_TIMEOUT_S
        while not self._ready():
            self._check_alive()
            if time.monotonic() > deadline:
                raise GraphError(f"the agent graph was not up after {STARTUP_TIMEOUT_S:.0f} s\n{log_tail(self.log)}")
            self.executor.spin_once(timeout_sec=0.1)
        settle = time.monotonic() + MATCH_DELAY_S
        while time.monotonic() < settle:
            self.executor.spin_once(timeout_sec=0.05)
        self.processes = graph_processes(self.process.pid)
        self.resets = self._reset_clients([name for name in self.processes if name != "launcher"])

    def _reset_clients(self, nodes: list[str]) -> dict[str, Any]:
        from std_srvs.srv import Trigger

        from msfsu_common.reset import reset_service_name

        clients = {name: self.node.create_client(Trigger, reset_service_name(name)) for name in nodes}
        for name, client in clients.items():
            if not client.wait_for_service(timeout_sec=RESET_TIMEOUT_S):
                raise GraphError(f"the {name} node offers no reset service\n{log_tail(self.log)}")
        return clients

    def _reset_graph(self) -> None:
        """Every node of the graph forgets the episode before (msfsu_common.reset); GraphError if one does not answer."""
        from std_srvs.srv import Trigger

        futures = {name: client.call_async(Trigger.Request()) for name, client in self.resets.items()}
        deadline = time.monotonic() + RESET_TIMEOUT_S
        while not all(future.done() for future in futures.values()):
            self._check_alive()
            if time.monotonic() > deadline:
                late = ", ".join(name for name, future in futures.items() if not future.done())
                raise GraphError(f"no answer to the reset from {late} within {RESET_TIMEOUT_S:g} s\n{log_tail(self.log)}")
            self.executor.spin_once(timeout_sec=0.01)

    def _check_alive(self) -> None:
        if self.process.poll() is not None:
            raise GraphError(f"the agent graph exited with code {self.process.returncode}\n{log_tail(self.log)}")

    # ----- Driver -----
    def begin(self, obs: Observation, env: SimEnvironment) -> None:
        self.unanswered_frames = 0
        self.silent_frames = 0  # unanswered in a row
        self.clock.clear()
        self._cpu_started = cpu_seconds(self.processes)
        with self.clock.stage("reset graph"):
            self._reset_graph()
        with self.clock.stage("publish"):
            self.link.start_episode(obs)
        self._first_frame = True
        if self.pacer is not None:
            self.pacer.start()

    def act(self, obs: Observation, env: SimEnvironment) -> tuple[float, float, float]:
        """Publish the frame of `obs` (the first is published by `begin`) and wait for its control (lockstep) or
        for the step to be due (free-running)."""
        if not self._first_frame:
            with self.clock.stage("publish"):
                self.link.publish_frame(obs)
        self._first_frame = False
        with self.clock.stage("wait for control"):
            return self._act_when_due() if self.pacer is not None else self._wait_for_control(obs)

    def _wait_for_control(self, obs: Observation) -> tuple[float, float, float]:
        """Lockstep: spin until the graph's VehicleControl of the frame arrives (or the control timeout)."""
        while not self.link.answered:
            if self.link.waited_s() > self.control_timeout_s:
                self._check_alive()
                self.unanswered_frames += 1
                self.silent_frames += 1
                print(f"msfsu-benchmark: {self.name}: the frame at {obs.time_s:.1f} s of the simulation was not answered "
                      f"within {self.control_timeout_s:g} s; stepped with the last control (load average "
                      f"{os.getloadavg()[0]:.1f})", file=sys.stderr, flush=True)
                if self.silent_frames >= MAX_SILENT_FRAMES:
                    raise GraphStalled(f"the agent graph answered none of the last {self.silent_frames} frames "
                                       f"({self.silent_frames * self.control_timeout_s:.0f} s)")
                return self.link.control
            self.executor.spin_once(timeout_sec=0.01)
        self.silent_frames = 0
        return self.link.control

    def _act_when_due(self) -> tuple[float, float, float]:
        """Free-running: take in what arrives until the step is due, then the newest control applies."""
        late = self.pacer.late()
        while (remaining := self.pacer.due() - time.monotonic()) > 0:
            self.executor.spin_once(timeout_sec=min(remaining, 0.01))
        self._take_ready()  # a late step did not wait: what arrived meanwhile must not queue up behind it
        self.pacer.step_taken(late, self.link.control_age_s())
        if not self.link.answered:
            self.unanswered_frames += 1
        if time.monotonic() - self.link.control_received > self.control_timeout_s * MAX_SILENT_FRAMES:
            self._check_alive()
            raise GraphStalled(f"the agent graph sent no control for {self.control_timeout_s * MAX_SILENT_FRAMES:.0f} s")
        return self.link.control

    def _take_ready(self) -> None:
        """Run every callback that is ready now (spin_once runs at most one; a frame brings three messages)."""
        while True:
            taken = self.link.controls_received + self.outputs_received
            self.executor.spin_once(timeout_sec=0.0)
            if self.link.controls_received + self.outputs_received == taken:
                return

    def free_running_record(self) -> dict | None:
        """The episode's free-running figures (msfsu_sim.pacing), None in lockstep."""
        return None if self.pacer is None else self.pacer.record()

    def _on_output(self, kind: str, msg) -> None:
        self.outputs_received += 1
        outputs = self.outputs[kind]
        outputs[msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec] = msg
        while len(outputs) > 20:  # only the newest frames are asked for
            del outputs[min(outputs)]

    def decision(self, obs: Observation) -> DriveState:
        """The graph's DrivingAction and segmentation of the frame last published (waits for them briefly)."""
        stamp = round(self.link.frame_time_s * 1e9)
        wanted = ("action", "segmentation") if self.has_segmentation else ("action",)
        deadline = time.monotonic() + (0.0 if self.pacer is not None else OUTPUTS_TIMEOUT_S)  # free-running: no wait
        while any(stamp not in self.outputs[kind] for kind in wanted) and time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=0.01)
        action, segmentation = (self.outputs[kind].get(stamp) for kind in ("action", "segmentation"))
        intervention = self.outputs["intervention"].get(stamp)
        shown = ""
        if intervention is not None and intervention.decision != "none":
            shown = (f"AEB {intervention.decision.upper()}: {intervention.reason}, {intervention.gap_m:.1f} m, "
                     f"TTC {intervention.ttc_s:.1f} s, target {intervention.target_speed_out:.1f} m/s")
        return DriveState(
            obs.time_s, steer=None if action is None else float(action.steer),
            target_speed_mps=None if action is None else float(action.target_speed),
            command=None if action is None else int(action.command),
            segmentation=None if segmentation is None else np.array(decode_mono8(segmentation)),
            segmentation_top=self.crop_top, intervention=shown)

    def step_action(self, obs: Observation) -> DriverStep:
        """The DrivingAction the graph published for the frame last published (lockstep: waits for it briefly), or,
        free-running, the newest one that has arrived and how many steps older its frame is (NaN: none yet)."""
        with self.clock.stage("wait for outputs"):
            return self._step_action()

    def _step_action(self) -> DriverStep:
        stamp = round(self.link.frame_time_s * 1e9)
        actions = self.outputs["action"]
        if self.pacer is None:
            deadline = time.monotonic() + OUTPUTS_TIMEOUT_S
            while stamp not in actions and time.monotonic() < deadline:
                self.executor.spin_once(timeout_sec=0.01)
        arrived = [key for key in actions if key <= stamp]
        if not arrived:
            return DriverStep(math.nan, math.nan, None, None)
        newest = max(arrived)
        action = actions[newest]
        decision, sent_on = None, math.nan
        if self.aeb:
            if self.pacer is None:  # the brake's action comes right after the network's
                deadline = time.monotonic() + OUTPUTS_TIMEOUT_S
                while newest not in self.outputs["aeb"] and time.monotonic() < deadline:
                    self.executor.spin_once(timeout_sec=0.01)
            intervention = self.outputs["intervention"].get(newest)
            decision = "none" if intervention is None else intervention.decision
            if (forwarded := self.outputs["aeb"].get(newest)) is not None:
                sent_on = float(forwarded.target_speed)
        return DriverStep(float(action.steer), float(action.target_speed), int(action.command),
                          round((stamp - newest) / 1e9 / STEP_S), decision, sent_on)

    def timing(self) -> tuple[dict[str, float], dict[str, float]]:
        """Since begin(): wall seconds per stage of this driver (publish, wait for control, wait for outputs) and CPU
        seconds per process of the graph (its nodes by name, and the launcher)."""
        now = cpu_seconds(self.processes)
        return dict(self.clock.seconds), {name: now[name] - self._cpu_started.get(name, 0.0) for name in now}

    def camera_view(self, env: SimEnvironment) -> CameraView:
        """The camera and this network's crop and input size."""
        config = self.preprocess
        return env.camera_view(config.crop_top_fraction, config.input_width, config.input_height)

    def end(self, obs: Observation) -> None:
        self.link.end_episode(obs)

    def close(self) -> None:
        import rclpy

        if self.process.poll() is None:
            self.process.send_signal(signal.SIGINT)  # the launcher stops its nodes
            try:
                self.process.wait(STOP_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)

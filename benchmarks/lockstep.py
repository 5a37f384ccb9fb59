"""Closed loop through the node graph in lockstep: frames/s and where each frame's round trip goes.

    python benchmarks/lockstep.py                                   # default model, writes benchmarks/lockstep_results.{md,json}
    python benchmarks/lockstep.py --checkpoint runs/cpu/best.pt --route corl2017/navigation/heldout/00 --steps 300

The network drives benchmark routes (empty, regular and dense traffic by default) exactly as `msfsu-benchmark` does it: the simulator (evaluation
mode: RGB + metric depth) in this process, the bringup profile `agent` (route -> perception -> control,
one process each) on a private ROS domain, every frame answered by the VehicleControl stamped with it.
Per frame: simulator step, building and publishing the frame (sim_bridge's code), the whole round trip
(frame publishing starts -> its VehicleControl taken here) and, from the stage times perception and control
publish (`stage_times:=true`, msfsu_evaluation.latency_trace), where the round trip goes: DDS to perception,
the executor waits, preprocessing, network, DDS to control and back (here the simulator is both the camera
and the measurer of the soak's stage names). The expert drives the same route in-process for the
simulator-only rate. The 1-minute load average is printed: numbers taken under load are not comparable.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from msfsu_common import topics
from msfsu_common.message_types import stamp_ns
from msfsu_evaluation.records.lockstep import (STEP_STATISTICS, ExpertDrive, GraphDrive, LockstepResults,
                                               LockstepRoute, LockstepSetup)

if TYPE_CHECKING:
    from msfsu_evaluation.closed_loop.graph_agent import GraphAgent
    from msfsu_evaluation.closed_loop.suites import BenchmarkRoute
    from msfsu_interfaces.msg import StageTimes, VehicleControl
    from msfsu_sim.environment import SimEnvironment

DEFAULT_OUT = Path(__file__).with_name("lockstep_results.md")
DEFAULT_ROUTES = ["corl2017/navigation/heldout/00", "corl2017/navigation_dynamic/heldout/00",
                  "nocrash/nocrash_dense/train/00"]


def drive(env, route, driver, steps: int, on_frame=None) -> tuple[int, float, float]:
    """Drive `route` for up to `steps` frames; (frames, wall s without the reset, reset s)."""
    from msfsu_evaluation.closed_loop.suites import TASKS
    from msfsu_sim.environment import RouteSpec

    start = time.perf_counter()
    obs = env.reset(route.town, route.weather, TASKS[route.task].traffic, route.seed,
                    RouteSpec(route.start, route.lane, route.longitude_m, route.destination))
    reset_s = time.perf_counter() - start
    driver.begin(obs, env)
    start = time.perf_counter()
    frames = 0
    while frames < steps and not obs.done:
        control = driver.act(obs, env)
        step_started = time.perf_counter()
        obs = env.step(*control)
        if on_frame is not None:
            on_frame(time.perf_counter() - step_started)
        frames += 1
    driver.end(obs)
    return frames, time.perf_counter() - start, reset_s


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoint", type=Path, default=Path("models/msfsu_default.pt"))
    parser.add_argument("--route", nargs="+", default=DEFAULT_ROUTES, help="route keys of the benchmark's route file")
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--width", type=int, default=400)
    parser.add_argument("--height", type=int, default=300)
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help="markdown table; JSON beside it")
    return parser


def expert_rows(env: SimEnvironment, routes: list[BenchmarkRoute], steps: int) -> LockstepResults:
    """One row per route with the expert's in-process drive (the simulator-only rate)."""
    from msfsu_common.benchmark_run import load_1min, percentiles
    from msfsu_evaluation.closed_loop.episode import ExpertDriver
    from msfsu_evaluation.closed_loop.suites import TASKS

    results = LockstepResults([])
    for route in routes:
        sim_step_ms: list[float] = []
        frames, wall, reset_s = drive(env, route, ExpertDriver(), steps, lambda s: sim_step_ms.append(s * 1e3))
        results.rows.append(LockstepRoute(
            route=route.key, town=route.town, weather=route.weather, traffic=TASKS[route.task].traffic,
            expert_in_process=ExpertDrive(frames=frames, frames_per_s=round(frames / wall, 2),
                                          reset_s=round(reset_s, 2),
                                          simulator_step_ms=percentiles(sim_step_ms, STEP_STATISTICS),
                                          load_1min=load_1min())))
        print(json.dumps(results.rows[-1].to_dict()), flush=True)
    return results


class FrameTimer:
    """Times each frame of a GraphAgent: publishing it, the round trip to its VehicleControl, and the stage marks
    perception and control publish (frame stamp -> stage -> wall ns)."""

    def __init__(self, agent: GraphAgent) -> None:
        from msfsu_common.stage_times import received
        from msfsu_interfaces.msg import StageTimes, VehicleControl

        self._received = received

        self.control_received: dict[float, float] = {}  # frame time -> its control taken
        self.published: dict[float, tuple[float, float]] = {}  # frame time -> (publish started, published)
        self.marks: dict[int, dict[str, int]] = {}  # frame stamp (ns) -> stage marks (wall ns)
        agent.node.create_subscription(StageTimes, topics.STAGE_TIMES, self._on_stage_times, 100)
        agent.node.create_subscription(VehicleControl, topics.VEHICLE_CONTROL, self._on_control, 10)
        self._link = agent.link
        self._publish, self._act = agent.link.publish_frame, agent.act
        agent.link.publish_frame, agent.act = self._publish_frame, self._timed_act

    def clear(self) -> None:
        for record in (self.control_received, self.published, self.marks):
            record.clear()

    def segments_ms(self) -> dict[str, list[float]]:
        """Per answered frame: publishing it and its round trip (publishing starts -> its control taken)."""
        segments: dict[str, list[float]] = {"publish frame": [], "round trip": []}
        for stamp, (begun, done) in self.published.items():
            if stamp in self.control_received:
                segments["publish frame"].append((done - begun) * 1e3)
                segments["round trip"].append((self.control_received[stamp] - begun) * 1e3)
        return segments

    def _on_stage_times(self, msg: StageTimes) -> None:
        frame = self.marks.setdefault(stamp_ns(msg.header), {})
        for stage, t in zip(msg.stages, msg.times_ns):
            frame.setdefault(stage, int(t))

    def _on_control(self, msg: VehicleControl, info: Any) -> None:
        frame = self.marks.setdefault(stamp_ns(msg.header), {})
        if "control_dds" not in frame:
            frame.update(self._received("control", info))

    def _publish_frame(self, obs: Any) -> None:
        link = self._link
        begun, begun_ns = time.perf_counter(), time.time_ns()
        self._publish(obs)
        self.published[round(link.frame_time_s, 2)] = (begun, time.perf_counter())
        self.marks.setdefault(round(link.frame_time_s * 1e9), {})["stamp"] = begun_ns

    def _timed_act(self, obs: Any, env: Any) -> Any:
        """The agent's act, which returns as soon as the frame's VehicleControl has been taken."""
        control = self._act(obs, env)
        if self._link.answered:
            self.control_received[round(self._link.frame_time_s, 2)] = time.perf_counter()
        return control


def graph_drive(env: SimEnvironment, agent: GraphAgent, timer: FrameTimer, route: BenchmarkRoute,
                steps: int) -> GraphDrive:
    """Drive `route` through the node graph and summarise its frames and where their round trips go."""
    from msfsu_common.benchmark_run import load_1min, percentiles
    from msfsu_evaluation.latency_trace import frame_times, stage_rows

    timer.clear()
    graph_step_ms: list[float] = []
    frames, wall, reset_s = drive(env, route, agent, steps, lambda s: graph_step_ms.append(s * 1e3))
    segments = timer.segments_ms()
    time.sleep(0.2)  # the last frame's stage times
    agent.executor.spin_once(timeout_sec=0.1)
    keys = sorted(key for key, frame in timer.marks.items() if "stamp" in frame)
    times = frame_times(keys, timer.marks)
    answered = ~np.isnan(times.marks_ms.get("control_dds", np.full(len(keys), np.nan)))
    summaries = {name: percentiles(values, STEP_STATISTICS) if values else None for name, values in segments.items()}
    return GraphDrive(
        frames=frames, frames_per_s=round(frames / wall, 2), reset_s=round(reset_s, 2),
        unanswered_frames=agent.unanswered_frames, load_1min=load_1min(),
        simulator_step_ms=percentiles(graph_step_ms, STEP_STATISTICS),
        publish_frame_ms=summaries["publish frame"], round_trip_ms=summaries["round trip"],
        stages=stage_rows(times, answered))


def graph_rows(env: SimEnvironment, routes: list[BenchmarkRoute], results: LockstepResults, checkpoint: Path,
               steps: int) -> float:
    """Fill each row's graph drive (the bringup profile `agent` on a private ROS domain); returns the graph's
    start-up seconds."""
    from domain_coordinator import domain_id

    from msfsu_evaluation.closed_loop.graph_agent import GraphAgent

    with domain_id() as domain:
        os.environ["ROS_DOMAIN_ID"] = str(domain)
        started = time.perf_counter()
        agent = GraphAgent("network", checkpoint, env, Path("runs/benchmarks/lockstep_graph.log"), stage_times=True)
        graph_start_s = time.perf_counter() - started
        try:
            timer = FrameTimer(agent)
            for result, route in zip(results.rows, routes):
                result.graph = graph_drive(env, agent, timer, route, steps)
                print(json.dumps(result.graph.to_dict()), flush=True)
        finally:
            agent.close()
    return graph_start_s


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    from msfsu_common.benchmark_run import BenchmarkRun
    from msfsu_common.ros_env import configure_ros_environment
    from msfsu_evaluation.closed_loop.suites import load_routes
    from msfsu_sim.environment import SimConfig, SimEnvironment

    configure_ros_environment()
    run = BenchmarkRun.start("python benchmarks/lockstep.py")  # the page's command line: sys.argv
    known = {r.key: r for r in load_routes()[1]}
    missing = [key for key in args.route if key not in known]
    if missing:
        print(f"error: no route {', '.join(missing)} in the route file", file=sys.stderr)
        return 2
    routes = [known[key] for key in args.route]
    env = SimEnvironment(SimConfig(width=args.width, height=args.height, labels=False))
    results = expert_rows(env, routes, args.steps)
    graph_start_s = graph_rows(env, routes, results, args.checkpoint, args.steps)
    env.close()
    run.end()
    text = results.page(LockstepSetup(date_end=run.date_end, command=run.command, width=args.width,
                                      height=args.height, checkpoint=str(args.checkpoint), steps=args.steps,
                                      graph_start_s=graph_start_s))
    print(text)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(text)
    args.out.with_suffix(".json").write_text(results.to_json())
    return 0


if __name__ == "__main__":
    sys.exit(main())

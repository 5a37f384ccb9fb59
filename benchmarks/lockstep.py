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

import numpy as np

from msfsu_evaluation.records.lockstep import (STEP_STATISTICS, ExpertDrive, GraphDrive, LockstepResults,
                                               LockstepRoute, LockstepSetup)

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


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoint", type=Path, default=Path("models/msfsu_default.pt"))
    parser.add_argument("--route", nargs="+", default=DEFAULT_ROUTES, help="route keys of the benchmark's route file")
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--width", type=int, default=400)
    parser.add_argument("--height", type=int, default=300)
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help="markdown table; JSON beside it")
    args = parser.parse_args(argv)

    os.environ.setdefault("OMP_NUM_THREADS", "1")
    from domain_coordinator import domain_id

    from msfsu_common import topics
    from msfsu_common.benchmark_run import BenchmarkRun, load_1min, percentiles
    from msfsu_common.ros_env import configure_ros_environment
    from msfsu_evaluation.closed_loop.episode import ExpertDriver
    from msfsu_evaluation.closed_loop.graph_agent import GraphAgent
    from msfsu_evaluation.closed_loop.suites import TASKS, load_routes
    from msfsu_common.message_types import stamp_ns
    from msfsu_common.stage_times import received
    from msfsu_evaluation.latency_trace import frame_times, stage_rows
    from msfsu_interfaces.msg import StageTimes, VehicleControl
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
    results = LockstepResults([])
    for route in routes:
        sim_step_ms: list[float] = []
        frames, wall, reset_s = drive(env, route, ExpertDriver(), args.steps, lambda s: sim_step_ms.append(s * 1e3))
        results.rows.append(LockstepRoute(
            route=route.key, town=route.town, weather=route.weather, traffic=TASKS[route.task].traffic,
            expert_in_process=ExpertDrive(frames=frames, frames_per_s=round(frames / wall, 2),
                                          reset_s=round(reset_s, 2),
                                          simulator_step_ms=percentiles(sim_step_ms, STEP_STATISTICS),
                                          load_1min=load_1min())))
        print(json.dumps(results.rows[-1].to_dict()), flush=True)

    with domain_id() as domain:
        os.environ["ROS_DOMAIN_ID"] = str(domain)
        started = time.perf_counter()
        agent = GraphAgent("network", args.checkpoint, env, Path("runs/benchmarks/lockstep_graph.log"), stage_times=True)
        graph_start_s = time.perf_counter() - started
        try:
            control_received: dict[float, float] = {}
            published: dict[float, tuple[float, float]] = {}  # frame time -> (publish started, published)
            marks: dict[int, dict[str, int]] = {}  # frame stamp (ns) -> stage marks (wall ns)

            def on_stage_times(msg: StageTimes) -> None:
                frame = marks.setdefault(stamp_ns(msg.header), {})
                for stage, t in zip(msg.stages, msg.times_ns):
                    frame.setdefault(stage, int(t))

            def on_control(msg: VehicleControl, info) -> None:
                frame = marks.setdefault(stamp_ns(msg.header), {})
                if "control_dds" not in frame:
                    frame.update(received("control", info))

            agent.node.create_subscription(StageTimes, topics.STAGE_TIMES, on_stage_times, 100)
            agent.node.create_subscription(VehicleControl, topics.VEHICLE_CONTROL, on_control, 10)
            link = agent.link
            original_publish, original_act = link.publish_frame, agent.act

            def publish_frame(obs) -> None:
                begun, begun_ns = time.perf_counter(), time.time_ns()
                original_publish(obs)
                published[round(link.frame_time_s, 2)] = (begun, time.perf_counter())
                marks.setdefault(round(link.frame_time_s * 1e9), {})["stamp"] = begun_ns

            def act(obs, env):  # returns as soon as the frame's VehicleControl has been taken
                control = original_act(obs, env)
                if link.answered:
                    control_received[round(link.frame_time_s, 2)] = time.perf_counter()
                return control

            link.publish_frame, agent.act = publish_frame, act
            for result, route in zip(results.rows, routes):
                for record in (control_received, published, marks):
                    record.clear()
                graph_step_ms: list[float] = []
                frames, wall, reset_s = drive(env, route, agent, args.steps,
                                              lambda s: graph_step_ms.append(s * 1e3))
                segments: dict[str, list[float]] = {"publish frame": [], "round trip": []}
                for stamp, (begun, done) in published.items():
                    if stamp in control_received:
                        segments["publish frame"].append((done - begun) * 1e3)
                        segments["round trip"].append((control_received[stamp] - begun) * 1e3)
                time.sleep(0.2)  # the last frame's stage times
                agent.executor.spin_once(timeout_sec=0.1)
                keys = sorted(key for key, frame in marks.items() if "stamp" in frame)
                times = frame_times(keys, marks)
                answered = ~np.isnan(times.marks_ms.get("control_dds", np.full(len(keys), np.nan)))
                summaries = {name: percentiles(values, STEP_STATISTICS) if values else None
                             for name, values in segments.items()}
                result.graph = GraphDrive(
                    frames=frames, frames_per_s=round(frames / wall, 2), reset_s=round(reset_s, 2),
                    unanswered_frames=agent.unanswered_frames, load_1min=load_1min(),
                    simulator_step_ms=percentiles(graph_step_ms, STEP_STATISTICS),
                    publish_frame_ms=summaries["publish frame"], round_trip_ms=summaries["round trip"],
                    stages=stage_rows(times, answered))
                print(json.dumps(result.graph.to_dict()), flush=True)
        finally:
            agent.close()
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

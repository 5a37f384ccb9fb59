"""Closed loop through the node graph in lockstep: frames/s and where each frame's round trip goes.

    python benchmarks/lockstep.py                                   # default model, writes benchmarks/lockstep_results.{md,json}
    python benchmarks/lockstep.py --checkpoint runs/cpu/best.pt --route corl2017/navigation/heldout/00 --steps 300

The network drives one benchmark route exactly as `msfsu-benchmark` does it: the simulator (evaluation
mode: RGB + metric depth) in this process, the bringup profile `agent` (route -> perception -> control,
one process each) on a private ROS domain, every frame answered by the VehicleControl stamped with it.
Per frame: simulator step, building and publishing the frame (sim_bridge's code), frame published ->
DrivingAction of the network received here (DDS to perception, decode, preprocessing, inference, DDS back;
p50/p95 only: when the action and the control arrive in the same spin, their callbacks may run in either
order), and the whole round trip (frame published -> its VehicleControl taken). The expert drives the
same route in-process for the simulator-only rate. The 1-minute load average is printed: numbers taken
under load are not comparable.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

DEFAULT_OUT = Path(__file__).with_name("lockstep_results.md")
DEFAULT_ROUTE = "corl2017/navigation/heldout/00"


def _percentiles(values: list[float]) -> dict[str, float]:
    array = np.asarray(values, np.float64)
    return {"mean": round(float(array.mean()), 2), "p50": round(float(np.percentile(array, 50)), 2),
            "p95": round(float(np.percentile(array, 95)), 2)}


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
    parser.add_argument("--route", default=DEFAULT_ROUTE, help="a route key of the benchmark's route file")
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--width", type=int, default=400)
    parser.add_argument("--height", type=int, default=300)
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help="markdown table; JSON beside it")
    args = parser.parse_args(argv)

    os.environ.setdefault("OMP_NUM_THREADS", "1")
    from domain_coordinator import domain_id

    from msfsu_common import topics
    from msfsu_common.ros_env import configure_ros_environment
    from msfsu_evaluation.closed_loop.episode import ExpertDriver
    from msfsu_evaluation.closed_loop.graph_agent import GraphAgent
    from msfsu_evaluation.closed_loop.suites import load_routes
    from msfsu_interfaces.msg import DrivingAction
    from msfsu_sim.environment import SimConfig, SimEnvironment

    configure_ros_environment()
    route = next((r for r in load_routes()[1] if r.key == args.route), None)
    if route is None:
        print(f"error: no route {args.route} in the route file", file=sys.stderr)
        return 2
    env = SimEnvironment(SimConfig(width=args.width, height=args.height, labels=False))
    result: dict = {"route": route.key, "checkpoint": str(args.checkpoint), "camera": f"{args.width}x{args.height}"}

    sim_step_ms: list[float] = []
    frames, wall, reset_s = drive(env, route, ExpertDriver(), args.steps, lambda s: sim_step_ms.append(s * 1e3))
    result["expert_in_process"] = {"frames": frames, "frames_per_s": round(frames / wall, 2),
                                   "reset_s": round(reset_s, 2), "load_1min": round(os.getloadavg()[0], 2)}
    print(json.dumps(result["expert_in_process"]), flush=True)

    with domain_id() as domain:
        os.environ["ROS_DOMAIN_ID"] = str(domain)
        log = Path("runs/benchmarks/lockstep_graph.log")
        started = time.perf_counter()
        agent = GraphAgent("network", args.checkpoint, env, log)
        graph_start_s = time.perf_counter() - started
        try:
            action_received: dict[float, float] = {}
            control_received: dict[float, float] = {}

            def on_action(msg: DrivingAction) -> None:
                action_received[msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9] = time.perf_counter()

            agent.node.create_subscription(DrivingAction, topics.DRIVING_ACTION, on_action, 10)
            link = agent.link
            published: dict[float, tuple[float, float]] = {}  # frame time -> (publish started, published)
            original_publish, original_act = link.publish_frame, agent.act

            def publish_frame(obs) -> None:
                begun = time.perf_counter()
                original_publish(obs)
                published[link.frame_time_s] = (begun, time.perf_counter())

            def act(obs, env):  # returns as soon as the frame's VehicleControl has been taken
                control = original_act(obs, env)
                if link.answered:
                    control_received[link.frame_time_s] = time.perf_counter()
                return control

            link.publish_frame, agent.act = publish_frame, act
            graph_step_ms: list[float] = []
            frames, wall, reset_s = drive(env, route, agent, args.steps, lambda s: graph_step_ms.append(s * 1e3))
            unanswered = agent.unanswered_frames
        finally:
            agent.close()
    segments: dict[str, list[float]] = {"publish frame": [], "frame -> DrivingAction": [], "round trip": []}
    for stamp, (begun, done) in published.items():
        if stamp not in control_received:
            continue
        segments["publish frame"].append((done - begun) * 1e3)
        segments["round trip"].append((control_received[stamp] - begun) * 1e3)
        action = next((t for s, t in action_received.items() if abs(s - stamp) < 0.05), None)
        if action is not None:
            segments["frame -> DrivingAction"].append((action - done) * 1e3)
    result["graph"] = {
        "frames": frames, "frames_per_s": round(frames / wall, 2), "reset_s": round(reset_s, 2),
        "graph_start_s": round(graph_start_s, 1), "unanswered_frames": unanswered,
        "load_1min": round(os.getloadavg()[0], 2), "simulator_step_ms": _percentiles(graph_step_ms),
        **{f"{name} ms": _percentiles(values) for name, values in segments.items() if values}}
    result["expert_in_process"]["simulator_step_ms"] = _percentiles(sim_step_ms)
    print(json.dumps(result["graph"]), flush=True)
    env.close()

    graph, expert = result["graph"], result["expert_in_process"]
    lines = [f"# Lockstep closed loop through the node graph ({datetime.now(timezone.utc):%Y-%m-%d %H:%M} UTC)", "",
             f"`{' '.join(['python', 'benchmarks/lockstep.py', *sys.argv[1:]])}`: route {route.key} "
             f"({route.town}, {route.weather}), {args.width}x{args.height} cameras, checkpoint "
             f"`{args.checkpoint}`, up to {args.steps} frames.", "",
             "| driver | frames | frames/s | reset s | load (1 min) |", "| --- | --- | --- | --- | --- |",
             f"| expert in-process (simulator only) | {expert['frames']} | {expert['frames_per_s']} | "
             f"{expert['reset_s']} | {expert['load_1min']} |",
             f"| network through the graph | {graph['frames']} | {graph['frames_per_s']} | {graph['reset_s']} | "
             f"{graph['load_1min']} |", "",
             f"Graph start (launch, torch import, model load): {graph['graph_start_s']} s; frames stepped without "
             f"their control: {graph['unanswered_frames']}.", "",
             "| per frame, ms | mean | p50 | p95 |", "| --- | --- | --- | --- |"]
    for name in ("simulator_step_ms", "publish frame ms", "frame -> DrivingAction ms", "round trip ms"):
        if name in graph:
            stats = graph[name]
            mean = "-" if name.startswith("frame ->") else stats["mean"]
            lines.append(f"| {name.removesuffix(' ms').replace('_ms', '').replace('_', ' ')} | {mean} | "
                         f"{stats['p50']} | {stats['p95']} |")
    text = "\n".join(lines) + "\n"
    print(text)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(text)
    args.out.with_suffix(".json").write_text(json.dumps(result, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())

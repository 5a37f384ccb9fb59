"""What the speed label tells the network: the expert's target speed against its own speed, on a free road.

    python benchmarks/expert_label.py [--routes 6] [--out benchmarks/expert_label_results.md]

MSFSU sees one image and no ego speed (paper II-D), so a label that depends on the car's own speed cannot
be learned: the same free road would have to mean 1.5 m/s at rest and 8 m/s cruising. The expert drives
(blind: it needs no images) the first routes of the NoCrash regular suite in training conditions; at every
frame both labels are computed on the same scene:
- v1: current speed + IDM acceleration x 1 s, clipped to [0, desired] (the label before routes v2);
- v2: `msfsu_sim.expert.scene_speed`, the speed the scene allows (what the expert asks its PID for now).
Frames on a free road (nothing in the corridor ahead, no junction wait) are binned by the car's speed:
a learnable label is flat across the bins. Writes a markdown table and a JSON record next to it.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

DEFAULT_OUT = Path(__file__).with_name("expert_label_results.md")
SPEED_BINS = (0.0, 1.0, 2.0, 4.0, 6.0, 7.5, 9.0)
# The v1 label's IDM parameters (msfsu_sim.expert before routes v2)
IDM_MAX_ACCEL, IDM_COMFORT_DECEL, IDM_MIN_GAP, IDM_HEADWAY = 1.5, 2.5, 3.0, 1.2


def v1_label(speed: float, desired: float, gap: float | None, lead_speed: float) -> float:
    """The previous label: current speed + IDM acceleration x 1 s."""
    free = 1.0 - (speed / max(desired, 0.1)) ** 4
    if gap is None:
        acceleration = IDM_MAX_ACCEL * free
    else:
        closing = speed - lead_speed
        wanted = IDM_MIN_GAP + speed * IDM_HEADWAY + speed * closing / (2 * math.sqrt(IDM_MAX_ACCEL * IDM_COMFORT_DECEL))
        acceleration = IDM_MAX_ACCEL * (free - (max(wanted, 0.0) / max(gap, 0.1)) ** 2)
    label = float(np.clip(speed + acceleration, 0.0, desired))
    return 0.0 if gap is not None and gap < IDM_MIN_GAP else label


def collect(routes: int) -> list[dict]:
    from msfsu_evaluation.closed_loop.suites import SPAWN_CLEARANCE, TASKS, choose, load_routes
    from msfsu_sim.environment import RouteSpec, SimConfig, SimEnvironment
    from msfsu_sim.expert import Expert, scene_speed

    _, all_routes = load_routes()
    chosen = choose(all_routes, ["nocrash"], ["train"], ["nocrash_regular"], routes)
    environment = SimEnvironment(SimConfig(labels=False))
    expert = Expert()
    config = expert.config
    frames = []
    try:
        for route in chosen:
            obs = environment.reset(route.town, route.weather, TASKS[route.task].traffic, route.seed,
                                    RouteSpec(route.start, route.lane, route.longitude_m, route.destination),
                                    SPAWN_CLEARANCE, render=False)
            expert.reset()
            while not obs.done and obs.time_s < 120.0:
                gap, lead, _ = expert.limit_ahead(obs.odometry, environment.tracker, environment.obstacles())
                desired = expert.desired_speed(obs.command)
                speed = obs.odometry.speed
                frames.append({"speed": speed, "desired": desired, "free": gap is None,
                               "v1": v1_label(speed, desired, gap, lead),
                               "v2": scene_speed(desired, gap, lead, config)})
                action, longitudinal = expert.drive(obs, environment)
                obs = environment.step(action.steer, longitudinal.throttle, longitudinal.brake)
    finally:
        environment.close()
    return frames


def summarise(frames: list[dict]) -> dict:
    from msfsu_sim.expert import ExpertConfig

    cruise = ExpertConfig().cruise_speed
    free = [f for f in frames if f["free"] and f["desired"] == cruise]  # free road, lane following
    rows = []
    for low, high in zip(SPEED_BINS[:-1], SPEED_BINS[1:]):
        members = [f for f in free if low <= f["speed"] < high]
        if members:
            rows.append({"speed_bin": [low, high], "frames": len(members),
                         **{label: {"mean": float(np.mean([f[label] for f in members])),
                                    "std": float(np.std([f[label] for f in members]))} for label in ("v1", "v2")}})
    speeds = np.array([f["speed"] for f in free])
    correlation = {label: float(np.corrcoef(speeds, [f[label] for f in free])[0, 1])
                   if np.std([f[label] for f in free]) > 0 else 0.0 for label in ("v1", "v2")}
    stopping = {label: sum(f[label] < 1.0 for f in frames) for label in ("v1", "v2")}
    return {"frames": len(frames), "free_road_frames": len(free), "bins": rows,
            "correlation_with_speed_on_free_road": correlation, "frames_below_1_mps": stopping}


def markdown(summary: dict, command: str) -> str:
    lines = ["# The speed label against the car's own speed (free road, lane following, desired 8 m/s)", "",
             f"Made by `{command}`: {summary['frames']} expert frames, {summary['free_road_frames']} of them on a "
             "free road.", "", "| own speed (m/s) | frames | v1 label mean ± std | v2 label mean ± std |",
             "| --- | --- | --- | --- |"]
    for row in summary["bins"]:
        low, high = row["speed_bin"]
        lines.append(f"| {low:.1f}-{high:.1f} | {row['frames']} | {row['v1']['mean']:.2f} ± {row['v1']['std']:.2f} | "
                     f"{row['v2']['mean']:.2f} ± {row['v2']['std']:.2f} |")
    correlation = summary["correlation_with_speed_on_free_road"]
    below = summary["frames_below_1_mps"]
    lines += ["", f"Correlation of the label with the car's own speed on a free road: v1 {correlation['v1']:.3f}, "
              f"v2 {correlation['v2']:.3f}. Frames labelled below 1 m/s (all frames): v1 {below['v1']}, v2 {below['v2']}.",
              ""]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--routes", type=int, default=6, help="first N NoCrash regular routes, training conditions")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT)
    options = parser.parse_args(argv)
    from msfsu_common.ros_env import configure_ros_environment

    configure_ros_environment()
    summary = summarise(collect(options.routes))
    command = " ".join(["python", "benchmarks/expert_label.py", *(argv if argv is not None else sys.argv[1:])])
    options.out.write_text(markdown(summary, command))
    options.out.with_suffix(".json").write_text(json.dumps({"command": command, **summary}, indent=2) + "\n")
    print(options.out.read_text())
    return 0


if __name__ == "__main__":
    sys.exit(main())

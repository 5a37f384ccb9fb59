"""Which command each frame was inferred with: one benchmark route driven by a network through the node graph, traced.

    .venv/bin/python scripts/lockstep_trace.py ROUTE_KEY [ROUTE_KEY ...] --checkpoint models/msfsu_default.pt --out trace.csv
    .venv/bin/python scripts/lockstep_trace.py corl2017/one_turn/train/10 corl2017/one_turn/train/13 \
        --checkpoint models/su.pt --out su.csv

Drives the routes one after the other in one graph, as a benchmark worker does (the agent profile in lockstep with
the simulator; the nodes stay up across episodes, so an episode can inherit state from the one before) and writes,
per simulator frame: simulated time, route progress, speed, the command the simulator's own route tracker gives that
frame (`frame_command`: what the route node must answer for this frame's odometry) and the command the perception node
inferred the frame with (`used_command`, from the frame's DrivingAction), with the action's steer and target speed.
Prints the episode's outcome and every run of frames inferred with another frame's command. It uses only what every
node graph revision has (GraphAgent, run_episode), so the same script traces an older revision's code put first on
PYTHONPATH (a worktree of that commit).

    .venv/bin/python scripts/lockstep_trace.py --summarise graph1.csv graph2.csv --out traces.md

writes the page of committed traces: per trace and route, the frames, how many were inferred with another frame's
command, and each such run with where it fell (the episode's first frame, a command change, or elsewhere).
"""

from __future__ import annotations

import argparse
import csv
import os
import sys
from pathlib import Path

FIELDS = ("route", "step", "time_s", "progress_m", "speed_mps", "frame_command", "used_command", "steer", "target_speed_mps")


class Tracer:
    """A Driver wrapping the graph agent: records each frame's command beside the one its action was inferred with."""

    def __init__(self, agent) -> None:
        self.agent, self.rows, self.route = agent, [], ""
        self.name, self.needs_images = agent.name, agent.needs_images

    def __getattr__(self, name: str):
        return getattr(self.agent, name)

    def act(self, obs, env):
        from msfsu_common.road_option import RoadOption

        control = self.agent.act(obs, env)
        decision = self.agent.decision(obs)
        used = "" if decision.command is None else RoadOption(decision.command).name
        self.rows.append({"route": self.route, "step": obs.step, "time_s": round(obs.time_s, 2), "progress_m": round(obs.route_progress_m, 2),
                          "speed_mps": round(obs.odometry.speed, 2), "frame_command": obs.command.name,
                          "used_command": used, "steer": decision.steer, "target_speed_mps": decision.target_speed_mps})
        return control


def mismatches(rows: list[dict]) -> list[tuple[int, int, str, str]]:
    """Runs of consecutive frames of one route inferred with another command than their own: (first step, last step,
    own, used)."""
    runs: list[tuple[int, int, str, str]] = []
    for row in rows:
        if row["used_command"] and row["used_command"] != row["frame_command"]:
            own, used = row["frame_command"], row["used_command"]
            if runs and runs[-1][1] == row["step"] - 1 and runs[-1][2:] == (own, used):
                runs[-1] = (runs[-1][0], row["step"], own, used)
            else:
                runs.append((row["step"], row["step"], own, used))
    return runs


def where(rows: list[dict], first: int) -> str:
    """Where a run starting at step `first` fell: the episode's first frame, a change of the frame's command, or
    elsewhere."""
    steps = [int(row["step"]) for row in rows]
    index = steps.index(first)
    if index == 0:
        return "first frame"
    return "command change" if rows[index]["frame_command"] != rows[index - 1]["frame_command"] else "elsewhere"


def summary_page(traces: list[Path]) -> str:
    """The Markdown page of trace CSVs (written by this script)."""
    lines = ["# Lockstep traces: the command each frame was inferred with", "",
             f"`python scripts/lockstep_trace.py --summarise {' '.join(str(path) for path in traces)} --out ...`", "",
             "Per route: frames, frames inferred with another frame's command than their own, and each run of such "
             "frames (steps, the frame's own command, the command used, where it fell).", ""]
    for path in traces:
        with path.open() as source:
            rows = list(csv.DictReader(source))
        lines += [f"## {path.name}", "", "| route | frames | with another frame's command | runs |", "| --- | --- | --- | --- |"]
        for route in dict.fromkeys(row["route"] for row in rows):
            mine = [{**row, "step": int(row["step"])} for row in rows if row["route"] == route]
            runs = mismatches(mine)
            text = "; ".join(f"{first}-{last}: {used} for {own} ({where(mine, first)})"
                             for first, last, own, used in runs) or "–"
            lines.append(f"| {route} | {len(mine)} | {sum(last - first + 1 for first, last, _, _ in runs)} | {text} |")
        lines.append("")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("routes", nargs="*", help="route keys of routes v3 (e.g. corl2017/one_turn/train/06), driven "
                        "in this order in one graph")
    parser.add_argument("--checkpoint", type=Path)
    parser.add_argument("--out", type=Path, required=True, help="CSV of the frames (with --summarise: the page)")
    parser.add_argument("--summarise", nargs="+", type=Path, metavar="CSV", help="write the page of these traces")
    args = parser.parse_args(argv)
    if args.summarise:
        args.out.write_text(summary_page(args.summarise))
        return 0
    if not args.routes or args.checkpoint is None:
        parser.error("give ROUTE_KEY ... and --checkpoint (or --summarise CSV ...)")
    from domain_coordinator import domain_id

    from msfsu_common.ros_env import configure_ros_environment
    from msfsu_evaluation.closed_loop.episode import run_episode
    from msfsu_evaluation.closed_loop.graph_agent import GraphAgent
    from msfsu_evaluation.closed_loop.suites import load_routes
    from msfsu_sim.environment import SimConfig, SimEnvironment

    routes = {route.key: route for route in load_routes()[1]}
    if unknown := [key for key in args.routes if key not in routes]:
        print(f"lockstep_trace: no route {', '.join(unknown)} in routes v3", file=sys.stderr)
        return 2
    configure_ros_environment()
    with domain_id() as domain:
        os.environ["ROS_DOMAIN_ID"] = str(domain)
        environment = SimEnvironment(SimConfig(labels=False))
        agent = GraphAgent("traced", args.checkpoint.resolve(), environment, args.out.with_suffix(".log"))
        tracer = Tracer(agent)
        results = []
        try:
            for key in args.routes:
                tracer.route = key
                results.append(run_episode(environment, routes[key], tracer)[0])
        finally:
            agent.close()
            environment.close()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    with args.out.open("w", newline="") as output:
        writer = csv.DictWriter(output, FIELDS)
        writer.writeheader()
        writer.writerows(tracer.rows)
    for result in results:
        rows = [row for row in tracer.rows if row["route"] == result.route]
        print(f"{result.route}: {result.status} {result.collision_type} at {result.time_s:.1f} s, route completion "
              f"{result.route_completion:.2f}, {len(rows)} frames")
        for first, last, own, used in mismatches(rows):
            print(f"  steps {first}-{last}: inferred with {used}, the frame's own command is {own}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

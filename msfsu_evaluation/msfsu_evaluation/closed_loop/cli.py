"""msfsu-benchmark: closed-loop CoRL2017/NoCrash-style benchmark of checkpoints in the embedded simulator.

    msfsu-benchmark --checkpoint models/msfsu_default.pt --suite corl2017 --out runs/bench/msfsu
    msfsu-benchmark --checkpoint msfsu=m.pt --checkpoint alone=m.pt --network-only alone --suite all --out ...
    msfsu-benchmark --checkpoint msfsu=a.pt --checkpoint msf=b.pt --checkpoint su=c.pt --suite all --out ...
    msfsu-benchmark --agent expert --suite smoke --out runs/bench/expert
    msfsu-benchmark --checkpoint models/msfsu_default.pt --suite smoke --video all --out runs/bench/videos
    msfsu-benchmark --agent expert --suite all --shard 2/8 --out runs/bench/expert-2   # 1/8 of the jobs
    msfsu-benchmark --checkpoint models/msfsu_default.pt --suite abilities --workers 2 --out runs/bench/abilities
    msfsu-benchmark-report runs/bench/expert-* --out runs/bench/expert                  # merge the shards

Every network drives as the product ships it (msfsu_bringup/product.yaml: the emergency brake and its parameters, the
backend and precision rule), through the node graph (route -> perception -> aeb -> control, one process each) in
lockstep with the simulator; --network-only NAME drives that agent's network alone (perception -> control), and
run.json records each agent's configuration. Before each episode every node of the graph is reset (a fresh start).
The expert drives every route too (reference column, and the reference trajectory of the RMSE). With --real-time-factor R the networks drive free-running instead, as in CARLA's
asynchronous mode: the simulator steps on the wall clock at R times real time with whatever control arrived
last, and every episode records the factor achieved and the age of the controls it applied (the expert, which
drives in-process, is not run: its lockstep records are the reference); --no-expert leaves it out of a lockstep
run too, when another run of the same routes holds it. Several --checkpoint options are an ablation: same routes,
side by side.
--suite abilities runs the per-ability scenarios (closed_loop/abilities.py: pedestrians crossing, stepping out,
a lead car braking, a car cutting in, crossing traffic with the right of way, a clear road) into a run directory of
its own, with its own page (success per ability and condition, paired tests). Every episode keeps its per-step
telemetry (telemetry/<agent>/<route>.npz); collisions.md shows the last seconds before each collision.
Re-running with the same --out resumes (finished episodes are skipped); --shard K/N runs a fixed 1/N
of the jobs (a cluster array job per shard, each with its own --out), and msfsu-benchmark-report merges
the shards' records into one report. Ctrl-C or SIGTERM to this process stops its workers and their
graphs (re-run to resume). Writes episodes.jsonl,
trajectories/, results.json, results.md and trajectory / yaw-rate PNGs into --out; with --video, an MP4
per episode (videos/<agent>/<route>.mp4: camera, segmentation, command, speed, steer, route inset).
Exit codes: 0 done, 1 failure (one-line reason), 2 usage error.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
from collections.abc import Mapping, Sequence
from dataclasses import replace
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, get_args

from msfsu_bringup import GRAPH_REVISION, UNRECORDED_GRAPH_REVISION
from msfsu_bringup.product import load_product
from msfsu_common.benchmark_run import load_1min
from msfsu_common.machine import describe_cpu
from msfsu_common.processes import interrupt_on_signals
from msfsu_common.ros_env import configure_ros_environment
from msfsu_evaluation.closed_loop.abilities import ABILITIES, ABILITIES_FILE, ABILITIES_VERSION, choose_abilities, \
    load_abilities
from msfsu_evaluation.closed_loop.abilities import SUITE as ABILITY_SUITE
from msfsu_evaluation.closed_loop.suites import (CONDITIONS, ROUTES_FILE, ROUTES_VERSION, SUITES, TASKS, choose,
                                                 load_routes)
from msfsu_evaluation.closed_loop.markdown import brake_parameters_text
from msfsu_evaluation.closed_loop.runner import RUN_FILE, VIDEO_CHOICES, RunInfo, Settings, Shard
from msfsu_evaluation.closed_loop.runs import relative
from msfsu_evaluation.usage import UsageError
from msfsu_perception.backends.base import Backend, Precision
from msfsu_perception.deploy_files import file_digest
from msfsu_sim import SIMULATOR_REVISION


BACKENDS, PRECISIONS = get_args(Backend), get_args(Precision)
DEFAULT_RUNTIME = {"backend": "auto", "precision": "auto"}  # what a run.json without agent_runtimes drove with


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="msfsu-benchmark", description=__doc__.split("\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    parser.add_argument("--checkpoint", action="append", default=[], metavar="[NAME=]PATH",
                        help="network to evaluate (repeat for an ablation); NAME defaults to the file's stem")
    parser.add_argument("--backend", action="append", default=[], metavar="[NAME=]BACKEND",
                        help="a network's inference backend (auto, " + ", ".join(BACKENDS) + "), the perception node's "
                        "`backend` parameter; without NAME: every network (default auto: the node's default)")
    parser.add_argument("--precision", action="append", default=[], metavar="[NAME=]PRECISION",
                        help="a network's precision (auto, " + ", ".join(PRECISIONS) + "), the perception node's "
                        "`precision` parameter; without NAME: every network (default auto: the node's default)")
    parser.add_argument("--network-only", nargs="+", default=[], metavar="NAME",
                        help="network agents that drive without the product's emergency brake (the network alone); "
                             "every other --checkpoint drives as the product does (msfsu_bringup/product.yaml)")
    parser.add_argument("--aeb-param", action="append", default=[], metavar="NAME:PARAMETER=VALUE",
                        help="one of an agent's brake parameters beyond the product's (the aeb node's, e.g. "
                             "msfsu_l:track_lost_s=0.5 or msfsu_c:predict_crossing=false; repeatable): two agents of one "
                             "network whose brakes differ in a parameter drive in one run")
    parser.add_argument("--agent", choices=["expert"], help="evaluate only the expert (no checkpoint)")
    parser.add_argument("--no-expert", action="store_true",
                        help="drive the networks only: the expert's lockstep records of the same routes come from "
                             "another run (msfsu-benchmark-report merges them; the simulator is deterministic)")
    parser.add_argument("--suite", nargs="+", choices=[*SUITES, "all", ABILITY_SUITE], default=["smoke"])
    parser.add_argument("--conditions", nargs="+", metavar="CONDITION",
                        help=f"only these conditions ({', '.join(CONDITIONS)}, or a scenario file's own; default: all)")
    parser.add_argument("--tasks", nargs="+", choices=[*TASKS, *ABILITIES],
                        help="only these tasks, or abilities of --suite abilities (default: all)")
    parser.add_argument("--towns", nargs="+", metavar="TOWN",
                        help="only the routes or scenarios in these towns (default: all)")
    parser.add_argument("--routes-per-task", type=int,
                        help="the first N routes of each task x condition (abilities: scenarios per ability x condition)")
    parser.add_argument("--workers", type=int, default=1, help="parallel simulators (~5.5 GB RAM each)")
    parser.add_argument("--shard", type=_shard, default=Shard(), metavar="K/N",
                        help="run only shard K of N (a deterministic 1/N of the jobs; default 1/1: all)")
    parser.add_argument("--control-timeout", type=float, default=5.0,
                        help="wall seconds to wait for the graph's control of a frame before stepping without it")
    parser.add_argument("--real-time-factor", type=float, metavar="R",
                        help="networks drive free-running: simulated time runs at R x wall time (default: lockstep)")
    parser.add_argument("--blocked-s", type=float, default=20.0,
                        help="end an episode without route progress for this many simulated seconds")
    parser.add_argument("--stall-timeout", type=float, default=Settings.stall_s,
                        help="wall seconds a worker may go without progress before the workers are restarted")
    parser.add_argument("--restarts", type=int, default=Settings.restarts,
                        help="restart the workers after a stall at most this many times (then exit 1; re-run resumes)")
    parser.add_argument("--video", choices=VIDEO_CHOICES, default="none",
                        help="keep an MP4 of these episodes (failures: those not successful)")
    parser.add_argument("--no-expert-labels", action="store_true",
                        help="leave the expert's action in the same state out of the networks' telemetry (saves its "
                             "few ms per step)")
    parser.add_argument("--routes", type=Path, default=ROUTES_FILE, help="route file")
    parser.add_argument("--scenarios", type=Path, default=ABILITIES_FILE,
                        help="scenario file of --suite abilities (python -m msfsu_evaluation.closed_loop.make_abilities "
                             "writes one; default: the committed suite)")
    parser.add_argument("--out", type=Path, required=True, help="run directory (re-use it to resume)")
    parser.add_argument("--report-only", action="store_true", help="rewrite the reports from episodes.jsonl")
    return parser


def _shard(text: str) -> Shard:
    try:
        return Shard.parse(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def parse_agents(options: argparse.Namespace):
    from msfsu_evaluation.closed_loop.runner import EXPERT, Agent

    if options.agent and options.checkpoint:
        raise UsageError("--agent expert and --checkpoint exclude each other")
    if not options.agent and not options.checkpoint:
        raise UsageError("give --checkpoint PATH (repeatable) or --agent expert")
    if options.agent and options.real_time_factor is not None:
        raise UsageError("--real-time-factor paces the networks' graphs; the expert drives in lockstep")
    if options.agent and options.no_expert:
        raise UsageError("--agent expert and --no-expert exclude each other")
    agents = [] if options.real_time_factor is not None or options.no_expert else [Agent(EXPERT)]
    for item in options.checkpoint:
        name, separator, path = item.partition("=")
        path = Path(path if separator else name)
        name = name if separator else path.stem
        if not path.is_file():
            raise UsageError(f"checkpoint {path} does not exist")
        if name == EXPERT or name in (agent.name for agent in agents) or not name.replace("_", "").replace("-", "").isalnum():
            raise UsageError(f"agent name '{name}' is taken or not [A-Za-z0-9_-]: use NAME=PATH")
        agents.append(Agent(name, path.resolve()))
    backends = _per_agent(options.backend, "--backend", BACKENDS, agents)
    precisions = _per_agent(options.precision, "--precision", PRECISIONS, agents)
    networks = {agent.name for agent in agents if agent.checkpoint}
    for name in options.network_only:
        if name not in networks:
            raise UsageError(f"--network-only {name}: no network agent of that name ({', '.join(sorted(networks))})")
    from msfsu_control.aeb import AebConfig

    product = load_product()
    braking = sorted(networks - set(options.network_only)) if product.aeb else []
    brake_parameters = _aeb_parameters(options.aeb_param, braking, product.aeb_parameters)
    return [replace(agent, backend=backends.get(agent.name, product.backend),
                    precision=precisions.get(agent.name, product.precision), aeb=agent.name in braking,
                    aeb_crossing=agent.name in braking and brake_parameters[agent.name].get(
                        "predict_crossing", AebConfig().predict_crossing),
                    aeb_parameters=tuple(sorted((key, value) for key, value in brake_parameters.get(agent.name, {}).items()
                                                if key != "predict_crossing")))
            if agent.checkpoint else agent for agent in agents]


def _aeb_parameters(items: Sequence[str], braking: Sequence[str],
                    product: Mapping[str, Any]) -> dict[str, dict[str, Any]]:
    """{agent: its brake's parameters}: the product's (`product`), then the `NAME:PARAMETER=VALUE` items, each value
    checked as the aeb node checks it (msfsu_control.aeb.AebConfig); UsageError for an agent without the brake, an
    unknown parameter or a bad value."""
    import yaml

    from msfsu_common.settings import with_values
    from msfsu_control.aeb import AebConfig

    chosen: dict[str, dict[str, Any]] = {name: dict(product) for name in braking}
    for item in items:
        name, colon, assignment = item.partition(":")
        parameter, equals, text = assignment.partition("=")
        if not (colon and equals and parameter):
            raise UsageError(f"--aeb-param {item}: give NAME:PARAMETER=VALUE (e.g. msfsu:track_lost_s=0.5)")
        if name not in braking:
            raise UsageError(f"--aeb-param {item}: '{name}' drives without the brake ({', '.join(braking) or 'none'} "
                             "drive with it)")
        try:
            value = yaml.safe_load(text)
            with_values(AebConfig(), {**chosen[name], parameter: value})
        except (yaml.YAMLError, ValueError) as error:
            raise UsageError(f"--aeb-param {item}: {str(error).splitlines()[0]}") from None
        chosen[name][parameter] = value
    return chosen


def _per_agent(items: Sequence[str], option: str, choices: Sequence[str], agents: Sequence) -> dict[str, str]:
    """`[NAME=]VALUE` items -> {network agent: VALUE}; a bare VALUE applies to every network, a named one overrides
    it. UsageError for an unknown value or a name that is no network agent."""
    networks = [agent.name for agent in agents if agent.checkpoint]
    chosen: dict[str, str] = {}
    for item in sorted(items, key=lambda item: "=" in item):  # bare values first: a named one wins
        name, separator, value = item.rpartition("=")
        if value not in ("auto", *choices):
            raise UsageError(f"{option} {item}: '{value}' is none of auto, {', '.join(choices)}")
        if separator and name not in networks:
            raise UsageError(f"{option} {item}: '{name}' is no network agent of this run ({', '.join(networks)})")
        chosen.update({name: value} if separator else dict.fromkeys(networks, value))
    return chosen


def agent_runtimes(agents: Sequence) -> dict[str, dict]:
    """run.json's agent_runtimes: the backend and precision each network agent asked its perception node for, and
    "aeb": true for those driving with the emergency brake ("aeb_crossing": true where it also predicts crossings,
    "aeb_parameters": the brake's parameters given with --aeb-param)."""
    return {agent.name: {"backend": agent.backend, "precision": agent.precision, **({"aeb": True} if agent.aeb else {}),
                         **({"aeb_crossing": True} if agent.aeb_crossing else {}),
                         **({"aeb_parameters": dict(agent.aeb_parameters)} if agent.aeb_parameters else {})}
            for agent in agents if agent.checkpoint}


def resolved_runtimes(agents: Sequence) -> dict[str, str]:
    """What each network's perception node runs on this machine ('cpu openvino/int8'): the node's own resolution of
    auto (msfsu_perception.inference), recorded with each leg (it depends on the CPU and the gate verdicts)."""
    from msfsu_perception.inference import resolve_backend, resolve_device, resolve_precision

    device = resolve_device("auto")
    resolved = {}
    for agent in agents:
        if agent.checkpoint:
            backend = resolve_backend(agent.backend, device)
            resolved[agent.name] = f"{device} {backend}/{resolve_precision(agent.checkpoint, backend, agent.precision, device)}"
    return resolved


def _brake(runtime: dict) -> str:
    """How an agent's runtime record says its emergency brake, for a message ("" without one)."""
    crossing = " predicting crossings" if runtime.get("aeb_crossing") else ""
    given = brake_parameters_text(runtime)
    return f", with the emergency brake{crossing}{f' ({given})' if given else ''}" if runtime.get("aeb") else ""


def _check_run_dir(out: Path, info: dict) -> None:
    """A run directory holds one route-file version, one simulator revision, one node graph revision for its networks,
    one shard, and per agent name one checkpoint (by content): resuming otherwise would mix results, or take an earlier
    model's episodes as done for a retrained one."""
    path = out / RUN_FILE
    if path.exists():
        previous = json.loads(path.read_text())
        recorded = previous.get("checkpoint_digests", {})
        for name, digest in info["checkpoint_digests"].items():
            if name in previous.get("agents", {}) and recorded.get(name) != digest:
                held = "another checkpoint" if name in recorded else "a checkpoint whose content it did not record"
                raise UsageError(f"{out} holds agent '{name}' run with {held} ({previous['agents'][name]}), not "
                                 f"{info['agents'][name]} as it is now: choose a new --out or another agent name")
        runtimes = previous.get("agent_runtimes", {})
        for name, runtime in info.get("agent_runtimes", {}).items():
            ran_on = runtimes.get(name, DEFAULT_RUNTIME)
            if name in previous.get("agents", {}) and ran_on != runtime:
                raise UsageError(f"{out} holds agent '{name}' run on backend {ran_on['backend']}, precision "
                                 f"{ran_on['precision']}{_brake(ran_on)}, not {runtime['backend']}/"
                                 f"{runtime['precision']}{_brake(runtime)}: choose a new --out or another agent name")
        held, wanted = RunInfo.of(previous), RunInfo.of(info)
        if held.routes_version != wanted.routes_version:
            raise UsageError(f"{out} holds a run on routes v{held.routes_version}, these are "
                             f"v{wanted.routes_version}: choose a new --out")
        if held.real_time_factor != wanted.real_time_factor:
            raise UsageError(f"{out} holds a run at real-time factor {held.real_time_factor} (None: "
                             f"lockstep), not {wanted.real_time_factor}: choose a new --out")
        if held.simulator_revision != wanted.simulator_revision:
            raise UsageError(f"{out} holds a run of simulator revision {held.simulator_revision}, this code is "
                             f"revision {wanted.simulator_revision}: choose a new --out, or resume with the code that "
                             "started the run")
        current = info.get("graph_revision", UNRECORDED_GRAPH_REVISION)  # this code's, whoever drives now
        if held.graph_revision is not None and held.graph_revision != current:  # the expert alone drove without it
            raise UsageError(f"{out} holds networks driven through node graph revision {held.graph_revision}, this "
                             f"code is revision {current}: choose a new --out, or resume with the code that started "
                             "the run")
        if held.shard != wanted.shard:
            raise UsageError(f"{out} holds shard {held.shard}, not {wanted.shard}: one --out per shard")
        machines, here = previous.get("machines", []), info.get("machines", [])
        if machines and here and here[0] not in machines and info["checkpoint_digests"]:
            print(f"note: {out} was run on {'; '.join(machines)}, this is {here[0]}: a network's episodes differ "
                  "between CPUs, so the finished episodes of each route with an episode to run are driven again "
                  "here beside it", file=sys.stderr)
        info = {**info, "agents": {**previous.get("agents", {}), **info["agents"]},
                "checkpoint_digests": {**recorded, **info["checkpoint_digests"]},
                "agent_runtimes": {**runtimes, **info.get("agent_runtimes", {})},
                "machines": machines + [m for m in here if m not in machines], "legs": previous.get("legs", [])}
    out.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(info, indent=2) + "\n")


def _suite_routes(options: argparse.Namespace) -> tuple[list, dict]:
    """The routes of the route suites asked for, and what run.json says of them."""
    try:
        version, all_routes = load_routes(options.routes)
    except (OSError, ValueError, KeyError, TypeError) as error:
        raise UsageError(f"cannot read the route file: {error}") from error
    if version != ROUTES_VERSION:
        raise UsageError(f"{options.routes} is routes v{version}: its results can be reported "
                         f"(msfsu-benchmark-report), but this simulator and its rules run v{ROUTES_VERSION} only")
    suites = list(SUITES[1:]) if "all" in options.suite else options.suite
    if unknown := [task for task in options.tasks or () if task not in TASKS]:
        raise UsageError(f"--tasks {' '.join(unknown)}: abilities of --suite {ABILITY_SUITE}, not route tasks")
    if unknown := sorted(set(options.conditions or ()) - set(CONDITIONS)):
        raise UsageError(f"--conditions {' '.join(unknown)}: the route suites' are {', '.join(CONDITIONS)}")
    options.conditions = options.conditions or list(CONDITIONS)
    routes = choose(all_routes, suites, options.conditions, options.tasks, options.routes_per_task, options.towns)
    if not routes:
        raise UsageError(f"no routes for suites {suites}, conditions {options.conditions}, tasks {options.tasks}"
                         + (f", towns {options.towns}" if options.towns else ""))
    return routes, {"routes_version": version, "routes_file": relative(options.routes)}


def _ability_routes(options: argparse.Namespace) -> tuple[list, dict]:
    """The scenarios of the per-ability suite asked for, and what run.json says of them."""
    if options.suite != [ABILITY_SUITE]:
        raise UsageError(f"--suite {ABILITY_SUITE} runs on its own (its run directory and page are its own)")
    if unknown := [task for task in options.tasks or () if task not in ABILITIES]:
        raise UsageError(f"--tasks {' '.join(unknown)}: route tasks, not abilities ({', '.join(ABILITIES)})")
    try:
        _, scenarios = load_abilities(options.scenarios)
    except (OSError, ValueError, KeyError, TypeError) as error:
        raise UsageError(f"cannot read the scenario file: {error}") from error
    held = list(dict.fromkeys(route.condition for route in scenarios))
    if unknown := sorted(set(options.conditions or ()) - set(held)):
        raise UsageError(f"--conditions {' '.join(unknown)}: {options.scenarios} holds {', '.join(held)}")
    options.conditions = options.conditions or held
    routes = choose_abilities(scenarios, options.conditions, options.tasks, options.routes_per_task, options.towns)
    if not routes:
        raise UsageError(f"no scenarios for conditions {options.conditions}, abilities {options.tasks}"
                         + (f", towns {options.towns}" if options.towns else ""))
    return routes, {"suite": ABILITY_SUITE, "routes_version": None, "abilities_version": ABILITIES_VERSION,
                    "routes_file": relative(options.scenarios)}


def _now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


def _record_leg(out: Path, leg: dict, episodes: Sequence) -> None:
    """Append one invocation's wall time to run.json ('legs'): when it ran, how many workers, how many of its
    episodes finished, the load average at both ends (a suite's wall time is only known here), and its throughput
    (closed_loop.throughput: per agent, steps/s per worker and where a step's time went; episodes per hour), which it
    prints."""
    from msfsu_evaluation.closed_loop.throughput import by_agent, summary_line

    ended = datetime.now(timezone.utc)
    wall_s = round((ended - datetime.fromisoformat(leg["started"])).total_seconds(), 1)
    speeds = by_agent(episodes)
    leg = {**leg, "ended": ended.isoformat(timespec="seconds"), "load_1min_end": load_1min(), "wall_s": wall_s,
           "episodes_per_hour": round(len(episodes) / wall_s * 3600, 1) if wall_s > 0 else None,
           "throughput": {agent: speed.to_dict() for agent, speed in speeds.items()}}
    print(summary_line(speeds, wall_s, leg["workers"]) + f" (load average {leg['load_1min_end']})",
          file=sys.stderr, flush=True)
    path = out / RUN_FILE
    info = json.loads(path.read_text())
    info["legs"] = [*info.get("legs", []), leg]
    path.write_text(json.dumps(info, indent=2) + "\n")


def run(options: argparse.Namespace) -> dict:
    from tqdm import tqdm

    from msfsu_evaluation.closed_loop.report import write_reports
    from msfsu_evaluation.closed_loop.runner import Job, pending, run_jobs
    from msfsu_evaluation.closed_loop.runs import ability_run_info, read_run_info, report_run_info

    if options.workers < 1 or (options.routes_per_task is not None and options.routes_per_task < 1):
        raise UsageError("--workers and --routes-per-task must be at least 1")
    if options.blocked_s <= 0 or options.control_timeout <= 0 or options.stall_timeout <= 0:
        raise UsageError("--blocked-s, --control-timeout and --stall-timeout must be positive")
    if options.real_time_factor is not None and not 0 < options.real_time_factor <= 10:
        raise UsageError("--real-time-factor must be in (0, 10]")
    if options.restarts < 0:
        raise UsageError("--restarts must be at least 0")
    agents = parse_agents(options)
    abilities = ABILITY_SUITE in options.suite
    if abilities:
        routes, info = _ability_routes(options)
    else:
        routes, info = _suite_routes(options)
    info = {**info, "shard": str(options.shard),
            "simulator_revision": SIMULATOR_REVISION, "graph_revision": GRAPH_REVISION,
            "real_time_factor": options.real_time_factor,
            "agents": {agent.name: relative(agent.checkpoint) if agent.checkpoint else None for agent in agents},
            "checkpoint_digests": {agent.name: file_digest(agent.checkpoint) for agent in agents if agent.checkpoint},
            "agent_runtimes": agent_runtimes(agents),
            "machines": [describe_cpu()]}  # every CPU this run directory was run on
    run_machines = read_run_info(options.out).get("machines", []) if (options.out / RUN_FILE).is_file() else []
    _check_run_dir(options.out, info)
    if not options.report_only:
        jobs = options.shard.select([Job(agent, route) for agent in agents for route in routes])
        unfinished = pending(options.out, jobs)
        todo = pending(options.out, jobs, info["machines"][0], run_machines)
        again = len(todo) - len(unfinished)
        shard = "" if options.shard.count == 1 else f" in shard {options.shard}"
        print(f"{len(routes)} routes x {len(agents)} agents, {len(jobs)} episodes{shard}, {len(todo)} to run "
              f"({len(jobs) - len(unfinished)} done before"
              + (f"; {again} of them driven again on this machine, beside their routes' episodes to run)" if again
                 else ")"), file=sys.stderr, flush=True)
        settings = Settings(options.control_timeout, options.blocked_s, options.video, options.stall_timeout,
                            options.restarts, options.real_time_factor, not options.no_expert_labels)
        running = {job.agent.name for job in todo}
        leg = {"started": _now(), "workers": options.workers, "load_1min_start": load_1min(),
               "agents": sorted(running), "to_run": len(todo), "finished": 0,
               "runtimes": resolved_runtimes([agent for agent in agents if agent.name in running])}
        finished = []
        try:
            with tqdm(total=len(todo), unit="episode") as progress, \
                    contextlib.closing(run_jobs(todo, options.out, options.workers, settings)) as episodes:
                for episode in episodes:
                    progress.set_postfix_str(f"{episode.agent} {episode.route}: {episode.status}")
                    progress.update()
                    finished.append(episode)
                    leg["finished"] += 1
        finally:
            if todo:
                _record_leg(options.out, leg, finished)
    # the page msfsu-benchmark-report makes of this run directory, word for word (run.json keeps the rest of info)
    if abilities:
        from msfsu_evaluation.closed_loop.ability_report import write_ability_report

        report = write_ability_report(options.out, [options.out], routes, [a.name for a in agents], options.conditions,
                                      ability_run_info([read_run_info(options.out)]))
    else:
        report = write_reports(options.out, [options.out], routes, [a.name for a in agents], options.conditions,
                               info["routes_version"], report_run_info([read_run_info(options.out)],
                                                                       info["routes_version"], info["routes_file"]))
    print((options.out / "results.md").read_text(), flush=True)
    videos = sorted((options.out / "videos").glob("*/*.mp4"))
    if videos:
        print(f"{len(videos)} episode videos in {options.out / 'videos'}", flush=True)
    return report


def main(argv: Sequence[str] | None = None) -> int:
    configure_ros_environment()  # before anything (workers, launched nodes) initialises rclpy
    interrupt_on_signals()  # SIGTERM / SIGINT end the run like Ctrl-C: workers stopped, records kept
    options = build_parser().parse_args(argv)
    from msfsu_evaluation.closed_loop.runner import BenchmarkError

    try:
        run(options)
    except UsageError as error:
        print(f"msfsu-benchmark: {error}", file=sys.stderr)
        return 2
    except (BenchmarkError, OSError, ValueError) as error:
        print(f"msfsu-benchmark: {str(error).splitlines()[0]}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("msfsu-benchmark: interrupted (re-run with the same --out to resume)", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())

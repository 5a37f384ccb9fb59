"""A run resumed on another CPU drives again, beside each route's episodes still to run, that route's episodes driven
elsewhere: a route's agents are compared on one machine (runner.pending)."""

import json
from pathlib import Path

from msfsu_evaluation.closed_loop.episode_record import EpisodeResult
from msfsu_evaluation.closed_loop.runner import EPISODES_FILE, Agent, Job, episode_machine, pending, read_episodes
from msfsu_evaluation.closed_loop.suites import load_routes

AMD, INTEL = "AMD EPYC, 2 CPUs, avx2 fma avx512f", "Intel(R) Xeon(R) Processor, 2 CPUs, avx2 fma avx512f amx_int8"


def record(agent: str, route: str, machine: str | None) -> EpisodeResult:
    return EpisodeResult(agent, route, "success", True, time_s=1.0, steps=10, route_completion=1.0, collision_type="",
                         distance_to_goal_m=1.0, timeout_s=60.0, wall_s=1.0, unanswered_frames=0, machine=machine)


def write(out: Path, records: list[EpisodeResult]) -> None:
    with (out / EPISODES_FILE).open("a") as log:
        for episode in records:
            log.write(json.dumps(episode.to_dict()) + "\n")


def jobs_of(agents: tuple[str, ...], routes: int) -> list[Job]:
    _, all_routes = load_routes()
    return [Job(Agent(name, Path(f"{name}.pt")), route) for name in agents for route in all_routes[:routes]]


def keys(jobs: list[Job]) -> set[tuple[str, str]]:
    return {(job.agent.name, job.route.key) for job in jobs}


def test_on_the_same_machine_only_the_unfinished_episodes_run(tmp_path):
    jobs = jobs_of(("msfsu", "candidate"), 3)
    routes = [job.route.key for job in jobs[:3]]
    write(tmp_path, [record("msfsu", route, AMD) for route in routes] + [record("candidate", routes[0], AMD)])
    unfinished = {("candidate", routes[1]), ("candidate", routes[2])}
    assert keys(pending(tmp_path, jobs)) == unfinished
    assert keys(pending(tmp_path, jobs, AMD, [AMD])) == unfinished


def test_on_another_machine_a_routes_finished_episodes_are_driven_again_beside_its_unfinished_ones(tmp_path):
    jobs = jobs_of(("msfsu", "candidate"), 3)
    routes = [job.route.key for job in jobs[:3]]
    # route 0: both finished on AMD (kept); route 1: only msfsu, recorded before machines were (its run's first: AMD)
    write(tmp_path, [record("msfsu", routes[0], AMD), record("candidate", routes[0], AMD),
                     record("msfsu", routes[1], None)])
    todo = pending(tmp_path, jobs, INTEL, [AMD, INTEL])
    assert keys(todo) == {("candidate", routes[1]), ("msfsu", routes[1]), ("candidate", routes[2]),
                          ("msfsu", routes[2])}
    assert [job.agent.name for job in todo] == sorted(job.agent.name for job in todo)  # one graph at a time


def test_an_episode_driven_again_here_is_the_routes_record_and_no_longer_runs(tmp_path):
    jobs = jobs_of(("msfsu", "candidate"), 1)
    route = jobs[0].route.key
    write(tmp_path, [record("msfsu", route, AMD)])
    assert keys(pending(tmp_path, jobs, INTEL, [AMD, INTEL])) == {("msfsu", route), ("candidate", route)}
    write(tmp_path, [record("msfsu", route, INTEL)])  # interrupted after the baseline was driven again
    assert keys(pending(tmp_path, jobs, INTEL, [AMD, INTEL])) == {("candidate", route)}
    write(tmp_path, [record("candidate", route, INTEL)])
    assert pending(tmp_path, jobs, INTEL, [AMD, INTEL]) == []
    assert [episode.machine for episode in read_episodes(tmp_path)] == [AMD, INTEL, INTEL]  # the first kept


def test_an_episode_without_its_machine_ran_on_its_runs_first_machine_or_an_unknown_one():
    assert episode_machine(record("msfsu", "r", None), [AMD, INTEL]) == AMD
    assert episode_machine(record("msfsu", "r", INTEL), [AMD, INTEL]) == INTEL
    assert episode_machine(record("msfsu", "r", None), []) is None

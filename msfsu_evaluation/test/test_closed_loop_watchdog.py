"""The benchmark's watchdog: a worker that hangs for good is killed and its episodes run again in a fresh one.

The hang is injected (a worker target that blocks with SIGTERM ignored, as the rclpy wait seen once did);
everything else is the real runner: spawned processes, shared heartbeats, episodes.jsonl, resume.
"""

import signal
import time
from pathlib import Path

import pytest

from msfsu_evaluation.closed_loop import runner
from msfsu_evaluation.closed_loop.episode_record import EpisodeResult
from msfsu_evaluation.closed_loop.runner import Agent, Job, Settings, WorkerStalled, read_episodes, run_jobs
from msfsu_evaluation.closed_loop.suites import load_routes

HANG_FILE = "hang"  # in the run directory: the route key to hang on, and how many attempts at it hang


def hangs_on(out: Path, route_key: str) -> bool:
    """Whether this attempt at the route hangs (out/hang names the route and counts the attempts that do)."""
    marker = out / HANG_FILE
    if not marker.exists():
        return False
    route, hangs = marker.read_text().split()
    if route != route_key or int(hangs) == 0:
        return False
    marker.write_text(f"{route} {int(hangs) - 1}")
    return True


def finished(job: Job) -> EpisodeResult:
    """The record of an episode the injected worker says it finished."""
    return EpisodeResult(job.agent.name, job.route.key, "success", True, time_s=1.0, steps=10, route_completion=1.0,
                         collision_type="", distance_to_goal_m=1.0, timeout_s=60.0, wall_s=1.0, unanswered_frames=0)


def hanging_worker(jobs, results, out: Path, settings: Settings, parent: int, heartbeat) -> None:
    """Runs every job at once, except the route named in out/hang: there it stops beating and blocks."""
    signal.signal(signal.SIGTERM, signal.SIG_IGN)  # like a process stuck in C code: only SIGKILL ends it
    while (job := jobs.get()) is not None:
        heartbeat.value = time.monotonic()
        if hangs_on(out, job.route.key):
            time.sleep(3600)
        results.put(("episode", finished(job)))


def silent_graph_worker(jobs, results, out: Path, settings: Settings, parent: int, heartbeat) -> None:
    """Keeps beating, but its graph goes silent on the route named in out/hang (reported as the real worker does)."""
    while (job := jobs.get()) is not None:
        heartbeat.value = time.monotonic()
        if hangs_on(out, job.route.key):
            results.put(("stalled", f"{job.agent.name} on {job.route.key}: the agent graph answered none of the "
                                    "last 12 frames (60 s)"))
            return
        results.put(("episode", finished(job)))


@pytest.fixture
def jobs() -> list[Job]:
    _, routes = load_routes()
    return [Job(Agent("expert"), route) for route in routes[:3]]


@pytest.fixture(autouse=True)
def short_grace(monkeypatch):
    monkeypatch.setattr(runner, "STOP_GRACE_S", 1.0)


def test_a_hung_worker_is_replaced_and_every_episode_is_recorded_once(tmp_path, jobs, capsys):
    (tmp_path / HANG_FILE).write_text(f"{jobs[1].route.key} 1")
    started = time.monotonic()
    done = list(run_jobs(jobs, tmp_path, 1, Settings(stall_s=1.0, restarts=1), target=hanging_worker))
    assert sorted(e.route for e in done) == sorted(job.route.key for job in jobs)
    assert read_episodes(tmp_path) == done  # what was yielded is what a resume reads back
    assert time.monotonic() - started < 60  # the hung process was killed, not waited for
    assert "worker 1 made no progress" in capsys.readouterr().err


def test_a_worker_that_keeps_hanging_ends_the_run_with_one_line_and_keeps_what_finished(tmp_path, jobs):
    (tmp_path / HANG_FILE).write_text(f"{jobs[1].route.key} 9")
    done = []
    with pytest.raises(WorkerStalled, match=r"made no progress .* gave up after 1 restarts, \d episodes left"):
        for episode in run_jobs(jobs, tmp_path, 1, Settings(stall_s=1.0, restarts=1), target=hanging_worker):
            done.append(episode.route)
    assert jobs[0].route.key in done and jobs[1].route.key not in done
    assert [e.route for e in read_episodes(tmp_path)] == done  # a re-run resumes from here


def test_a_silent_graph_restarts_the_workers_and_its_episode_is_driven_again(tmp_path, jobs, capsys):
    (tmp_path / HANG_FILE).write_text(f"{jobs[0].route.key} 1")
    done = list(run_jobs(jobs, tmp_path, 2, Settings(stall_s=30.0, restarts=1), target=silent_graph_worker))
    assert sorted(e.route for e in done) == sorted(job.route.key for job in jobs)
    assert sorted(e.route for e in read_episodes(tmp_path)) == sorted(job.route.key for job in jobs)
    assert "answered none of the last 12 frames" in capsys.readouterr().err


STOP_WITH_JOBS_LEFT = """
import sys
from pathlib import Path
from msfsu_evaluation.closed_loop import runner
from msfsu_evaluation.closed_loop.runner import Agent, Job, Settings, run_jobs
from msfsu_evaluation.closed_loop.suites import load_routes
sys.path.insert(0, {tests!r})
from test_closed_loop_watchdog import first_job_then_interrupt

runner.STOP_GRACE_S = 1.0
_, routes = load_routes()
jobs = [Job(Agent(f"a{{i}}"), route) for i in range(4) for route in routes]  # far more than a pipe buffer holds
try:
    for _ in run_jobs(jobs, Path({out!r}), 1, Settings(stall_s=60.0), target=first_job_then_interrupt):
        raise KeyboardInterrupt  # Ctrl-C after the first episode
except KeyboardInterrupt:
    print("interrupted", flush=True)
"""


def first_job_then_interrupt(jobs, results, out: Path, settings: Settings, parent: int, heartbeat) -> None:
    """Finishes one job, then waits to be stopped (as a worker busy with its next episode)."""
    job = jobs.get()
    results.put(("episode", finished(job)))
    time.sleep(3600)


def test_a_run_stopped_with_many_jobs_left_exits(tmp_path):
    """The jobs nobody took must not keep the stopped run alive (the queue's pipe holds them)."""
    import subprocess
    import sys

    code = STOP_WITH_JOBS_LEFT.format(tests=str(Path(__file__).parent), out=str(tmp_path))
    stopped = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert stopped.returncode == 0 and "interrupted" in stopped.stdout, stopped.stderr[-2000:]
    assert len(read_episodes(tmp_path)) == 1

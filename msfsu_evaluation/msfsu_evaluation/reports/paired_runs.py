"""One agent's episodes of a benchmark run, keyed by route, and how a command line names them (RUN:AGENT): what the
before/after pages (revision_change, graph_change) and the release rule (release) pair per route."""

from __future__ import annotations

import argparse
from pathlib import Path

from msfsu_evaluation.closed_loop.episode_record import EpisodeResult
from msfsu_evaluation.closed_loop.runner import read_episodes

Episodes = dict[str, EpisodeResult]  # route key -> the agent's episode


def episodes(run: Path, agent: str) -> Episodes:
    """The agent's episodes of a run directory by route key."""
    return {episode.route: episode for episode in read_episodes(run) if episode.agent == agent}


def suite_and_condition(key: str) -> tuple[str, str]:
    """(suite, condition) of a route key suite/task/condition/index."""
    parts = key.split("/")
    return parts[0], parts[2]


def task_of(key: str) -> str:
    """The task (a scenario suite's ability) of a route key suite/task/condition/index."""
    return key.split("/")[1]


def run_and_agent(text: str) -> tuple[Path, str]:
    """RUN_DIRECTORY:AGENT as (run directory, agent)."""
    run, separator, agent = text.rpartition(":")
    if not separator or not agent:
        raise argparse.ArgumentTypeError(f"{text!r}: give RUN_DIRECTORY:AGENT")
    return Path(run), agent

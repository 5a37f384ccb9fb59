"""Plays a bag through the real node graph with the bringup `replay` profile and records its outputs.

Every node runs in its own process exactly as deployed; this module only chooses profile
arguments, keeps the nodes' logs in a file and shows progress on the terminal. The graph runs in a
ROS domain reserved for this run (domain_coordinator), so a stack already running on this machine
neither feeds the evaluation nor hears the replayed sensors.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

from domain_coordinator import domain_id
from tqdm import tqdm

from msfsu_bringup.bag_player import STARTED_MESSAGE
from msfsu_common import topics
from msfsu_common.bag_io import open_bag
from msfsu_common.camera_geometry import FrontCamera
from msfsu_common.processes import die_with_parent
from msfsu_control.aeb_node import camera_parameters
from msfsu_evaluation.recording import RECORDED_TOPICS

# The player starts once perception subscribed the command and the recorder subscribed the outputs only it
# consumes; this delay then covers endpoint matching, so the first frame's action is recorded too.
START_DELAY_S = 1.0
# Time for perception to finish the last frame after the bag ends (a ResNet-50 at 224x224 takes ~0.1 s).
END_DELAY_S = 2.0
STARTUP_ALLOWANCE_S = 120.0  # importing torch, loading the checkpoint, discovery on a busy machine
LOG_TAIL_LINES = 30


class ReplayError(RuntimeError):
    """The graph did not run the bag to its end; the message carries the end of the nodes' log."""


@dataclass(frozen=True)
class ReplayRequest:
    bag: Path
    checkpoint: Path
    recording: Path  # bag directory the outputs are recorded into (must not exist)
    log: Path  # the nodes' stdout/stderr
    rate: float = 1.0
    remap: Mapping[str, str] | None = None  # bag topic -> graph topic
    play_topics: Sequence[str] = ()  # bag topics to play (empty: all)
    aeb: bool = True  # the emergency brake between perception and control (the replay profile's default)
    crop_top_fraction: float = 0.5  # the network's crop, which the brake must know (the checkpoint's)
    camera: FrontCamera | None = None  # the bag's camera, which the brake must know; None: the simulator's


def replay_command(request: ReplayRequest) -> list[str]:
    """`python -m msfsu_bringup replay --arg ...`; lists and mappings go as JSON, which is YAML flow text."""
    arguments = {
        "bag": str(request.bag),
        "checkpoint": str(request.checkpoint),
        "rate": str(request.rate),
        "record": str(request.recording),
        "record_topics": json.dumps(list(RECORDED_TOPICS)),
        "record_sim_time": "false",
        "remap": json.dumps(dict(request.remap or {})),
        "play_topics": json.dumps(list(request.play_topics)),
        # the recorder subscribes RGB too (latency): wait for a topic only perception subscribes, and for
        # outputs only the recorder subscribes (it starts slower than perception on a loaded machine)
        "wait_for": json.dumps([topics.NAVIGATION_COMMAND, topics.VEHICLE_CONTROL, topics.DIAGNOSTICS]),
        "start_delay": str(START_DELAY_S),
        "end_delay": str(END_DELAY_S),
        "aeb": str(request.aeb).lower(),
        "aeb_crop_top": str(request.crop_top_fraction),
        "aeb_camera": json.dumps(camera_parameters(request.camera) if request.camera else {}),
    }
    command = [sys.executable, "-m", "msfsu_bringup", "replay"]
    for name, value in arguments.items():
        command += ["--arg", f"{name}={value}"]
    return command


def bag_duration_s(bag: Path) -> float:
    with open_bag(bag) as reader:
        return reader.duration * 1e-9


def run_replay(request: ReplayRequest) -> None:
    """Run the replay profile to the end of the bag; ReplayError if it fails or hangs.

    Progress: "starting" until the player logs that playback started (nodes load for seconds),
    then the share of the bag played, from the wall time since. Shown on terminals only (not in CI logs).
    """
    play_s = bag_duration_s(request.bag) / request.rate + END_DELAY_S
    timeout_s = STARTUP_ALLOWANCE_S + 2 * play_s
    deadline = time.monotonic() + timeout_s
    playing_since: float | None = None
    log_end = ""  # the last characters read, so a line split between two reads is still found
    bar_format = "{desc}: {percentage:3.0f}%|{bar}| {n:.1f}/{total:.1f} s of replay"
    with (domain_id() as domain, request.log.open("w") as log, request.log.open() as log_reader,
          tqdm(total=round(play_s, 1), desc="starting the graph", bar_format=bar_format,
               disable=None, leave=False) as progress):
        process = subprocess.Popen(replay_command(request), stdout=log, stderr=subprocess.STDOUT,
                                   env=dict(os.environ, ROS_DOMAIN_ID=str(domain)),
                                   preexec_fn=die_with_parent())  # killed (SIGTERM, SIGKILL): the graph stops
        try:
            while process.poll() is None:
                if time.monotonic() > deadline:
                    raise ReplayError(f"replay still running after {timeout_s:.0f} s\n{_tail(request.log)}")
                text = log_end + log_reader.read()
                log_end = text[-len(STARTED_MESSAGE):]
                if playing_since is None and STARTED_MESSAGE in text:
                    playing_since = time.monotonic()
                    progress.set_description_str("replaying")
                if playing_since is not None:
                    progress.n = round(min(time.monotonic() - playing_since, play_s), 1)
                progress.refresh()
                time.sleep(0.2)
        finally:
            if process.poll() is None:  # timeout or Ctrl-C: the launcher stops its nodes on SIGINT
                process.send_signal(signal.SIGINT)
                process.wait()
    if process.returncode != 0:
        raise ReplayError(f"the replay graph exited with code {process.returncode}\n{_tail(request.log)}")


def _tail(log: Path) -> str:
    lines = log.read_text(errors="replace").splitlines()[-LOG_TAIL_LINES:]
    return f"last lines of {log}:\n" + "\n".join(lines)

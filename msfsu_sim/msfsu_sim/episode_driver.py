"""Who drives a collected episode: the expert alone, or on-policy (DAgger, Ross et al. 2011) the expert with
probability beta and the network otherwise, one seeded draw per step.

The network runs in this process through the perception node's per-frame function
(`msfsu_perception.frame_inference.infer_frame`, at the node's default `max_invalid_depth_fraction`), and whoever
drives, the steer and target speed go through the control node's speed PID (`ActionController`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from msfsu_common import bag_io
from msfsu_control.pid import ActionController
from msfsu_perception.frame_inference import infer_frame
from msfsu_sim.environment import Observation

if TYPE_CHECKING:
    from msfsu_perception.inference import DrivingModel, Prediction

DRIVER_STREAM = 1  # second entropy word of the per-episode driver draws (steering noise uses the seed alone)


@dataclass(frozen=True)
class Driver:
    """Who drives the steps of an episode: the expert with probability `beta`, else the network."""

    checkpoint: str | None = None  # the network's checkpoint; None: the expert drives every step
    beta: float = 1.0
    digest: str = ""  # the checkpoint's content hash (deploy_files.file_digest)
    backend: str = "auto"  # DrivingModel backend / precision, as the perception node's parameters
    precision: str = "auto"

    @property
    def on_policy(self) -> bool:
        """Does the network drive any step?"""
        return self.checkpoint is not None and self.beta < 1.0

    def metadata(self) -> dict[str, str]:
        if self.checkpoint is None:
            return {bag_io.DRIVER: bag_io.EXPERT_DRIVER, bag_io.BETA: str(self.beta)}
        return {bag_io.DRIVER: self.checkpoint, bag_io.DRIVER_DIGEST: self.digest, bag_io.BETA: str(self.beta)}


EXPERT = Driver()

_networks: dict[Driver, DrivingModel] = {}  # one load per driver and process, kept across episodes


def load_network(driver: Driver) -> DrivingModel:
    """The driver's network on its backend (CheckpointError / BackendUnavailableError / ValueError if unusable)."""
    from msfsu_perception.inference import DrivingModel

    return DrivingModel.from_checkpoint(driver.checkpoint, backend=driver.backend, precision=driver.precision)


def driver_network(driver: Driver) -> DrivingModel | None:
    """The network that drives `driver`'s on-policy steps (loaded once per process); None if the expert drives all."""
    if not driver.on_policy:
        return None
    if driver not in _networks:
        _networks[driver] = load_network(driver)
    return _networks[driver]


def keep_network(driver: Driver, network: DrivingModel) -> None:
    """Let this process's episodes of an on-policy `driver` use `network`, already loaded."""
    if driver.on_policy:
        _networks[driver] = network


class Pilot:
    """Who drives each step of an episode, and the control node's controller that turns the chosen steer and
    target speed into the applied control (one speed PID, whoever asks)."""

    def __init__(self, seed: int, beta: float, network: DrivingModel | None = None) -> None:
        if beta < 1.0 and network is None:
            raise ValueError(f"beta {beta} < 1 needs a network to drive")
        self.beta, self.network = beta, network
        self.controller = ActionController()
        self._draws = np.random.default_rng((seed, DRIVER_STREAM))

    def network_drives(self) -> bool:
        """Draw who drives this step: the network with probability 1 - beta (one draw per step)."""
        return bool(self._draws.random() >= self.beta)

    def network_action(self, obs: Observation) -> Prediction:
        """The network's steer and target speed for the frame, by the perception node's per-frame function (a frame
        it rejects raises its ValueError)."""
        return infer_frame(self.network, obs.rgb, obs.depth, obs.command).prediction

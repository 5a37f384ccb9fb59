"""Longitudinal control: desired speed -> throttle/brake, and a steering rate limiter.

The PID follows the peers the paper compares against (TransFuser/TCP/InterFuser): per-sample gains
Kp 5.0, Ki 0.5, Kd 1.0 on the speed error, an integral that is the mean of the last n errors (a
window cannot wind up), throttle capped at 0.75, and a brake rule instead of negative throttle:
brake when the desired speed is ~0 or the car is more than 10 % too fast.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

from msfsu_common.driving import STOP_SPEED_MPS
from msfsu_common.settings import setting


@dataclass(frozen=True)
class SpeedControlConfig:
    kp: float = setting(5.0, "proportional gain (per sample)", 0.0, 100.0)
    ki: float = setting(0.5, "integral gain on the windowed mean error", 0.0, 100.0)
    kd: float = setting(1.0, "derivative gain (per sample)", 0.0, 100.0)
    integral_window: int = setting(40, "samples in the integral window (anti-windup)", 1, 1000)
    # the speed error is clipped to [0, max_error] before the PID, as peers do
    max_error: float = setting(0.25, "speed error clip, m/s", 0.01, 50.0)
    max_throttle: float = setting(0.75, "throttle cap", 0.0, 1.0)
    stop_speed: float = setting(STOP_SPEED_MPS, "brake to stand still below this desired speed, m/s", 0.0, 10.0)
    overspeed_ratio: float = setting(1.1, "brake when speed/desired exceeds this", 1.0, 10.0)
    brake: float = setting(1.0, "brake value when braking", 0.0, 1.0)


@dataclass(frozen=True)
class Longitudinal:
    throttle: float
    brake: float


class WindowedPid:
    """PID whose integral is the mean over a fixed window of samples (bounded: no windup)."""

    def __init__(self, kp: float, ki: float, kd: float, window: int) -> None:
        self._errors: deque[float] = deque()
        self.configure(kp, ki, kd, window)

    def configure(self, kp: float, ki: float, kd: float, window: int) -> None:
        """New gains and window from the next step on; the newest `window` errors stay in the window."""
        if window < 1:
            raise ValueError("integral window must hold at least one sample")
        self.kp, self.ki, self.kd = kp, ki, kd
        if window != self._errors.maxlen:
            self._errors = deque(self._errors, maxlen=window)

    def step(self, error: float) -> float:
        self._errors.append(error)
        integral = sum(self._errors) / len(self._errors)
        derivative = self._errors[-1] - self._errors[-2] if len(self._errors) > 1 else 0.0
        return self.kp * error + self.ki * integral + self.kd * derivative

    def reset(self) -> None:
        self._errors.clear()


class SpeedController:
    """Desired and measured speed (m/s) -> throttle [0, max_throttle] and brake [0, 1]; one call per sample."""

    def __init__(self, config: SpeedControlConfig = SpeedControlConfig()) -> None:
        self.config = config
        self._pid = WindowedPid(config.kp, config.ki, config.kd, config.integral_window)

    def configure(self, config: SpeedControlConfig) -> None:
        """`config` from the next step on (the PID's error window carries over)."""
        self._pid.configure(config.kp, config.ki, config.kd, config.integral_window)
        self.config = config

    def step(self, desired_speed: float, speed: float) -> Longitudinal:
        config = self.config
        braking = desired_speed < config.stop_speed or speed > config.overspeed_ratio * desired_speed
        error = min(max(desired_speed - speed, 0.0), config.max_error)
        throttle = min(max(self._pid.step(error), 0.0), config.max_throttle)
        if braking:
            return Longitudinal(throttle=0.0, brake=config.brake)
        return Longitudinal(throttle=throttle, brake=0.0)

    def reset(self) -> None:
        self._pid.reset()


class SteerRateLimiter:
    """Limits how fast the steering command may change (per second); rate <= 0 passes through."""

    def __init__(self, max_rate: float) -> None:
        self.max_rate = max_rate
        self._last: float | None = None

    def step(self, steer: float, dt: float) -> float:
        steer = min(max(steer, -1.0), 1.0)
        if self._last is not None and self.max_rate > 0.0 and dt > 0.0:
            max_change = self.max_rate * dt
            steer = min(max(steer, self._last - max_change), self._last + max_change)
        self._last = steer
        return steer

    def reset(self) -> None:
        self._last = None


class InvalidActionError(ValueError):
    """A DrivingAction (or measured speed) that no control can follow: NaN or infinite values."""


def check_action(steer: float, target_speed: float) -> None:
    """InvalidActionError unless both fields of a DrivingAction are finite."""
    if not (math.isfinite(steer) and math.isfinite(target_speed)):
        raise InvalidActionError(f"non-finite DrivingAction (steer={steer}, target_speed={target_speed})")


@dataclass(frozen=True)
class Control:
    throttle: float  # [0, max_throttle]
    brake: float  # [0, 1]
    steer: float  # [-1, 1]


class ActionController:
    """The control core: each DrivingAction (steer, target speed) + the measured speed -> one Control.

    Any finite input gives a control within its ranges (target speeds below 0 mean stop, steer is
    clipped to [-1, 1]); non-finite input raises InvalidActionError and leaves the state untouched.
    """

    def __init__(self, config: SpeedControlConfig = SpeedControlConfig(), max_steer_rate: float = 0.0) -> None:
        self.speed_controller = SpeedController(config)
        self.steer_limiter = SteerRateLimiter(max_steer_rate)

    def configure(self, config: SpeedControlConfig, max_steer_rate: float) -> None:
        """A whole new configuration from the next step on. The state carries over: the errors in the integral
        window (a shorter window keeps the newest) and the last steer the rate limit starts from."""
        self.speed_controller.configure(config)
        self.steer_limiter.max_rate = max_steer_rate

    def step(self, steer: float, target_speed: float, speed: float, dt: float) -> Control:
        """dt: seconds since the previous action (0 or less: none, no rate limit)."""
        steer, target_speed, speed, dt = float(steer), float(target_speed), float(speed), float(dt)
        check_action(steer, target_speed)
        if not (math.isfinite(speed) and speed >= 0.0):
            raise InvalidActionError(f"measured speed {speed} is not a finite non-negative number")
        longitudinal = self.speed_controller.step(max(target_speed, 0.0), speed)
        return Control(longitudinal.throttle, longitudinal.brake,
                       self.steer_limiter.step(steer, dt if math.isfinite(dt) else 0.0))

    def reset(self) -> None:
        self.speed_controller.reset()
        self.steer_limiter.reset()

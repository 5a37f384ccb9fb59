"""Speed controller on a simple longitudinal vehicle model (no ROS)."""

from dataclasses import dataclass

import pytest

from msfsu_control.pid import ActionController, SpeedControlConfig, SpeedController, SteerRateLimiter, WindowedPid

DT = 0.1  # 10 Hz, the camera / action rate


@dataclass
class LongitudinalVehicle:
    """Point mass: up to 4 m/s^2 of drive, 8 m/s^2 of braking, aerodynamic drag and rolling resistance."""

    speed: float = 0.0

    def step(self, throttle: float, brake: float, slope_accel: float = 0.0) -> float:
        accel = 4.0 * throttle - 8.0 * brake - 0.02 * self.speed**2 - (0.15 if self.speed > 0 else 0.0) + slope_accel
        self.speed = max(0.0, self.speed + accel * DT)
        return self.speed


def drive(controller: SpeedController, vehicle: LongitudinalVehicle, desired: float, steps: int, slope=0.0):
    speeds = []
    for _ in range(steps):
        command = controller.step(desired, vehicle.speed)
        assert 0.0 <= command.throttle <= controller.config.max_throttle
        assert 0.0 <= command.brake <= 1.0
        assert command.throttle == 0.0 or command.brake == 0.0
        speeds.append(vehicle.step(command.throttle, command.brake, slope))
    return speeds


def test_step_response_settles_without_overshoot():
    speeds = drive(SpeedController(), LongitudinalVehicle(), desired=8.0, steps=300)
    assert max(speeds) <= 8.0 * 1.1  # the brake rule bounds overshoot at 10 %
    assert all(abs(v - 8.0) < 0.4 for v in speeds[100:])  # settled after 10 s


def test_no_windup_after_saturation():
    """Hold the car back (steep hill) with throttle saturated, then release: no overshoot burst."""
    controller, vehicle = SpeedController(), LongitudinalVehicle()
    held = drive(controller, vehicle, desired=10.0, steps=300, slope=-2.9)
    assert held[-1] < 5.0  # could not reach the target: saturated for 30 s
    released = drive(controller, vehicle, desired=5.0, steps=300)
    assert max(released) <= 5.0 * 1.1
    assert abs(released[-1] - 5.0) < 0.4


def test_brakes_to_stop_when_desired_speed_is_zero():
    controller, vehicle = SpeedController(), LongitudinalVehicle(speed=8.0)
    command = controller.step(0.0, vehicle.speed)
    assert (command.throttle, command.brake) == (0.0, 1.0)
    assert drive(controller, vehicle, desired=0.0, steps=30)[-1] == 0.0


def test_windowed_pid_terms():
    pid = WindowedPid(kp=2.0, ki=1.0, kd=0.5, window=2)
    assert pid.step(1.0) == pytest.approx(2.0 + 1.0)  # no derivative on the first sample
    assert pid.step(3.0) == pytest.approx(6.0 + 2.0 + 0.5 * 2.0)
    assert pid.step(3.0) == pytest.approx(6.0 + 3.0 + 0.0)  # window forgot the first error


def test_steer_rate_limiter():
    limiter = SteerRateLimiter(max_rate=1.0)
    assert limiter.step(0.0, 0.1) == 0.0
    assert limiter.step(1.0, 0.1) == pytest.approx(0.1)
    assert limiter.step(2.0, 0.1) == pytest.approx(0.2)  # also clipped to [-1, 1] first
    assert SteerRateLimiter(max_rate=0.0).step(-0.7, 0.1) == -0.7


def test_configure_takes_new_gains_from_the_next_step_and_keeps_the_newest_errors_of_the_window():
    pid = WindowedPid(kp=2.0, ki=1.0, kd=0.5, window=3)
    pid.step(1.0)
    pid.step(0.5)
    pid.configure(kp=1.0, ki=2.0, kd=4.0, window=2)  # the window keeps 0.5 and takes 0.25
    assert pid.step(0.25) == pytest.approx(1.0 * 0.25 + 2.0 * 0.375 + 4.0 * -0.25)


def test_a_configured_action_controller_steps_as_one_built_with_that_configuration_and_the_same_history():
    faster = SpeedControlConfig(kp=3.0, ki=0.2, integral_window=2)
    configured, built = ActionController(), ActionController(faster, max_steer_rate=1.0)
    for controller in (configured, built):
        controller.step(0.0, 4.1, 4.0, 0.1)
    configured.configure(faster, max_steer_rate=1.0)
    assert configured.step(1.0, 4.2, 4.0, 0.1) == built.step(1.0, 4.2, 4.0, 0.1)
    assert configured.speed_controller.config is faster
    assert configured.step(1.0, 4.2, 4.0, 0.1).steer == pytest.approx(0.2)

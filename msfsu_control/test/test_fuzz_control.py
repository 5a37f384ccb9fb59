"""Fuzz (hypothesis): any DrivingAction field values into the control core give a control within range, or
InvalidActionError for non-finite ones; a run of them never breaks the controller's state."""

import math

from hypothesis import given, settings
from hypothesis import strategies as st

from msfsu_control.pid import ActionController, InvalidActionError, SpeedControlConfig

ANY_FLOAT = st.floats(allow_nan=True, allow_infinity=True)  # float64: wider than the messages' float32


@settings(max_examples=300)
@given(st.lists(st.tuples(ANY_FLOAT, ANY_FLOAT, st.floats(0, 1e6) | ANY_FLOAT, ANY_FLOAT), min_size=1, max_size=20),
       st.floats(0, 100))
def test_any_driving_action_gives_a_control_in_range_or_an_invalid_action_error(actions, max_steer_rate):
    config = SpeedControlConfig()
    controller = ActionController(config, max_steer_rate)
    for steer, target_speed, speed, dt in actions:
        try:
            control = controller.step(steer, target_speed, speed, dt)
        except InvalidActionError:
            assert not all(math.isfinite(v) for v in (steer, target_speed, speed)) or speed < 0
            continue
        assert 0.0 <= control.throttle <= config.max_throttle and 0.0 <= control.brake <= 1.0
        assert -1.0 <= control.steer <= 1.0
        assert control.throttle == 0.0 or control.brake == 0.0
    control = controller.step(0.0, 5.0, 0.0, 0.1)  # still serves an ordinary action afterwards
    assert control.throttle > 0.0 and control.brake == 0.0

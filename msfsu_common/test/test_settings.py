"""Settings dataclasses (msfsu_common.settings): flattened parameters, whole new configurations, rules (no ROS)."""

from dataclasses import dataclass, field

import pytest

from msfsu_common.settings import Parameter, Setting, differences, parameters, render, setting, values, with_values


@dataclass(frozen=True)
class Gains:
    kp: float = setting(5.0, "proportional gain", 0.0, 100.0)
    window: int = setting(40, "samples", 1, 1000)


@dataclass(frozen=True)
class Limits:
    low: float = setting(0.0, "lower limit", -10.0, 10.0, name="limit_low")
    high: float = setting(1.0, "upper limit", -10.0, 10.0, name="limit_high")

    def __post_init__(self) -> None:
        if self.low > self.high:
            raise ValueError(f"limit_low {self.low} is above limit_high {self.high}")


@dataclass(frozen=True)
class NodeSettings:
    gains: Gains = field(default_factory=Gains)
    limits: Limits = field(default_factory=Limits)
    mode: str = setting("fast", "how to run", choices=("fast", "exact"))
    topics: tuple[str, ...] = setting(("",), "topics")
    trace: bool = setting(False, "publish traces")


def test_parameters_are_the_leaf_settings_in_field_order_under_their_parameter_names():
    assert parameters(NodeSettings) == [
        Parameter("kp", 5.0, Setting("proportional gain", 0.0, 100.0)),
        Parameter("window", 40, Setting("samples", 1, 1000)),
        Parameter("limit_low", 0.0, Setting("lower limit", -10.0, 10.0, name="limit_low")),
        Parameter("limit_high", 1.0, Setting("upper limit", -10.0, 10.0, name="limit_high")),
        Parameter("mode", "fast", Setting("how to run", choices=("fast", "exact"))),
        Parameter("topics", ("",), Setting("topics")),
        Parameter("trace", False, Setting("publish traces")),
    ]


def test_two_settings_of_one_name_are_refused():
    @dataclass(frozen=True)
    class Twice:
        gains: Gains = field(default_factory=Gains)
        kp: float = setting(1.0, "another kp")

    with pytest.raises(ValueError, match=r"Twice: parameter names repeat: \['kp'\]"):
        parameters(Twice)


def test_with_values_builds_a_new_whole_configuration_and_leaves_the_old_one():
    old = NodeSettings()
    new = with_values(old, {"kp": 3.0, "limit_low": 0.5, "topics": ["/a", "/b"], "window": 10})
    assert new == NodeSettings(Gains(3.0, 10), Limits(0.5, 1.0), topics=("/a", "/b"))
    assert old == NodeSettings() and new.limits is not old.limits and new is not old
    assert with_values(old, {}) is old
    assert with_values(old, {"kp": 2}).gains.kp == 2.0  # an int for a float setting: taken as a float


@pytest.mark.parametrize(("changes", "reason"), [
    ({"kp": 100.5}, r"^kp 100.5 is outside \[0.0, 100.0\]$"),
    ({"window": 0}, r"^window 0 is outside \[1, 1000\]$"),
    ({"window": 2.0}, r"^window takes a int, not float 2.0$"),
    ({"trace": 1}, r"^trace takes a bool, not int 1$"),
    ({"topics": [1]}, r"^topics takes a sequence of str, not \(1,\)$"),
    ({"mode": "slow"}, r"^mode 'slow' is not one of fast, exact$"),
    ({"limit_low": 2.0}, r"^limit_low 2.0 is above limit_high 1.0$"),
    ({"kp": 3.0, "limit_high": -1.0}, r"^limit_low 0.0 is above limit_high -1.0$"),
    ({"kd": 1.0}, r"^no such parameter: kd$"),
])
def test_one_invalid_value_or_broken_rule_refuses_the_whole_configuration(changes, reason):
    with pytest.raises(ValueError, match=reason):
        with_values(NodeSettings(), changes)


def test_values_move_together_past_a_cross_field_rule_that_each_alone_would_break():
    moved = with_values(NodeSettings(), {"limit_low": 5.0, "limit_high": 6.0})
    assert moved.limits == Limits(5.0, 6.0)


def test_differences_name_each_changed_value_old_to_new():
    new = with_values(NodeSettings(), {"kp": 3.0, "topics": ("/a", "/b"), "trace": True, "window": 40})
    assert differences(NodeSettings(), new) == ["kp 5.0 -> 3.0", "topics [] -> [/a, /b]", "trace False -> True"]
    assert values(new)["topics"] == ("/a", "/b") and render(("/a",)) == "[/a]"


def test_a_setting_with_half_a_range_or_a_range_on_a_bool_is_refused():
    with pytest.raises(ValueError, match="a range needs both ends"):
        setting(1.0, "gain", low=0.0)
    with pytest.raises(ValueError, match="a bool takes no range"):
        setting(False, "flag", 0, 1)

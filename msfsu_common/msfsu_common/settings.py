"""A node's settings as frozen dataclasses, one field per parameter, with its meaning and its valid values (ROS-free).

A field made with `setting()` is a parameter: the field's default is the parameter's default, its `Setting` says
what it means and which values are valid (a closed range for numbers, a list of choices for strings). Its type is
its default's type (an int setting takes no float, a float setting takes an int as a float; a sequence is a tuple).
A field whose default is itself a settings dataclass stands for that dataclass's settings: parameter names are the
leaf names (`Setting.name`, else the field name) and must be unique in a node. Every field has a default, so
`SettingsClass()` is the node's defaults.

A new configuration is built whole (`with_values`): each value checked against its setting, then the dataclasses
rebuilt with `dataclasses.replace`, which runs their `__post_init__`, where a class states its cross-field rules by
raising ValueError. Either every value is taken or the call raises and the old instance stays as it was.
msfsu_common.params turns these fields into ROS parameters.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, TypeVar

SETTING = "msfsu_setting"  # the dataclass field metadata key that holds a Setting
S = TypeVar("S")


@dataclass(frozen=True)
class Setting:
    """What a parameter means and which values it takes: [low, high] (numbers) or choices (strings)."""

    description: str
    low: float | None = None
    high: float | None = None
    choices: tuple[str, ...] = ()
    name: str | None = None  # the parameter's name where it differs from the field's


@dataclass(frozen=True)
class Parameter:
    """One leaf setting of a settings dataclass, flattened: its parameter name, default and Setting."""

    name: str
    default: Any
    setting: Setting


def setting(default: Any, description: str, low: float | None = None, high: float | None = None,
            choices: Sequence[str] = (), name: str | None = None) -> Any:
    """A dataclass field that is a parameter (see the module doc); a range takes both ends."""
    if (low is None) != (high is None):
        raise ValueError(f"setting '{description}': a range needs both ends")
    if low is not None and isinstance(default, bool):
        raise ValueError(f"setting '{description}': a bool takes no range")
    return dataclasses.field(default=default, metadata={SETTING: Setting(description, low, high, tuple(choices), name)})


def _leaves(config: Any) -> Iterator[tuple[dataclasses.Field, Any]]:
    """(field, value) of every leaf setting of `config`, nested settings dataclasses flattened."""
    for field in dataclasses.fields(config):
        value = getattr(config, field.name)
        if SETTING in field.metadata:
            yield field, value
        elif dataclasses.is_dataclass(value):
            yield from _leaves(value)


def parameter_name(field: dataclasses.Field) -> str:
    return field.metadata[SETTING].name or field.name


def parameters(settings_type: type) -> list[Parameter]:
    """Every parameter of a settings dataclass, in field order; ValueError if two share a name."""
    found = [Parameter(parameter_name(field), value, field.metadata[SETTING])
             for field, value in _leaves(settings_type())]
    names = [parameter.name for parameter in found]
    if len(set(names)) != len(names):
        repeated = sorted(name for name in set(names) if names.count(name) > 1)
        raise ValueError(f"{settings_type.__name__}: parameter names repeat: {repeated}")
    return found


def values(config: Any) -> dict[str, Any]:
    """Parameter name -> value of every leaf setting of `config`."""
    return {parameter_name(field): value for field, value in _leaves(config)}


def checked(name: str, value: Any, default: Any, spec: Setting) -> Any:
    """`value` as the setting takes it (a list as a tuple, an int as a float for a float setting); ValueError if its
    type is not the default's, or it lies outside [low, high], or is not one of the choices."""
    if isinstance(value, list):
        value = tuple(value)
    if isinstance(default, float) and isinstance(value, int) and not isinstance(value, bool):
        value = float(value)
    if type(value) is not type(default):
        raise ValueError(f"{name} takes a {type(default).__name__}, not {type(value).__name__} {value!r}")
    if isinstance(value, tuple) and default and not all(type(item) is type(default[0]) for item in value):
        raise ValueError(f"{name} takes a sequence of {type(default[0]).__name__}, not {value!r}")
    if spec.low is not None and not spec.low <= value <= spec.high:
        raise ValueError(f"{name} {value!r} is outside [{spec.low}, {spec.high}]")
    if spec.choices and value not in spec.choices:
        raise ValueError(f"{name} {value!r} is not one of {', '.join(spec.choices)}")
    return value


def with_values(config: S, changes: Mapping[str, Any]) -> S:
    """A new `config` with the parameters named in `changes` set, checked as a whole (module doc); ValueError names
    the first value or rule that fails, or a name that is no parameter of `config`."""
    unknown = set(changes) - set(values(config))
    if unknown:
        raise ValueError(f"no such parameter: {', '.join(sorted(unknown))}")
    return _replaced(config, changes)


def _replaced(config: S, changes: Mapping[str, Any]) -> S:
    own: dict[str, Any] = {}
    for field in dataclasses.fields(config):
        value = getattr(config, field.name)
        if SETTING in field.metadata:
            name = parameter_name(field)
            if name in changes:
                own[field.name] = checked(name, changes[name], field.default, field.metadata[SETTING])
        elif dataclasses.is_dataclass(value):
            inner = _replaced(value, changes)
            if inner is not value:
                own[field.name] = inner
    return dataclasses.replace(config, **own) if own else config


def check(config: Any) -> None:
    """ValueError unless every leaf setting of `config` holds a valid value (start-up values are checked so)."""
    for field, value in _leaves(config):
        checked(parameter_name(field), value, field.default, field.metadata[SETTING])


def render(value: Any) -> str:
    """A parameter value as logs and diagnostics show it: sequences as [a, b], the rest as str()."""
    if isinstance(value, tuple):
        return "[" + ", ".join(render(item) for item in value) + "]"
    return str(value)


def differences(old: Any, new: Any) -> list[str]:
    """`name old -> new` for every parameter whose value differs between two instances of one settings class."""
    before = values(old)
    return [f"{name} {render(before[name])} -> {render(value)}" for name, value in values(new).items()
            if value != before[name]]

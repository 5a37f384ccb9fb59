"""What the record types share: a row of a JSON list file, the list file itself, and keys that may be absent."""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping
from dataclasses import asdict, dataclass
from typing import Any, ClassVar, Generic, Self, TypeVar


def without_absent(fields: Mapping[str, Any], optional: Iterable[str]) -> dict[str, Any]:
    """`fields` less each of the `optional` keys whose value is None (absent from the JSON), order kept."""
    absent = {key for key in optional if fields.get(key) is None}
    return {key: value for key, value in fields.items() if key not in absent}


class JsonRow:
    """A dataclass whose fields are its JSON object's keys, in order; `OPTIONAL` keys are absent when None."""

    OPTIONAL: ClassVar[tuple[str, ...]] = ()

    @classmethod
    def from_dict(cls, fields: dict[str, Any]) -> Self:
        return cls(**fields)

    def to_dict(self) -> dict[str, Any]:
        return without_absent(asdict(self), self.OPTIONAL)  # type: ignore[call-overload]


Row = TypeVar("Row", bound=JsonRow)


@dataclass(kw_only=True)
class CpuRun:
    """What a CPU benchmark's record states first: when, how, where and with how many threads it ran."""

    date: str
    command: str
    machine: str
    threads: int
    iterations: int  # timed calls per measurement

    def made_by(self) -> str:
        """The line under a docs table that says which run it comes from."""
        return f"{self.date}, {self.machine}, {self.threads} threads: `{self.command}`"


@dataclass
class RecordList(Generic[Row]):
    """A JSON list file of `ROW`s, as the benchmarks write it: one-space indentation and a final newline."""

    ROW: ClassVar[type[JsonRow]]
    rows: list[Row]

    @classmethod
    def from_json(cls, text: str) -> Self:
        rows = json.loads(text)
        if not isinstance(rows, list):
            raise ValueError(f"a list of records was expected, found a JSON {type(rows).__name__}")
        return cls([cls.ROW.from_dict(fields) for fields in rows])

    def to_json(self) -> str:
        return json.dumps([row.to_dict() for row in self.rows], indent=1) + "\n"

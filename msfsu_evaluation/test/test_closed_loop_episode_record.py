"""Every committed episodes.jsonl line reads into an EpisodeResult and writes back byte for byte, whatever its shape."""

import dataclasses
import json
from pathlib import Path

import pytest

from msfsu_evaluation.closed_loop.episode_record import EpisodeResult, FreeRunning, SolidLineCrossing

RESULTS = Path(__file__).resolve().parents[2] / "docs" / "results"
DRIVEN = ("agent", "route", "status", "success", "time_s", "steps", "route_completion", "collision_type",
          "distance_to_goal_m", "timeout_s", "wall_s", "unanswered_frames")
WORKER = ("worker_peak_rss_mb", "worker", "worker_episode")
# every record shape the committed runs hold, oldest first: what each added
SHAPES = {
    "routes v2": (*DRIVEN, "worker_peak_rss_mb"),
    "free-running": (*DRIVEN, "free_running", "worker_peak_rss_mb"),
    "routes v3": (*DRIVEN, "solid_line_crossings", *WORKER),
    "crossing starts": (*DRIVEN, "solid_line_crossings", "solid_lines", *WORKER),
    "metres by command and place": (*DRIVEN, "solid_line_crossings", "solid_lines", "metres_by_command",
                                    "metres_by_place", *WORKER),
    "collision actor": (*DRIVEN, "solid_line_crossings", "solid_lines", "metres_by_command", "metres_by_place",
                        *WORKER, "collision_actor"),
    "emergency brake": (*DRIVEN, "solid_line_crossings", "solid_lines", "metres_by_command", "metres_by_place",
                        *WORKER, "collision_actor", "aeb"),
    "emergency brake free-running": (*DRIVEN, "free_running", "solid_line_crossings", "solid_lines",
                                     "metres_by_command", "metres_by_place", *WORKER, "collision_actor", "aeb"),
    "machine": (*DRIVEN, "solid_line_crossings", "solid_lines", "metres_by_command", "metres_by_place", *WORKER,
                "collision_actor", "machine"),
}


def committed_lines() -> list[str]:
    return [line for path in sorted(RESULTS.glob("**/episodes.jsonl")) for line in path.read_text().splitlines()]


def first_of_each_shape() -> dict[tuple[str, ...], str]:
    found: dict[tuple[str, ...], str] = {}
    for line in committed_lines():
        found.setdefault(tuple(json.loads(line)), line)
    return found


def test_the_committed_records_hold_exactly_the_known_shapes():
    assert set(first_of_each_shape()) == set(SHAPES.values())


@pytest.mark.parametrize("shape", SHAPES)
def test_one_line_of_each_shape_reads_and_writes_back_byte_for_byte(shape):
    line = first_of_each_shape()[SHAPES[shape]]
    record = EpisodeResult.from_dict(json.loads(line))
    assert json.dumps(record.to_dict()) == line  # as the runner writes it
    absent = set(EpisodeResult.__dataclass_fields__) - set(SHAPES[shape])
    assert all(getattr(record, name) is None for name in absent)  # not recorded, never a recorded default


def test_every_committed_line_writes_back_byte_for_byte():
    lines = committed_lines()
    assert lines and all(json.dumps(EpisodeResult.from_dict(json.loads(line)).to_dict()) == line for line in lines)


def test_recorded_fields_read_as_typed_values_and_none_crossed_differs_from_not_recorded():
    shapes = first_of_each_shape()
    free = EpisodeResult.from_dict(json.loads(shapes[SHAPES["free-running"]]))
    assert isinstance(free.free_running, FreeRunning) and free.free_running.steps == free.steps
    newest = [EpisodeResult.from_dict(json.loads(line)) for line in committed_lines()
              if tuple(json.loads(line)) == SHAPES["metres by command and place"]]
    crossed = next(record for record in newest if record.solid_lines)
    assert all(isinstance(crossing, SolidLineCrossing) for crossing in crossed.solid_lines)
    assert len(crossed.solid_lines) == crossed.solid_line_crossings
    clean = next(record for record in newest if record.solid_line_crossings == 0)
    assert clean.solid_lines == ()  # kept and none crossed; an older record's is None
    assert EpisodeResult.from_dict(json.loads(shapes[SHAPES["routes v3"]])).solid_lines is None


def test_a_record_with_a_field_missing_or_unknown_is_refused():
    record = json.loads(first_of_each_shape()[SHAPES["routes v2"]])
    with pytest.raises(TypeError):
        EpisodeResult.from_dict({key: value for key, value in record.items() if key != "status"})
    with pytest.raises(TypeError):
        EpisodeResult.from_dict({**record, "colour": "red"})


def test_a_stamped_record_is_written_with_the_worker_last():
    record = EpisodeResult.from_dict(json.loads(first_of_each_shape()[SHAPES["metres by command and place"]]))
    unstamped = EpisodeResult.from_dict({k: v for k, v in record.to_dict().items() if k not in WORKER})
    machine = "Intel(R) Xeon(R) Processor, 2 CPUs, avx2 fma avx512f"
    stamped = unstamped.stamped(record.worker_peak_rss_mb, record.worker, record.worker_episode, machine)
    assert stamped == dataclasses.replace(record, machine=machine)
    assert tuple(unstamped.to_dict()) == SHAPES["metres by command and place"][:-len(WORKER)]
    assert tuple(stamped.to_dict()) == (*SHAPES["metres by command and place"], "machine")
    assert EpisodeResult.from_dict(json.loads(json.dumps(stamped.to_dict()))) == stamped


def test_the_brakes_false_caps_are_written_where_counted_and_absent_in_the_first_brake_runs_records():
    line = first_of_each_shape()[SHAPES["emergency brake"]]
    record = EpisodeResult.from_dict(json.loads(line))
    assert record.aeb is not None and record.aeb.false_caps is None  # the first brake's runs did not judge caps
    assert json.dumps(record.to_dict()) == line
    counted = dataclasses.replace(record, aeb=dataclasses.replace(record.aeb, caps=2, false_caps=1))
    written = counted.to_dict()
    assert written["aeb"]["false_caps"] == 1 and EpisodeResult.from_dict(json.loads(json.dumps(written))) == counted

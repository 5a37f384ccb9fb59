"""The soak record (benchmarks/soak.py): the free-running graph fed by a camera at one size and rate, its goals.

    benchmarks/soak/<W>x<H>_<R>hz.json                         # one soak per camera size and rate
    benchmarks/soak/design/<inference>_<transport>_<W>x<H>_<R>hz.json   # the design study, one fix at a time

Rules:
- The goals are the real-time issue's, per camera size and rate (`SOAK_GOALS`); a soak without a goal has none to
  meet. A soak meets its goal when its end-to-end p95 is within the goal's, every frame is under the goal's maximum
  where it sets one, no frame went unpaired, the watchdog never braked while the graph drove, and at least
  `MIN_SERVED_SHARE` of the frames were answered or skipped for a newer one.
- Soaks are listed by camera width, then rate; the design study's by camera width, then file name.
- Percentile dicts (`end_to_end_ms`, the stage rows, the windows) are msfsu_common.benchmark_run.percentiles's:
  a statistic with no samples is absent, and rendered as "-".
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

SLOW_MS = 50.0  # a frame slower than this end to end gets its cause named
MIN_SERVED_SHARE = 0.99  # of the frames published: answered, or skipped for a newer one


@dataclass(frozen=True)
class SoakGoal:
    """End to end p95 within `p95_ms` and, where set, every frame under `max_ms`."""

    p95_ms: float
    max_ms: float | None = None

    def text(self) -> str:
        return f"p95 <= {self.p95_ms:g}" + (f", max < {self.max_ms:g}" if self.max_ms is not None else "")


# the real-time issue's goals per (camera size, rate in Hz)
SOAK_GOALS: dict[tuple[str, float], SoakGoal] = {
    ("800x600", 20.0): SoakGoal(25.0, 100.0), ("800x600", 30.0): SoakGoal(30.0, 100.0),
    ("1280x720", 30.0): SoakGoal(40.0), ("1920x1080", 30.0): SoakGoal(60.0)}


@dataclass(kw_only=True)
class SoakTotals:
    """The whole soak's counts and latencies."""

    published: int
    answered: int
    processed: int = 0
    skipped: int
    unpaired: int
    dropped: dict[str, int] = field(default_factory=dict)  # perception's drop counters by cause
    answered_or_skipped_share: float
    end_to_end_ms: dict[str, float]
    camera_late_ms: dict[str, float] = field(default_factory=dict)
    camera_send_ms: dict[str, float] = field(default_factory=dict)
    watchdog_brakes_driving: int
    watchdog_brakes_total: int = -1  # the control node's count, start and end included; -1: not reported
    first_answered_frame: int | None = None
    rss_mb: list[dict[str, float]] = field(default_factory=list)  # {"t_s", <process>: MB} per sample


@dataclass(kw_only=True)
class SoakRecord:
    """One soak; `totals` is None until the benchmark has analysed its frames."""

    started_utc: str
    minutes: float
    size: str  # WxH
    camera: str
    rate_hz: float
    checkpoint: str
    inference: str  # backend/precision the perception node chose
    machine: str
    load_average_start: str
    load_average_end: str
    command: str = ""
    totals: SoakTotals | None = None
    stages: list[dict[str, Any]] = field(default_factory=list)  # latency_trace.stage_rows
    slow_ms: float = SLOW_MS
    slow_causes: dict[str, int] = field(default_factory=dict)  # most frames first
    slow_examples: list[dict[str, Any]] = field(default_factory=list)
    windows: list[dict[str, Any]] = field(default_factory=list)
    diagnostics: dict[str, dict[str, str]] = field(default_factory=dict)  # last status per name

    @classmethod
    def from_json(cls, text: str) -> SoakRecord:
        fields = json.loads(text)
        totals = fields.pop("totals", None)
        return cls(**fields, totals=None if totals is None else SoakTotals(**totals))

    def to_json(self) -> str:
        return json.dumps(asdict(self), indent=1)

    @property
    def name(self) -> str:
        """`<W>x<H>_<R>hz`, the stem of its files."""
        return f"{self.size}_{self.rate_hz:g}hz"

    @property
    def width(self) -> int:
        return int(self.size.split("x")[0])

    @property
    def goal(self) -> SoakGoal | None:
        return SOAK_GOALS.get((self.size, self.rate_hz))

    def met_goal(self) -> bool | None:
        """Whether the soak met its goal; None where its camera size and rate have none."""
        goal = self.goal
        if goal is None:
            return None
        totals = self.analysed()
        e2e = totals.end_to_end_ms
        return (e2e.get("p95", float("inf")) <= goal.p95_ms
                and (goal.max_ms is None or e2e.get("max", float("inf")) < goal.max_ms)
                and totals.unpaired == 0 and totals.watchdog_brakes_driving == 0
                and totals.answered_or_skipped_share >= MIN_SERVED_SHARE)

    def goal_text(self) -> str:
        """'<goal>: met' or '<goal>: **not met**'; '-' without a goal."""
        goal, met = self.goal, self.met_goal()
        return "-" if goal is None else f"{goal.text()}: {'met' if met else '**not met**'}"

    def analysed(self) -> SoakTotals:
        """`totals`, which every committed soak has; an error before the benchmark analysed the frames."""
        if self.totals is None:
            raise ValueError(f"soak {self.name} has no totals: its frames were never analysed")
        return self.totals

    def page(self) -> str:
        """benchmarks/soak/<name>.md: the totals, the stages, the slow frames' causes, the windows, memory and the
        last diagnostics."""
        t = self.analysed()
        e2e = t.end_to_end_ms
        lines = [
            f"# Soak: perception + control, {self.camera} at {self.rate_hz:g} Hz for {self.minutes:g} min",
            "",
            f"`{self.command}` on {self.started_utc}; {self.machine}; load average at the start "
            f"{self.load_average_start}, at the end {self.load_average_end}. Checkpoint "
            f"`{Path(self.checkpoint).name}`, perception on **{self.inference}**. Four processes: camera, perception, "
            "control, measurer; wall-clock marks per frame (msfsu_common.stage_times).",
            "",
            "| frames published | answered (VehicleControl) | skipped for a newer frame | answered or skipped | unpaired "
            "| other drops | watchdog brakes while driving (all, start and end included) |",
            "| --- | --- | --- | --- | --- | --- | --- |",
            f"| {t.published} | {t.answered} | {t.skipped} | {100 * t.answered_or_skipped_share:.2f} % | "
            f"{t.unpaired} | {sum(v for k, v in t.dropped.items() if not k.startswith('unpaired'))} | "
            f"{t.watchdog_brakes_driving} ({t.watchdog_brakes_total}) |",
            "",
            f"End to end (camera stamp -> VehicleControl at the measurer): p50 {_ms(e2e, 'p50')}, p95 {_ms(e2e, 'p95')}, "
            f"p99 {_ms(e2e, 'p99')}, max {_ms(e2e, 'max')} ms over {e2e.get('n', 0)} frames. Camera: sends late against "
            f"its clock p95 {_ms(t.camera_late_ms, 'p95')} ms (max {_ms(t.camera_late_ms, 'max')}), a send (three "
            f"publish calls) p50 {_ms(t.camera_send_ms, 'p50')} ms, p95 {_ms(t.camera_send_ms, 'p95')} ms.",
            "",
            "| stage (answered frames) | from -> to | p50 ms | p95 ms | p99 ms | max ms |",
            "| --- | --- | --- | --- | --- | --- |",
        ]
        lines += [f"| {row['stage']} | `{row['from']}` -> `{row['to']}` | {_ms(row, 'p50')} | {_ms(row, 'p95')} | "
                  f"{_ms(row, 'p99')} | {_ms(row, 'max')} |" for row in self.stages]
        lines += self._slow_lines() + self._window_lines() + self._memory_lines()
        for name, values in self.diagnostics.items():
            lines += ["", f"Last diagnostics of {name}: " + ", ".join(f"{k} {v}" for k, v in values.items())]
        return "\n".join(lines) + "\n"

    def _slow_lines(self) -> list[str]:
        slow = sum(self.slow_causes.values())
        lines = ["", f"Frames slower than {self.slow_ms:g} ms end to end: {slow} of {self.analysed().answered}"
                 + (", by the stage that took longest on the frame's critical path:" if slow else ".")]
        if slow:
            lines += ["", "| cause | frames |", "| --- | --- |"]
            lines += [f"| {cause} | {count} |" for cause, count in self.slow_causes.items()]
        return lines

    def _window_lines(self) -> list[str]:
        lines = ["", "| window start, s | published | answered | end to end p50 ms | p95 ms | max ms |",
                 "| --- | --- | --- | --- | --- | --- |"]
        for w in self.windows:
            e = w["end_to_end_ms"]
            lines.append(f"| {w['start_s']:.0f} | {w['published']} | {w['answered']} | {_ms(e, 'p50')} | "
                         f"{_ms(e, 'p95')} | {_ms(e, 'max')} |")
        return lines

    def _memory_lines(self) -> list[str]:
        lines = ["", "| process | private RSS (RssAnon) after the first window MB | at the end MB |", "| --- | --- | --- |"]
        samples = self.analysed().rss_mb
        if samples:
            first, last = samples[0], samples[-1]
            lines += [f"| {name} | {first[name]:.1f} | {last[name]:.1f} |" for name in last if name != "t_s"]
        return lines


def _ms(values: dict[str, Any], key: str) -> str:
    """One statistic of a percentile dict with one decimal; '-' where it has no samples."""
    return f"{values[key]:.1f}" if key in values else "-"


def read_soaks(directory: Path) -> list[SoakRecord]:
    """The soaks of `directory` (benchmarks/soak/), by camera width, then rate."""
    records = (SoakRecord.from_json(path.read_text()) for path in directory.glob("*.json"))
    return sorted(records, key=lambda r: (r.width, r.rate_hz))


def _percentiles(e2e: dict[str, float]) -> str:
    return f"{e2e['p50']:.1f} / {e2e['p95']:.1f} / {e2e['p99']:.1f} / {e2e['max']:.1f}"


def _first_load(loads: str) -> str:
    """The 1-minute figure of a page's load average text."""
    return loads.split()[0]


def soak_block(records: list[SoakRecord]) -> str:
    """One row per camera size and rate with its goal's verdict (stages and windows are in each page)."""
    if not records:
        return "Not soaked yet: `python benchmarks/soak.py` writes `benchmarks/soak/<W>x<H>_<R>hz.json`."
    rows = ["| camera (rgb8 + 32FC1) | rate | minutes | frames | answered | skipped for a newer one | unpaired | "
            "watchdog brakes while driving | camera -> VehicleControl p50 / p95 / p99 / max ms | goal (0 drops, "
            "0 brakes, >= 99 % served) | load average start / end | record |",
            "| --- |" + " --- |" * 11]
    for r in records:
        t = r.analysed()
        rows.append(f"| {r.size} | {r.rate_hz:g} Hz | {r.minutes:g} | {t.published:,} | {t.answered:,} | "
                    f"{t.skipped:,} | {t.unpaired} | {t.watchdog_brakes_driving} | "
                    f"{_percentiles(t.end_to_end_ms)} | {r.goal_text()} | "
                    f"{_first_load(r.load_average_start)} / {_first_load(r.load_average_end)} | "
                    f"[{r.name}](benchmarks/soak/{r.name}.md) |")
    first = records[0]
    checkpoint = Path(first.checkpoint)
    rows += ["", f"{first.started_utc[:10]}, {first.machine}, `{checkpoint.parent.name}/{checkpoint.name}` on "
             f"{first.inference.split(',')[0]}; each soak: `python benchmarks/soak.py --size <W>x<H> --rate <R>`."]
    return "\n".join(rows)


def soak_stages_block(records: list[SoakRecord]) -> str:
    """The stage table of every soak side by side: p50 / p95 ms of each stage on the answered frames, then the slow
    frames' causes."""
    if not records:
        return "Not soaked yet."
    names = list(dict.fromkeys(row["stage"] for r in sorted(records, key=lambda r: -len(r.stages))
                               for row in r.stages))
    rows = ["| stage, p50 / p95 ms | " + " | ".join(f"{r.size} at {r.rate_hz:g} Hz" for r in records) + " |",
            "| --- |" + " --- |" * len(records)]
    for name in names:
        found = [next((row for row in r.stages if row["stage"] == name), None) for r in records]
        rows.append(f"| {name} | " + " | ".join(f"{row['p50']:.1f} / {row['p95']:.1f}" if row and "p50" in row
                                                 else "-" for row in found) + " |")
    causes = [f"{r.size} at {r.rate_hz:g} Hz: " + (", ".join(f"{count} {cause}" for cause, count in
                                                            r.slow_causes.items()) or "none") for r in records]
    rows += ["", f"Frames slower than {records[0].slow_ms:g} ms end to end, by the stage that took longest on their "
             "critical path: " + "; ".join(causes) + "."]
    return "\n".join(rows)


def headline_latency(records: list[SoakRecord]) -> str:
    """The README's real-time line: end-to-end p50 / p95 of the smallest and the largest camera at 30 Hz."""
    soaks = [r for r in records if r.rate_hz == 30.0]
    latency = ", ".join(f"{r.analysed().end_to_end_ms['p50']:.1f} / {r.analysed().end_to_end_ms['p95']:.1f} ms "
                        f"at {r.size}" for r in (soaks[0], soaks[-1]))
    return (f"- **Real-time latency**, camera -> VehicleControl through the graph in {soaks[0].minutes:g}-minute soaks "
            f"at 30 Hz, p50 / p95: {latency} ([realtime.md](docs/realtime.md#soak)).")



AEB_ADDED_P95_GOAL_MS = 2.0  # the emergency brake's issue: at most this much added to the end-to-end p95


@dataclass(frozen=True)
class AebSoaks:
    """The same soak without and with the emergency brake (benchmarks/soak/aeb/{without,with}/, `soak.py --aeb`),
    paired by camera size and rate, and beside them the brake's other placements and modes where soaked (VARIANTS:
    crossing/, `soak.py --aeb-crossing`; composed/, `soak.py --aeb-composed`)."""

    # directory -> (the words for its verdict, its column and record link); "with" first: a pair needs it
    VARIANTS = {"with": ("the brake", "with the brake"),
                "composed": ("the brake composed with the control in one process", "composed with the control"),
                "crossing": ("the brake predicting crossings", "predicting crossings")}

    pairs: list[tuple[SoakRecord, SoakRecord]]
    variants: dict[str, dict[str, SoakRecord]] = field(default_factory=dict)  # directory -> by name, beside its pair

    @classmethod
    def read(cls, directory: Path) -> AebSoaks:
        without = {r.name: r for r in read_soaks(directory / "without")}
        variants = {variant: {r.name: r for r in read_soaks(directory / variant)}  # none while a directory is missing
                    for variant in cls.VARIANTS}
        return cls([(without[name], variants["with"][name]) for name in without if name in variants["with"]],
                   variants)

    def block(self) -> str:
        """Per pair (and its other soaks): each stage and checkpoint p50 / p95 without, with each, and the p95 added;
        the goal's verdict for each."""
        if not self.pairs:
            return "Not soaked yet."
        lines = []
        for without, with_aeb in self.pairs:
            runs = [("with", with_aeb)] + [(variant, self.variants[variant][without.name]) for variant in self.VARIANTS
                                           if variant != "with" and without.name in self.variants.get(variant, {})]
            loads = " / ".join(_first_load(r.load_average_start) for r in (without, *(r for _, r in runs)))
            verdicts = []
            for variant, record in runs:
                added = record.analysed().end_to_end_ms["p95"] - without.analysed().end_to_end_ms["p95"]
                verdict = "met" if added <= AEB_ADDED_P95_GOAL_MS else "**not met**"
                verdicts.append(f"end-to-end p95 {added:+.1f} ms with {self.VARIANTS[variant][0]} (goal: at most "
                                f"+{AEB_ADDED_P95_GOAL_MS:g} ms: {verdict})")
            header = ["without"] + [cell for variant, _ in runs for cell in (self.VARIANTS[variant][1], "p95 added")]
            lines += [f"{without.camera} at {without.rate_hz:g} Hz, {without.minutes:g} min each, one after the other "
                      f"(load average at the start {loads}, perception on {with_aeb.inference}): "
                      + "; ".join(verdicts) + ".",
                      "", "| stage, p50 / p95 ms | " + " | ".join(header) + " |", "|" + " --- |" * (len(header) + 1)]
            for stage in _stage_order([without, *(record for _, record in runs)]):
                row, *others = [next((r for r in record.stages if r["stage"] == stage), {})
                                for record in (without, *(record for _, record in runs))]
                if not any("p50" in r for r in (row, *others)):
                    continue
                cells = [_p50_p95(row)] + [cell for other in others for cell in (
                    _p50_p95(other), f"{other['p95'] - row['p95']:+.1f}" if "p95" in row and "p95" in other else "")]
                lines.append(f"| {stage} | " + " | ".join(cells) + " |")
            records = [f"[without](benchmarks/soak/aeb/without/{without.name}.md)"] + [
                f"[{self.VARIANTS[variant][1]}](benchmarks/soak/aeb/{variant}/{without.name}.md)" for variant, _ in runs]
            lines += ["", "With the brake the action goes from perception to the aeb node and from it to the control: "
                      "the rows of the brake (\"aeb: ...\", from its own stage times) sit between perception's "
                      "publish and \"DDS: action to control\", which then starts at the brake's publish. Perception "
                      "sends the frame's depth at the segmentation's pixels and the segmentation just after the "
                      "action; the camera's depth goes to perception only."
                      + (" Composed, the aeb and control nodes share one process and one executor (aeb_control): the "
                         "brake's action reaches the control without waking another process."
                         if any(variant == "composed" for variant, _ in runs) else ""),
                      "", "Records: " + ", ".join(records) + ".", ""]
        return "\n".join(lines).rstrip()


def _stage_order(records: Sequence[SoakRecord]) -> list[str]:
    """Every stage of the records, each where it first appears (the brake's own stages sit in the path's order)."""
    order: list[str] = []
    for record in records:
        names = [row["stage"] for row in record.stages]
        for index, name in enumerate(names):
            if name not in order:
                before = [n for n in names[:index] if n in order]
                order.insert(order.index(before[-1]) + 1 if before else 0, name)
    return order


def _p50_p95(row: dict) -> str:
    return f"{row['p50']:.1f} / {row['p95']:.1f}" if "p50" in row else "-"


# the design study's file names: <inference>_<transport>_<W>x<H>_<R>hz
DESIGN_LABELS = {"executor": "on its executor thread (now)", "thread": "in a thread of its own (before)",
                 "profile": "the stack's profile (shared memory, 80 MiB)", "defaults": "Fast DDS defaults (before)"}


@dataclass(frozen=True)
class DesignSoak:
    """One soak of the design study: where perception ran inference, which transport, and the soak."""

    inference: str  # a key of DESIGN_LABELS
    transport: str  # a key of DESIGN_LABELS
    record: SoakRecord


def read_design_soaks(directory: Path) -> list[DesignSoak]:
    """The design study's soaks of `directory` (benchmarks/soak/design/), by camera width, then file name."""
    paths = sorted(directory.glob("*.json"), key=lambda p: (int(p.stem.split("_")[2].split("x")[0]), p.stem))
    return [DesignSoak(*path.stem.split("_")[:2], SoakRecord.from_json(path.read_text())) for path in paths]


def soak_design_block(soaks: list[DesignSoak]) -> str:
    """The two fixes one at a time: inference on the executor thread, the stack's transport profile."""
    rows = ["| perception runs inference | transport | camera | frames | answered | skipped / unpaired | "
            "camera -> VehicleControl p50 / p95 / p99 / max ms | slower than 50 ms | load average start |",
            "| --- |" + " --- |" * 8]
    for soak in soaks:
        r = soak.record
        t = r.analysed()
        rows.append(f"| {DESIGN_LABELS[soak.inference]} | {DESIGN_LABELS[soak.transport]} | {r.size} at "
                    f"{r.rate_hz:g} Hz | {t.published:,} | {t.answered:,} | {t.skipped} / {t.unpaired} | "
                    f"{_percentiles(t.end_to_end_ms)} | {sum(r.slow_causes.values())} | "
                    f"{_first_load(r.load_average_start)} |")
    return "\n".join(rows)

"""The training-speed record (benchmarks/training.py -> benchmarks/training_results.json): msfsu-train's samples/s
against the model-only ceiling of the same run, one row per preset, device, device name and batch size.

Rules:
- The whole run is the 2N-step run, its start included; the steady state is the difference of the N- and the 2N-step
  runs. Records from before 2026-11-27 have the whole run only: their steady fields are absent, rendered "–".
- The steady data wait is a difference of two runs: noise can make it negative, rendered as 0.
"""

from __future__ import annotations

from dataclasses import dataclass

from msfsu_evaluation.records._json import JsonRow, RecordList

NOT_MEASURED = "–"


@dataclass(kw_only=True)
class TrainingRun(JsonRow):
    """One machine's measurement of one preset."""

    OPTIONAL = ("first_batch_s", "steady_samples_per_s", "steady_data_wait_share", "steady_share_of_ceiling")

    date: str
    preset: str
    device: str  # "cpu" or "cuda"
    device_name: str
    cpus: int
    torch: str
    batch_size: int
    learning_rate: float
    bf16: bool
    channels_last: bool
    workers: int
    steps: int  # N
    trainer_samples_per_s: float  # the whole run
    trainer_data_wait_share: float
    ceiling_samples_per_s: float  # N steps on one batch already on the device
    trainer_share_of_ceiling: float
    first_batch_s: float | None = None  # waiting for the loader's first batch
    steady_samples_per_s: float | None = None
    steady_data_wait_share: float | None = None
    steady_share_of_ceiling: float | None = None
    load_before: str
    load_after: str
    command: str

    @property
    def key(self) -> tuple[str, str, str, int]:
        """What a row stands for: a new run with the same key replaces it."""
        return self.preset, self.device, self.device_name, self.batch_size

    @property
    def steady_wait(self) -> float:
        return max(self.steady_data_wait_share or 0.0, 0.0)

    def cells(self, rate: str) -> str:
        """The cells the page and the block share, preset to steady / ceiling; samples/s in the format `rate`
        (the page: as recorded, "", the block: rounded, ".0f")."""
        steady = NOT_MEASURED if self.steady_samples_per_s is None else (
            f"{self.steady_samples_per_s:{rate}} ({100 * self.steady_wait:.0f} %)")
        share = self.steady_share_of_ceiling
        return (f"{self.preset} | {self.device}: {self.device_name}, {self.cpus} CPUs | {self.batch_size}, "
                f"{self.learning_rate:g} | {self.bf16}, {self.channels_last} | {self.workers} | "
                f"{self.trainer_samples_per_s:{rate}} ({100 * self.trainer_data_wait_share:.0f} %) | {steady} | "
                f"{self.ceiling_samples_per_s:{rate}} | {100 * self.trainer_share_of_ceiling:.0f} % | "
                + (NOT_MEASURED if share is None else f"{100 * share:.0f} %"))


class TrainingResults(RecordList[TrainingRun]):
    """benchmarks/training_results.json: a row per `TrainingRun.key`."""

    ROW = TrainingRun

    def replacing(self, run: TrainingRun) -> TrainingResults:
        """These rows with `run` last, in place of the row of the same key."""
        return TrainingResults([kept for kept in self.rows if kept.key != run.key] + [run])

    def page(self) -> str:
        """benchmarks/training_results.md: every row with its load and command."""
        lines = ["# Training throughput: msfsu-train against the model-only ceiling", "",
                 "Whole run: the 2N-step run, its start included; steady state: the difference of the N- and the "
                 "2N-step runs. Its data wait is a difference of two runs too, shown as 0 where noise makes it "
                 "negative.", "",
                 "| preset | device | batch, lr | bf16, channels-last | workers | whole run: samples/s (data wait) | "
                 "steady state: samples/s (data wait) | model-only samples/s | whole run / ceiling | steady / ceiling | "
                 "load before / after | date, command |",
                 "| --- |" * 1 + " --- |" * 11]
        lines += [f"| {r.cells('')} | {r.load_before} / {r.load_after} | {r.date}: `{r.command}` |" for r in self.rows]
        return "\n".join(lines) + "\n"

    def block(self) -> str:
        """The docs' table: samples/s rounded, whole run and steady state against the ceiling, and N."""
        rows = ["| preset | device | batch, lr | bf16, channels-last | workers | whole run: samples/s (waiting for "
                "data) | steady state: samples/s (waiting for data) | model-only samples/s | whole run / ceiling | "
                "steady / ceiling | N steps |",
                "| --- | --- | --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]
        rows += [f"| {r.cells('.0f')} | {r.steps} |" for r in self.rows]
        return "\n".join(rows)

"""The network record (benchmarks/network.py -> benchmarks/network_results.json): parameters, FLOPs and release size
per preset and decoder layout, and torch's CPU latency per layout.

Rules:
- A latency is msfsu_common.benchmark_run.percentiles under the keys p50_ms, p90_ms, mean_ms and calls.
- The docs' table lists the paper preset first, then by decoder layout.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from typing import Any

from msfsu_evaluation.records._json import JsonRow

NETWORK_LABELS = {"paper": "MSFSU ResNet-50 V2 224 (`--preset paper`)",
                  "cpu": "MSFSU ResNet-18 V2 128 (`--preset cpu`)"}
LAYOUT_LABELS = {"v1": "v1: kernel 3 (paper)", "v2": "v2: kernel = stride (default)"}


@dataclass(kw_only=True)
class NetworkSize(JsonRow):
    """One preset with one decoder layout."""

    preset: str
    backbone: str
    input: str  # WxH
    decoder_layout: str
    decoder_filters: list[int]
    decoder_kernels: list[int]
    params_m: float
    decoder_params_m: float
    gflop: float  # per frame
    decoder_gflop: float
    release_mb: float  # the fp16 file msfsu-release-checkpoint writes

    def block_row(self) -> str:
        return (f"| {NETWORK_LABELS.get(self.preset, self.preset)} | "
                f"{LAYOUT_LABELS.get(self.decoder_layout, self.decoder_layout)} | {_listed(self.decoder_filters)} | "
                f"{self.params_m:.2f} M ({self.decoder_params_m:.2f} M) | {self.gflop:.2f} ({self.decoder_gflop:.2f}) "
                f"| {self.release_mb:.1f} MB |")


@dataclass(kw_only=True)
class NetworkLatency(JsonRow):
    """torch eager fp32, the layouts timed in alternating rounds."""

    threads: int
    rounds: int
    uptime_before: str  # `uptime`'s line: the load the timing ran under
    uptime_after: str
    presets: dict[str, dict[str, dict[str, float]]]  # preset -> timed part -> latency


@dataclass(kw_only=True)
class NetworkRecord:
    measured_at: str
    command: str
    torch: str
    size: list[NetworkSize]
    latency: NetworkLatency

    @classmethod
    def from_json(cls, text: str) -> NetworkRecord:
        fields: dict[str, Any] = json.loads(text)
        return cls(**{**fields, "size": [NetworkSize.from_dict(row) for row in fields["size"]],
                      "latency": NetworkLatency.from_dict(fields["latency"])})

    def to_json(self) -> str:
        return json.dumps(asdict(self), indent=1) + "\n"

    def page(self, release_limit_mb: float) -> str:
        """benchmarks/network_results.md (`release_limit_mb`: the most a shipped cpu-preset model may weigh)."""
        lines = [f"# Network size and torch CPU latency per decoder layout ({self.measured_at})", "",
                 f"`{self.command}`; torch {self.torch}, MSFSU variant, batch 1.", "",
                 f"Release: the fp16 file `msfsu-release-checkpoint` writes (a shipped cpu-preset model may weigh "
                 f"{release_limit_mb:.0f} MB).", "",
                 "| preset | backbone, input | decoder layout (kernels) | decoder filters | params | decoder params | "
                 "GFLOP/frame | decoder GFLOP | release MB |", "| --- |" + " --- |" * 8]
        lines += [f"| {r.preset} | {r.backbone}, {r.input} | {r.decoder_layout} ({_listed(r.decoder_kernels)}) | "
                  f"{_listed(r.decoder_filters)} | {r.params_m:.2f} M | {r.decoder_params_m:.2f} M | {r.gflop:.2f} | "
                  f"{r.decoder_gflop:.2f} | {r.release_mb:.1f} |" for r in self.size]
        timing = self.latency
        lines += ["", f"torch eager fp32, {timing.threads} thread(s), {timing.rounds} alternating rounds; "
                  "noisy: the machine is shared.", "", f"- before: `{timing.uptime_before}`",
                  f"- after: `{timing.uptime_after}`", "",
                  "| preset | decoder layout, timed part | p50 ms | p90 ms | mean ms | calls |",
                  "| --- | --- | --- | --- | --- | --- |"]
        lines += [f"| {preset} | {part} | {result['p50_ms']:.2f} | {result['p90_ms']:.2f} | {result['mean_ms']:.2f} | "
                  f"{result['calls']} |"
                  for preset, by_part in timing.presets.items() for part, result in by_part.items()]
        return "\n".join(lines) + "\n"

    def block(self) -> str:
        """The docs' table: size and FLOPs of each network and decoder layout, the paper's first."""
        ordered = sorted(self.size, key=lambda r: (r.preset != "paper", r.decoder_layout))
        return "\n".join(["| network | decoder | decoder filters | params (decoder) | GFLOP/frame (decoder) | release "
                          "(fp16) |", "| --- |" + " --- |" * 5, *(r.block_row() for r in ordered)])


def _listed(values: list[int]) -> str:
    return ", ".join(str(value) for value in values)

"""Write the README's measured figures from the committed result records (never typed by hand).

    python scripts/readme_results.py           # rewrite the marked blocks of README.md
    python scripts/readme_results.py --check   # exit 1 if README.md differs from the records (a test runs this)

A block is `<!-- results:NAME -->` ... `<!-- /results:NAME -->`; NAME picks the generator below, which reads
the JSON a benchmark wrote next to its markdown (`benchmarks/*_results.json`).
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"


def _load(name: str) -> Any:
    return json.loads((ROOT / "benchmarks" / name).read_text())


def simulator_speed() -> str:
    results = {r["mode"]: r for r in _load("simulator_results.json")}
    stock = results.get("stock")
    rows = ["| mode (what renders) | steps/s | vs MetaDrive's passes | reset: same town / other town / new engine |",
            "| --- | --- | --- | --- |"]
    what = {"stock": "MetaDrive's own passes (before)", "collection": "`collection`: RGB+depth pass, semantic pass",
            "evaluation": "`evaluation`: one RGB+depth pass"}
    for mode, result in results.items():
        ratio = f"{result['steps_per_s'] / stock['steps_per_s']:.1f}x" if stock else "-"
        reset = result["reset_s"]
        rows.append(f"| {what.get(mode, mode)} | {result['steps_per_s']} | {ratio} | "
                    f"{reset['same town']} s / {reset['other town']} s / {reset['new engine']} s |")
    return "\n".join(rows)


def lockstep_speed() -> str:
    rows = ["| route (traffic) | simulator alone, frames/s | network through the graph, frames/s | "
            "graph round trip p50 ms |", "| --- | --- | --- | --- |"]
    for result in _load("lockstep_results.json"):
        trip = result["graph"].get("round trip ms", {}).get("p50", "-")
        rows.append(f"| {result['route']} ({result['traffic']}) | {result['expert_in_process']['frames_per_s']} | "
                    f"{result['graph']['frames_per_s']} | {trip} |")
    return "\n".join(rows)


def benchmark_workers() -> str:
    results = _load("workers_results.json")
    one = next((r for r in results if r["workers"] == 1), results[0])
    rows = ["| workers | episodes/h | speed-up | mean wall s per episode (expert / network) | simulator process "
            "peak RSS GB | load (1 min) after |", "| --- | --- | --- | --- | --- | --- |"]
    for r in results:
        agents = r["agents"]
        rows.append(f"| {r['workers']} | {r['episodes_per_hour']} | {r['episodes_per_hour'] / one['episodes_per_hour']:.2f}x | "
                    f"{agents['expert']['mean_wall_s']} / {agents['network']['mean_wall_s']} | {r['worker_peak_rss_gb']} | "
                    f"{r['load_1min_after']} |")
    return "\n".join(rows)


def network_size() -> str:
    network = {"paper": "MSFSU ResNet-50 V2 224 (`--preset paper`)", "cpu": "MSFSU ResNet-18 V2 128 (`--preset cpu`)"}
    layout = {"v1": "v1: kernel 3 (paper; shipped models)", "v2": "v2: kernel = stride (new default)"}
    rows = ["| network | decoder | params (decoder) | GFLOP/frame (decoder) |", "| --- | --- | --- | --- |"]
    for r in sorted(_load("network_results.json")["size"], key=lambda r: (r["preset"] != "paper", r["decoder_layout"])):
        rows.append(f"| {network.get(r['preset'], r['preset'])} | {layout.get(r['decoder_layout'], r['decoder_layout'])} | "
                    f"{r['params_m']:.2f} M ({r['decoder_params_m']:.2f} M) | {r['gflop']:.2f} ({r['decoder_gflop']:.2f}) |")
    return "\n".join(rows)


GENERATORS: dict[str, Callable[[], str]] = {"simulator-speed": simulator_speed, "lockstep-speed": lockstep_speed,
                                            "benchmark-workers": benchmark_workers, "network-size": network_size}
BLOCK = re.compile(r"(<!-- results:(?P<name>[\w-]+) -->\n)(?P<body>.*?)(<!-- /results:(?P=name) -->)", re.S)


def render(text: str) -> str:
    def replace(match: re.Match) -> str:
        name = match.group("name")
        if name not in GENERATORS:
            raise KeyError(f"README block '{name}' has no generator (known: {', '.join(GENERATORS)})")
        return f"{match.group(1)}{GENERATORS[name]()}\n{match.group(4)}"

    return BLOCK.sub(replace, text)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="compare only; exit 1 when README.md is stale")
    args = parser.parse_args(argv)
    text = README.read_text()
    updated = render(text)
    if args.check:
        if updated != text:
            print("README.md is stale: run python scripts/readme_results.py", file=sys.stderr)
            return 1
        return 0
    README.write_text(updated)
    return 0


if __name__ == "__main__":
    sys.exit(main())

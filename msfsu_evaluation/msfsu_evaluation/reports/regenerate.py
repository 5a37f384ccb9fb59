"""Rewrite every committed closed-loop report from the records its own results.json names.

    msfsu-regenerate-reports               # every report
    msfsu-regenerate-reports --run-pages   # only the run directories' own pages

After a change to msfsu-benchmark-report: the pages of docs/results/ (each folder holding a results.json: the report
pages, and the page msfsu-benchmark wrote into each run directory under records/) are made again, with the same
runs, agents and --prefer as before. tests/test_results_docs.py checks that nothing is left stale.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from msfsu_evaluation.closed_loop import report
from msfsu_evaluation.closed_loop.runs import REPOSITORY

RESULTS = REPOSITORY / "docs" / "results"


def run_pages() -> list[Path]:
    """The run directories holding the page msfsu-benchmark wrote at their end (records/.../<run>/results.json)."""
    return sorted(page.parent for page in RESULTS.glob("**/records/**/results.json"))


def report_directories() -> list[Path]:
    """Every committed report: each folder of docs/results/ holding a results.json (the report pages beside their
    records/, those made from other folders' records, and the run directories' own pages, however deep)."""
    return sorted({page.parent for page in RESULTS.glob("**/results.json")})


def arguments(docs: Path, out: Path | None = None) -> list[str]:
    """The msfsu-benchmark-report arguments that made `docs` (read from its results.json), out into `out` (default:
    `docs` itself)."""
    committed = json.loads((docs / "results.json").read_text())
    prefer = [f"{agent}={REPOSITORY / run}" for agent, run in committed.get("prefer", {}).items()]
    return [*(str(REPOSITORY / run) for run in committed["records"]), "--agents", *committed["agents"],
            *(["--prefer", *prefer] if prefer else []), "--out", str(out or docs)]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="msfsu-regenerate-reports", description=__doc__.splitlines()[0])
    parser.add_argument("--run-pages", action="store_true",
                        help="only the run directories' own pages (scripts/results.sh writes the reports above them)")
    options = parser.parse_args(argv)
    for docs in run_pages() if options.run_pages else report_directories():
        if report.main(arguments(docs)) != 0:
            return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())

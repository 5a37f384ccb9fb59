"""Rewrite every committed closed-loop report from the records its own results.json names.

    python scripts/regenerate_reports.py

After a change to msfsu-benchmark-report: the pages of docs/results/ (each report directory with a records/ folder,
and the page msfsu-benchmark wrote into each run directory, records/<run>/results.md) are made again, with the same
runs, agents and --prefer as before. tests/test_results_docs.py checks that nothing is left stale.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from msfsu_evaluation.closed_loop import report

REPOSITORY = Path(__file__).resolve().parents[1]
RESULTS = REPOSITORY / "docs" / "results"


def report_directories() -> list[Path]:
    """Every committed report: the parents of records/ folders and the run directories holding a results.json."""
    return sorted({records.parent for records in RESULTS.glob("**/records")}
                  | {page.parent for page in RESULTS.glob("**/records/*/results.json")})


def arguments(docs: Path) -> list[str]:
    """The msfsu-benchmark-report arguments that made `docs` (read from its results.json), out into `docs`."""
    committed = json.loads((docs / "results.json").read_text())
    prefer = [f"{agent}={REPOSITORY / run}" for agent, run in committed.get("prefer", {}).items()]
    return [*(str(REPOSITORY / run) for run in committed["records"]), "--agents", *committed["agents"],
            *(["--prefer", *prefer] if prefer else []), "--out", str(docs)]


def main() -> int:
    for docs in report_directories():
        if report.main(arguments(docs)) != 0:
            return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""The committed closed-loop reports are exactly what msfsu-benchmark-report makes of the committed records.

Each report names the run directories it was made from and its agents (results.json: "records", "agents"): the
free-running report, for one, pairs its own records with the lockstep records of docs/results/closed_loop/."""

import json
from pathlib import Path

import pytest

from msfsu_evaluation.closed_loop import report

RESULTS = Path(__file__).resolve().parents[1] / "docs" / "results"
REPORTS = sorted(records.parent for records in RESULTS.glob("**/records"))  # closed_loop/, dagger/, free_running/ ...
# and the page msfsu-benchmark writes into each run directory at its end (records/<run>/results.md)
REPORTS += sorted(page.parent for page in RESULTS.glob("**/records/*/results.json"))
REPOSITORY = RESULTS.parents[1]


def test_the_closed_loop_report_has_records():
    assert RESULTS / "closed_loop" in REPORTS, "no committed closed-loop records"


@pytest.mark.parametrize("docs", REPORTS, ids=[str(path.relative_to(RESULTS)) for path in REPORTS])
def test_report_is_what_the_committed_records_give(tmp_path, docs):
    committed = json.loads((docs / "results.json").read_text())
    runs = [REPOSITORY / run for run in committed["records"]]
    assert all(run.is_relative_to(RESULTS) for run in runs), committed["records"]  # committed records only
    prefer = [f"{agent}={REPOSITORY / run}" for agent, run in committed.get("prefer", {}).items()]
    assert report.main([*map(str, runs), "--agents", *committed["agents"], *(["--prefer", *prefer] if prefer else []),
                        "--out", str(tmp_path)]) == 0
    for name in ("results.md", "results.json"):
        assert (tmp_path / name).read_text() == (docs / name).read_text(), f"{name}: regenerate with scripts/results.sh"
    committed_figures = sorted(path.name for path in docs.glob("*.png"))
    assert committed_figures == sorted(path.name for path in tmp_path.glob("*.png"))

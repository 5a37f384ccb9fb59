"""Every committed lateral study page is its committed record rendered (`python -m msfsu_evaluation.lateral_study
--render DIR` rewrites it)."""

from pathlib import Path

import pytest

from msfsu_evaluation.records.lateral_study import PAGE_NAME, RECORD_NAME, LateralStudy

REPOSITORY = Path(__file__).resolve().parent.parent
RECORDS = sorted((REPOSITORY / "docs" / "results").rglob(RECORD_NAME))


def test_there_is_a_committed_lateral_study():
    assert RECORDS, f"no {RECORD_NAME} under docs/results"


@pytest.mark.parametrize("record", RECORDS, ids=lambda path: path.parent.relative_to(REPOSITORY).as_posix())
def test_the_page_is_the_record_rendered(record):
    study = LateralStudy.from_json(record.read_text())
    assert (record.parent / PAGE_NAME).read_text() == study.markdown(), (
        f"stale: python -m msfsu_evaluation.lateral_study --render {record.parent.relative_to(REPOSITORY)}")
    assert LateralStudy.from_json(study.to_json()) == study

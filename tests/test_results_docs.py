"""The committed closed-loop report is exactly what msfsu-benchmark-report makes of the committed records."""

from pathlib import Path

from msfsu_evaluation.closed_loop import report

DOCS = Path(__file__).resolve().parents[1] / "docs" / "results" / "closed_loop"


def test_closed_loop_report_is_what_the_committed_records_give(tmp_path):
    runs = sorted(path for path in (DOCS / "records").iterdir() if path.is_dir())
    assert runs, "no committed closed-loop records"
    assert report.main([*map(str, runs), "--out", str(tmp_path)]) == 0
    for name in ("results.md", "results.json"):
        assert (tmp_path / name).read_text() == (DOCS / name).read_text(), f"{name}: regenerate with scripts/results.sh"
    committed_figures = sorted(path.name for path in DOCS.glob("*.png"))
    assert committed_figures == sorted(path.name for path in tmp_path.glob("*.png"))

"""metrics.csv rows: a run resumed by a newer version keeps its old rows and gains the new columns."""

from msfsu_perception.reporting import append_csv_row, read_csv


def test_a_new_column_rewrites_the_header_once_and_keeps_the_old_rows(tmp_path):
    path = tmp_path / "metrics.csv"
    append_csv_row(path, {"epoch": 0, "loss": 1.5})
    append_csv_row(path, {"epoch": 1, "loss": 1.25, "first_batch_s": 0.5})  # written by a newer version
    append_csv_row(path, {"epoch": 2, "loss": 1.0, "first_batch_s": 0.25})
    assert read_csv(path) == [{"epoch": "0", "loss": "1.5", "first_batch_s": ""},
                              {"epoch": "1", "loss": "1.25", "first_batch_s": "0.5"},
                              {"epoch": "2", "loss": "1.0", "first_batch_s": "0.25"}]
    assert path.read_text().splitlines()[0] == "epoch,loss,first_batch_s"
    assert not list(tmp_path.glob(".*partial"))

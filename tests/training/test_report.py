"""The report's tables (jaxpose.training.report) say what holds for the run at hand."""

from jaxpose.training.report import ground_truth_free_table
from jaxpose.training.self_consistency import METRICS


def test_the_ground_truth_free_table_claims_nothing_measured_on_another_data_set():
    # Every run writes this table, a synthetic or rig run too: a finding of the Human3.6M study is not its own.
    consistency = {metric: {"per_camera": [10.0 * i, 20.0 * i], "overall": 15.0 * i} for i, metric in enumerate(METRICS, 1)}
    text = ground_truth_free_table(consistency, ("left", "right"))
    assert "Human3.6M" not in text
    assert "| left | 10.0 | 20.0 | 30.0 |" in text and "| all | 15.0 | 30.0 | 45.0 |" in text

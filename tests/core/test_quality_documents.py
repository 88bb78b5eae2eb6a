"""metrics.json carries what a technician judges by: quality and strength."""

from __future__ import annotations

import math

from amrst.results.documents import record_from_registration, result_documents
from amrst.review.strength import AXES


def test_metrics_hold_quality_and_strength(sample_run) -> None:
    metrics = result_documents(record_from_registration(sample_run.result)).metrics
    distance = metrics["quality"]["distance"]
    assert distance["median_m"] < 0.015
    assert distance["within_2cm_fraction"] > 0.5
    assert 0 < distance["overlap_fraction"] <= 1
    slices = metrics["quality"]["stem_slices"]
    assert [s["height_m"] for s in slices] == [0.3, 1.3, 3.0]
    assert all(isinstance(s["status"], str) for s in slices)
    assert set(metrics["strength"]) == set(AXES)
    assert all(0 <= v <= 1.01 for v in metrics["strength"].values())
    assert not any(math.isnan(v) for v in metrics["strength"].values())

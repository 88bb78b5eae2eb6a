"""One result layout for the CLI, the app and the benchmark.

transform.json, metrics.json and metrics.csv come from amrst.results.documents.result_documents;
files written before (no schema_version, by the CLI or the app) keep being read.
"""

from __future__ import annotations

import csv
import io as _stdio
import json
from pathlib import Path

import numpy as np

from amrst.results.documents import (
    RESULT_SCHEMA_VERSION,
    ResultRecord,
    record_from_registration,
    result_documents,
    upgrade_result,
)
from amrst.stages.metrics import truth_errors

DATA = Path(__file__).parent / "data"


def test_a_whole_run_and_a_run_of_pieces_share_one_layout(
    sample_run, sample_pair
) -> None:
    result = sample_run.result
    cli = result_documents(record_from_registration(result, sample_pair.T_true))
    # The app holds the pieces, not a RegistrationResult.
    src = sample_pair.source.world_xyz
    app = result_documents(
        ResultRecord(
            T_target_source=result.T_target_source,
            T_coarse=result.T_coarse,
            coarse=result.coarse,
            fine=result.fine,
            metrics_coarse=result.metrics_coarse.as_dict(),
            metrics_fine=result.metrics_fine.as_dict(),
            truth={
                "fine": truth_errors(result.T_target_source, sample_pair.T_true, src)
            },
            rejected_match_ids=(4, 2),
        )
    )
    assert set(cli.transform) == set(app.transform)
    for doc in (cli, app):
        assert doc.transform["schema_version"] == RESULT_SCHEMA_VERSION
        assert doc.metrics["schema_version"] == RESULT_SCHEMA_VERSION
        assert doc.transform["coarse_candidate"]["rank"] == result.coarse.candidate.rank
        assert doc.metrics["fine"]["method"] == result.fine.method
        assert doc.metrics["truth"]["fine"]["rotation_error_deg"] < 1.0
        assert doc.metrics["truth"]["registered"] is True
        assert not any(k.startswith("truth_") for k in doc.metrics["fine"])
    assert app.transform["rejected_match_ids"] == [2, 4]
    assert app.metrics["coarse"]["rejected_ids"] == [2, 4]
    rows = dict(csv.reader(_stdio.StringIO(cli.metrics_csv)))
    assert "truth.fine.gt_rmse_m" in rows
    assert "tree.merged.height_m" in rows
    T = np.loadtxt(_stdio.StringIO(cli.transform_txt))
    np.testing.assert_allclose(T, result.T_target_source, atol=1e-9)


def test_files_of_the_app_before_schema_2_are_read_in_the_new_layout() -> None:
    old_t = json.loads((DATA / "transform_v1_app.json").read_text())
    new_t = upgrade_result(old_t, "transform")
    assert new_t["schema_version"] == RESULT_SCHEMA_VERSION
    assert new_t["coarse_candidate"] == {"rank": 1, "origin": "tetrahedra"}
    assert new_t["fine"] == {"method": "point_to_plane", "converged": True}
    assert new_t["confidence"] == 0.8
    assert not {"coarse_match_rank", "fine_method"} & set(new_t)
    old_m = json.loads((DATA / "metrics_v1_app.json").read_text())
    new_m = upgrade_result(old_m, "metrics")
    assert new_m["truth"]["fine"] == {
        "rotation_error_deg": 0.05,
        "translation_error_m": 0.002,
        "gt_rmse_m": 0.003,
    }
    assert "truth_gt_rmse_m" not in new_m["coarse"]
    assert new_m["fine"]["iterations"] == 12


def test_a_campaign_reads_a_pair_trees_old_metrics_in_the_new_layout(
    tmp_path: Path,
) -> None:
    from amrst.campaign.stored import _pair_metrics

    old = (DATA / "metrics_v1_app.json").read_text()
    (tmp_path / "metrics.json").write_text(old)
    pair = _pair_metrics(tmp_path)
    assert pair is not None
    assert pair["schema_version"] == RESULT_SCHEMA_VERSION
    assert pair["truth"]["fine"]["gt_rmse_m"] == 0.003
    assert "truth_gt_rmse_m" not in pair["fine"]
    (tmp_path / "metrics.json").write_text('{"schema_version": "two"}')
    assert _pair_metrics(tmp_path) == {"schema_version": "two"}  # shown as it is
    (tmp_path / "metrics.json").unlink()
    assert _pair_metrics(tmp_path) is None


def test_files_of_the_cli_before_schema_2_keep_their_keys(sample_run) -> None:
    doc = result_documents(record_from_registration(sample_run.result)).transform
    old = {k: v for k, v in doc.items() if k not in ("schema_version", "stage")}
    new = upgrade_result(old, "transform")
    assert new["coarse_candidate"] == doc["coarse_candidate"]
    assert new["stage"] == "fine"

"""A registration from point pairs: the pairs' pose, verified, and never spoilt by Fine."""

from __future__ import annotations

import numpy as np
import pytest

from amrst.errors import InvalidInput
from amrst.params import RegistrationParams
from amrst.pipeline.manual import register_from_pairs
from amrst.stages.metrics import truth_errors
from amrst.types import local_transform


def _spread_pairs(sample_pair, n: int, noise_m: float = 0.0):
    """``n`` source points far apart and their true target counterparts (world)."""
    src = sample_pair.source.xyz + sample_pair.source.offset
    picked = [0]
    dmin = np.linalg.norm(src - src[0], axis=1)
    for _ in range(n - 1):
        picked.append(int(np.argmax(dmin)))
        dmin = np.minimum(dmin, np.linalg.norm(src - src[picked[-1]], axis=1))
    s = src[picked]
    T = sample_pair.T_true
    t = s @ T[:3, :3].T + T[:3, 3]
    rng = np.random.default_rng(0)
    return t + rng.normal(0, noise_m, t.shape), s


def test_six_pairs_register_the_sample(sample_pair) -> None:
    pairs = _spread_pairs(sample_pair, 6, noise_m=0.01)
    r = register_from_pairs(
        sample_pair.target, sample_pair.source, pairs, RegistrationParams()
    )
    T_true = local_transform(sample_pair.T_true, sample_pair.target, sample_pair.source)
    err = truth_errors(r.fine.T_target_source, T_true, r.source.xyz)
    assert err.rotation_error_deg < 0.5
    assert err.gt_rmse_m < 0.02
    assert r.coarse.candidate.origin.value == "manual"
    assert "6 point pairs" in r.coarse.candidate.explanation


def test_pairs_on_one_line_are_refused(sample_pair) -> None:
    t, s = _spread_pairs(sample_pair, 3)
    line = np.linspace(0, 1, 3)[:, None] * np.array([[1.0, 0.0, 0.0]])
    with pytest.raises(InvalidInput):
        register_from_pairs(
            sample_pair.target,
            sample_pair.source,
            (t[:1] + line, s[:1] + line),
            RegistrationParams(),
        )


def test_pairs_in_another_order_are_refused(sample_pair) -> None:
    t, s = _spread_pairs(sample_pair, 4)
    with pytest.raises(InvalidInput, match="same point in both scans"):
        register_from_pairs(
            sample_pair.target,
            sample_pair.source,
            (t, s[[1, 2, 3, 0]]),
            RegistrationParams(),
        )


def test_pairs_up_one_stem_warn_of_a_weak_turn(sample_pair, caplog) -> None:
    t, s = _spread_pairs(sample_pair, 2)
    up = np.array([[0.0, 0.0, 0.0], [0.02, 0.0, 3.0]])  # 2 cm apart across the ground
    with caplog.at_level("WARNING"):
        register_from_pairs(
            sample_pair.target,
            sample_pair.source,
            (t[:1] + up, s[:1] + up),
            RegistrationParams(),
            levelled=True,
        )
    assert "Weak turn" in caplog.text
    caplog.clear()
    with caplog.at_level("WARNING"):
        register_from_pairs(
            sample_pair.target,
            sample_pair.source,
            _spread_pairs(sample_pair, 6),
            RegistrationParams(),
        )
    assert "Weak turn" not in caplog.text

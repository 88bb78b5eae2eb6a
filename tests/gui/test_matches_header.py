"""The Matches header follows the candidate list: after a rejection or a new manual
pose it describes what Accept coarse would take now, not the result accepted before."""

from __future__ import annotations

import dataclasses

from amrst.types import local_transform


def _unverifiable(params):
    # Nothing verifies at 5 mm, nor a trunk heading at 1 mm: the best solution is
    # the trunk heading search's, and it fails.
    return dataclasses.replace(
        params,
        coarse=dataclasses.replace(params.coarse, tight_dist_m=0.005),
        trunk=dataclasses.replace(params.trunk, score_dist_m=0.001),
    )


def _verdict_line(win) -> str:
    return win.matches_panel.coarse_label.text().split("<br>")[0]


def test_header_follows_new_manual_poses_and_rejections(loaded_window, finish):
    win = loaded_window
    s = win.session
    s.set_params(_unverifiable(s.params))
    finish(s, win.actions.match.trigger, "matches_changed")
    finish(s, win.actions.accept_coarse.trigger, "coarse_accepted")
    assert s.accepted_coarse.candidate.origin == "trunk"
    # Accepted by hand though it does not verify: judged by its own evidence.
    assert _verdict_line(win).startswith("<b>Needs review</b>: Candidate 1 from the")
    assert "trunk heading search, which you accepted" in _verdict_line(win)

    # A new manual pose (5 cm off the truth) goes first: the header is about it now.
    T = local_transform(s.truth, s.cloud("target"), s.cloud("source"))
    T[:3, 3] += [0.05, 0.0, 0.0]
    finish(s, lambda: s.add_manual_pose(T, "typed"), "matches_changed")
    manual = s.matches[0]
    assert s.coarse.candidate.id == manual.id
    line = _verdict_line(win)
    assert "which you accepted" not in line
    assert "trunk heading search" not in line
    assert "Accept coarse now takes candidate #1 (your manual pose" in line

    # Accepted, the header is the result's verdict again.
    finish(s, win.actions.accept_coarse.trigger, "coarse_accepted")
    assert _verdict_line(win).startswith("<b>Needs review</b>: Your manual pose")

    # Rejected, it no longer speaks for the manual pose.
    s.reject_match(manual.id)
    line = _verdict_line(win)
    assert "Your manual pose" not in line
    assert "which you rejected" in line
    assert f"Accept coarse now takes candidate #{s.coarse.candidate.rank}" in line
    # One verdict: the Metrics dock and the status bar read the same, and Export
    # is not offered for a result the review left behind.
    assert "which you rejected" in s.verdict.reason
    assert win.status.message.text().endswith("candidates rejected. Needs review.")
    assert not win.actions.export.isEnabled()
    assert "out of date" in win.actions.export.toolTip()
    # Restored, the accepted result is the coarse solution again.
    s.restore_match(manual.id)
    assert _verdict_line(win).startswith("<b>Needs review</b>: Your manual pose")
    assert win.actions.export.isEnabled()

    # Every candidate rejected: the list's own verdict.
    for c in s.matches:
        s.reject_match(c.id)
    assert s.coarse is None
    assert "Every candidate is rejected" in _verdict_line(win)

"""Open a campaign in the app and switch between its trees; time both.

Usage (a campaign already run with ``amrst batch``; a display or Xvfb)::

    xvfb-run -s "-screen 0 1920x1080x24" python docs/bench/campaign_gui/bench_campaign_gui.py CAMPAIGN [OUT.json]

Open: ``CampaignPanel.open_campaign`` (manifest and every tree's result files read).
Switch: from selecting a tree's row until the window is idle again with its scans and
stored result shown (the load job done, every queued event handled, views drawn).
Baselines in the same run: right after each switch, the same two scans loaded alone
(what selecting a tree did before its stored result was shown; back to back, so both
see the same machine load), and three trees registered from scratch in the window
(load + Run all: what showing a result costs without the stored one).
"""

from __future__ import annotations

import json
import os
import statistics
import sys
import time

os.environ.setdefault("QT_API", "pyside6")
ROUNDS = 3


def _idle(app, session, timeout_s: float = 120.0) -> None:
    end = time.perf_counter() + timeout_s
    while time.perf_counter() < end:
        app.processEvents()
        if not session.busy:
            break
        time.sleep(0.002)
    for _ in range(5):  # the signals of the applied result, the views' redraws
        app.processEvents()


def _stats(values: list[float]) -> dict[str, float]:
    values = sorted(values)
    return {
        "median": statistics.median(values),
        "p90": values[int(0.9 * (len(values) - 1))],
        "max": values[-1],
    }


def main() -> int:
    from amrst_gui.app import configure_qt, create_app

    configure_qt()
    app = create_app(sys.argv[:1])
    from amrst_gui.main_window import MainWindow

    root = sys.argv[1]
    out = sys.argv[2] if len(sys.argv) > 2 else None
    win = MainWindow()
    win.session.discard_guard = None
    win.resize(1920, 1080)
    win.show()
    win.docks["campaign"].raise_()
    app.processEvents()
    panel, session = win.campaign_panel, win.session
    t0 = time.perf_counter()
    assert panel.open_campaign(root)
    app.processEvents()
    open_s = time.perf_counter() - t0
    ids = [r["tree_id"] for r in panel.rows]
    steps: list[str] = []
    session.step_started.connect(steps.append)
    for tree in ids:  # a first round: files in the page cache, as in use
        panel.select_tree(tree)
        _idle(app, session)
    switch: dict[str, list[float]] = {t: [] for t in ids}
    scans_only: dict[str, list[float]] = {t: [] for t in ids}
    for _round in range(ROUNDS):
        for tree in ids:
            panel.table.clearSelection()
            t0 = time.perf_counter()
            panel.select_tree(tree)
            _idle(app, session)
            switch[tree].append(time.perf_counter() - t0)
            assert session.stored is not None, tree
            entry = panel.campaign.tree(tree)
            paths = [panel.campaign.root / s for s in entry.scans]
            other = next(k for k in range(len(paths)) if k != entry.reference)
            t0 = time.perf_counter()
            session.load_scans(paths[entry.reference], paths[other])
            _idle(app, session)
            scans_only[tree].append(time.perf_counter() - t0)
    assert set(steps) == {"load"}, steps  # nothing but loading ran
    baseline: dict[str, float] = {}
    for tree in ids[:3]:
        panel.table.clearSelection()
        panel.select_tree(tree)
        _idle(app, session)
        t0 = time.perf_counter()
        session.load_scans(session.path("target"), session.path("source"))
        _idle(app, session)
        session.run_all()
        _idle(app, session, 600)
        baseline[tree] = time.perf_counter() - t0
    every = [v for vs in switch.values() for v in vs]
    best = [min(vs) for vs in switch.values()]
    every_scans = [v for vs in scans_only.values() for v in vs]
    ratios = [a / b for t in ids for a, b in zip(switch[t], scans_only[t], strict=True)]
    doc = {
        "campaign": root,
        "trees": len(ids),
        "rounds": ROUNDS,
        "open_s": open_s,
        "switch_s": _stats(every),
        "switch_best_of_rounds_s": _stats(best),
        "scans_only_s": _stats(every_scans),
        "ratio_switch_over_scans_only_median": statistics.median(ratios),
        "register_from_scratch_s": baseline,
        "ratio_register_over_switch_median": statistics.median(baseline.values())
        / statistics.median(every),
        "load": os.getloadavg(),
        "switch_by_tree_s": switch,
    }
    print(
        json.dumps({k: v for k, v in doc.items() if k != "switch_by_tree_s"}, indent=1)
    )
    if out:
        with open(out, "w", encoding="utf-8") as f:
            json.dump(doc, f, indent=1)
    win.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())

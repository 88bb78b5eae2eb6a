"""The window opens on real scans, shows them, and keeps its layout."""

from __future__ import annotations

DOCKS = ("scans_dock", "parameters_dock", "matches_dock", "metrics_dock", "log_dock")


def test_opens_with_both_scans_drawn(loaded_window, content_fraction):
    win = loaded_window
    assert {d.objectName() for d in win.docks.values()} == set(DOCKS)
    assert win.toolbar.objectName() == "workflow_toolbar"
    for role, view in zip(("target", "source"), win.scans_area.views(), strict=True):
        assert "points" in view.actor_names()
        assert len(view.scene.layers[0].xyz) == len(win.session.cloud(role))
        # The interactor really drew the tree: not just background.
        assert content_fraction(view.plotter) > 0.005, role
    assert "Load scans: finished" in win.log_panel.plain_text()
    assert (
        win.scans_panel.boxes["target"].points.text()
        == f"{len(win.session.cloud('target')):,}"
    )


def test_update_scene_twice_changes_nothing(loaded_window):
    view = loaded_window.scans_area.views()[0]
    actors = dict(view.plotter.actors)
    pane = loaded_window.scans_area.panes["target"]
    pane.refresh()
    pane.refresh()
    assert dict(view.plotter.actors) == actors


def test_layer_toggle_removes_and_restores_actor(loaded_window):
    pane = loaded_window.scans_area.panes["source"]
    pane.toggles["show_points"].setChecked(False)
    assert "points" not in pane.view.actor_names()
    pane.toggles["show_points"].setChecked(True)
    assert "points" in pane.view.actor_names()


def test_layout_and_recent_files_are_remembered(make_main_window, qtbot, sample_pair):
    target, source, _ = sample_pair
    win = make_main_window()
    with qtbot.waitSignals([win.session.scan_loaded] * 2, timeout=20_000):
        win.open_pair(target, source)
    win.docks["log"].setFloating(True)
    win.close()
    again = make_main_window()
    assert again.docks["log"].isFloating()
    assert again.recent_files()[:2] == [str(source), str(target)]
    assert not again.scans_panel.boxes["target"].recent_menu.isEmpty()

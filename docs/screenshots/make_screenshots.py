"""Take one screenshot per workflow step from the running app, for the docs.

    xvfb-run -a -s "-screen 0 1600x1000x24" env QT_QPA_PLATFORM=xcb \
        LIBGL_ALWAYS_SOFTWARE=1 .venv/bin/python docs/screenshots/make_screenshots.py

Drives the real MainWindow on the bundled sample pair, then the Plot window on the
README's plot made from it; the PNGs land next to this script. Settings go to a
temporary folder, so the layout is the default one.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent


def main() -> int:
    from amrst_gui.app import create_app, sample_dir

    app = create_app(sys.argv[:1])
    from PySide6.QtCore import QEventLoop, QSettings, QTimer

    from amrst_gui.main_window import MainWindow

    settings_dir = tempfile.mkdtemp(prefix="amrst-shots-")
    QSettings.setPath(QSettings.IniFormat, QSettings.UserScope, settings_dir)
    win = MainWindow()
    win.resize(1500, 950)
    win.show()
    s = win.session
    failures: list[str] = []
    s.failed.connect(failures.append)

    def settle(ms: int = 400) -> None:
        loop = QEventLoop()
        QTimer.singleShot(ms, loop.quit)
        loop.exec()

    def run(start) -> None:
        loop = QEventLoop()
        s.busy_changed.connect(lambda busy: None if busy else loop.quit())
        QTimer.singleShot(120_000, loop.quit)
        start()
        if s.busy:
            loop.exec()
        if failures:
            raise SystemExit(f"failed: {failures}")
        settle()

    def shot(name: str, tab: int = 0) -> None:
        win.tabs.setCurrentIndex(tab)
        settle()
        path = HERE / f"{name}.png"
        win.grab().save(str(path))
        print(f"saved {path}")

    sample = sample_dir()
    run(lambda: s.load_scans(sample / "target.ply", sample / "source.ply"))
    win.session.load_truth(sample / "truth.json")  # after: it belongs to these scans
    shot("01-loaded")
    run(lambda: win.actions.separate.trigger())
    shot("02-separated")
    run(lambda: win.actions.skeleton.trigger())
    shot("03-skeleton-keypoints")
    run(lambda: win.actions.match.trigger())
    win.scans_area.frame_match()
    shot("04-matches")
    # Review: reject the best match; the coarse solution moves to the next one.
    win.matches_panel.table.setFocus()
    win.actions.reject.trigger()
    win.matches_panel.table.selectRow(1)
    win.scans_area.frame_match()
    shot("05-review-rejected")
    run(lambda: win.actions.accept_coarse.trigger())
    shot("06-coarse-overlay", tab=1)
    run(lambda: win.actions.run_fine.trigger())
    shot("07-fine-overlay", tab=1)
    win.metrics_panel.tabs.setCurrentIndex(1)  # the Tree tab
    shot("12-tree-measures", tab=1)
    win.metrics_panel.tabs.setCurrentIndex(0)
    win.registration.colour.setCurrentIndex(1)  # colour by distance
    settle(1500)
    shot("11-distance", tab=1)
    win.registration.colour.setCurrentIndex(0)
    win.tabs.setCurrentIndex(2)  # the stem slices are cut when the tab is shown
    settle(1500)
    shot("13-stem-slices", tab=2)
    win.docks["parameters"].raise_()
    shot("08-parameters", tab=1)
    win.docks["scans"].raise_()
    box = win.export_dialog()
    box.folder_edit.setText(str(Path(settings_dir) / "export"))
    settle()
    path = HERE / "09-export-dialog.png"
    box.grab().save(str(path))
    print(f"saved {path}")
    box.accept()
    run(lambda: None)
    shot("10-exported", tab=1)
    plot_shot(win, sample, Path(settings_dir), settle)
    win.close()
    app.processEvents()
    return 0


def plot_shot(win, sample: Path, work: Path, settle) -> None:
    """The Plot window at 1366x768 on the README's plot: simulated from the sample
    (four trees, three positions), run with ``amrst plot``, its results opened."""
    import subprocess

    amrst = [sys.executable, "-m", "amrst.cli"]
    scans = [str(sample / n) for n in ("target.ply", "source.ply")] * 2
    made = work / "my_plot"
    options = ["--trees", "4", "--positions", "3", "--seed", "1", "--out", str(made)]
    subprocess.run([*amrst, "simulate", "--plot", *scans, *options], check=True)
    results = work / "results"
    files = [str(made / f"scan_{k}.ply") for k in (1, 2, 3)]
    subprocess.run([*amrst, "plot", *files, "--out", str(results)], check=True)
    plot = win.open_plot_results(results)
    plot.resize(1366, 768)
    while plot.outcome is None:
        settle(200)
    plot.select_tree(0)
    settle()
    path = HERE / "14-plot.png"
    plot.grab().save(str(path))
    print(f"saved {path}")
    plot.close()


if __name__ == "__main__":
    sys.exit(main())

"""``amrst-gui [TARGET SOURCE] [--truth FILE]``: open AMRST Studio.

With no files it opens the bundled sample pair (resources/sample), ready to run.
``--campaign DIR [--tree ID]`` opens a campaign in the Campaign dock instead and shows
one tree (default: the first listed) from its stored result.
``--plot SCAN SCAN [SCAN ...] [--out DIR]`` opens a forest plot's scans in the Plot
window (the first is the reference; DIR: its results folder); ``--run all`` runs it.
``--plot-results DIR`` shows the plot a results folder holds, without running it.
``--screenshot PATH`` saves the window once the scans are shown (after ``--run
STEP`` if given) and quits: used for the README and for checking headless runs.
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
from pathlib import Path

os.environ.setdefault("QT_API", "pyside6")


def _steps() -> tuple[str, ...]:
    from amrst.pipeline.steps import STEP_NAMES  # the step table

    return STEP_NAMES


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    from amrst.io.scans import names_several

    parser = argparse.ArgumentParser(
        prog="amrst-gui", description=__doc__.split("\n")[0]
    )
    parser.add_argument(
        "target", nargs="?", type=Path, help="reference scan (stays fixed)"
    )
    parser.add_argument(
        "source", nargs="?", type=Path, help="scan to move onto the target"
    )
    parser.add_argument("--truth", type=Path, help="truth.json with T_target_source")
    parser.add_argument(
        "--screenshot",
        type=Path,
        metavar="PNG",
        help="save the window to PNG once ready, then quit",
    )
    parser.add_argument(
        "--run",
        choices=(*_steps(), "all"),
        help="run the workflow up to this step first (all: Run all, which stops "
        "before an unverified candidate)",
    )
    parser.add_argument(
        "--tab",
        choices=("scans", "registration", "slices", "distance"),
        default="scans",
        help="which 3D tab to show (for --screenshot)",
    )
    parser.add_argument(
        "--campaign",
        type=Path,
        metavar="DIR",
        help="open this campaign folder in the Campaign dock (instead of scans)",
    )
    parser.add_argument(
        "--tree", metavar="ID", help="with --campaign: the tree to show first"
    )
    parser.add_argument(
        "--plot",
        nargs="+",
        type=Path,
        metavar="SCAN",
        help="open a forest plot's scans in the Plot window (the first is the "
        "reference)",
    )
    parser.add_argument(
        "--plot-results",
        type=Path,
        metavar="DIR",
        help="show the plot a results folder holds (amrst plot --out DIR) in the "
        "Plot window, without running it",
    )
    parser.add_argument(
        "--out",
        type=Path,
        metavar="DIR",
        help="with --plot: the results folder (--run all writes the plot there)",
    )
    parser.add_argument(
        "--size",
        metavar="WxH",
        help="window size for --screenshot, e.g. 1366x768 (default: fit the screen)",
    )
    args = parser.parse_args(argv)
    if args.plot is not None and args.plot_results is not None:
        parser.error("give --plot SCANS or --plot-results DIR, not both")
    if args.plot_results is not None and args.run is not None:
        parser.error("--plot-results shows a plot as written: give no --run")
    if args.plot is not None and len(args.plot) < 2 and not names_several(args.plot[0]):
        parser.error(
            "--plot needs two or more scans (the first is the reference), or one "
            "E57 or PTX file that holds them"
        )
    if args.plot is not None and args.run is not None and args.out is None:
        parser.error("--plot with --run needs --out DIR: where the plot is written")
    if (args.target is None) != (args.source is None):
        parser.error(
            "give both TARGET and SOURCE, or neither (to open the bundled sample)"
        )
    return args


def resolve_inputs(
    args: argparse.Namespace,
) -> tuple[Path | None, Path | None, Path | None]:
    """The files to open: the ones given, else the bundled sample (with its truth)."""
    from amrst_gui.app import sample_dir

    if args.target is not None:
        return args.target, args.source, args.truth
    sample = sample_dir()
    target, source, truth = (
        sample / n for n in ("target.ply", "source.ply", "truth.json")
    )
    if not (target.is_file() and source.is_file()):
        return None, None, args.truth
    return target, source, args.truth or (truth if truth.is_file() else None)


class _Screenshot:
    """Runs to the requested step, grabs the window, quits (exit code 1 on failure)."""

    def __init__(self, app, win, path: Path, step: str | None, tab: str) -> None:
        self.app, self.win, self.path, self.step, self.tab = app, win, path, step, tab
        self.ran = False
        win.session.discard_guard = None  # nobody to ask: it closes on its own
        win.session.busy_changed.connect(self._on_busy_changed)
        win.session.failed.connect(self._on_failed)

    def _on_busy_changed(self, busy: bool) -> None:
        from PySide6.QtCore import QTimer

        if busy or not self.win.session.has_scans:
            return
        if self.step and not self.ran:
            self.ran = True
            if self.step == "all":
                self.win.session.run_all()
            else:
                self.win.session.run_step(self.step)
            return
        QTimer.singleShot(0, self._after_results)

    def _after_results(self) -> None:
        from amrst_gui.pacing import DRAWS

        # The window switches to the overlay in the draws' queue: the requested tab
        # takes the turn after.
        DRAWS.later(self.win, "requested tab", self._show_tab)

    def _show_tab(self) -> None:
        from PySide6.QtCore import QTimer

        tab = {"registration": 1, "distance": 1, "slices": 2}.get(self.tab, 0)
        self.win.tabs.setCurrentIndex(tab)
        if self.tab == "distance":
            self.win.registration.colour.setCurrentIndex(1)
        QTimer.singleShot(500, self._save)  # the tab's views drawn

    def _save(self) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.win.grab().save(str(self.path))
        print(f"Saved {self.path}")
        self.win.close()
        self.app.exit(0)

    def _on_failed(self, message: str) -> None:
        # A failed verdict is worth a picture too: save, then quit.
        print(f"amrst-gui: {message}", file=sys.stderr)
        self.ran = True


def _open_campaign(win, folder: Path, tree: str | None) -> bool:
    """Open a campaign in the Campaign dock and select a tree; False after a message."""
    panel = win.campaign_panel
    if not panel.open_campaign(folder):
        print(f"amrst-gui: {panel.status.text()}", file=sys.stderr)
        return False
    win.docks["campaign"].raise_()
    ids = [r["tree_id"] for r in panel.rows]
    if tree is not None and tree not in ids:
        print(
            f"amrst-gui: no tree {tree!r} in {folder}; choose one of: "
            + ", ".join(ids),
            file=sys.stderr,
        )
        return False
    if ids:
        panel.select_tree(tree or ids[0])
    return True


def _open_plot(app, win, args: argparse.Namespace) -> None:
    """Open the plot's scans (or results) in the Plot window; run it and save a
    screenshot if asked (after the run or the opening, or at once), then quit."""
    from PySide6.QtCore import QTimer

    if args.plot_results is not None:
        plot = win.open_plot_results(args.plot_results)
    else:
        plot = win.open_plot(list(args.plot), args.out)
    if args.size:
        w, _x, h = args.size.partition("x")
        plot.resize(int(w), int(h))

    def save() -> None:
        from amrst_gui.pacing import DRAWS

        if plot.outcome is not None and plot.outcome.trees:
            plot.select_tree(0)  # a tree's figures and slice in the picture
        # Grabbed in a later turn, once the tree panel's rows are laid out again.
        DRAWS.later(plot, "screenshot", grab)

    def grab() -> None:
        args.screenshot.parent.mkdir(parents=True, exist_ok=True)
        plot.grab().save(str(args.screenshot))
        print(f"Saved {args.screenshot}")
        win.close()
        app.exit(0)

    if args.run is not None:
        plot.run()  # once the scans of a file of several are listed

    def settle() -> None:
        """Save once no job runs: the listing of the scans may start the run."""
        if plot.job is not None:
            plot.job.finished.connect(lambda: QTimer.singleShot(300, settle))
        else:
            save()

    if args.screenshot is not None:
        QTimer.singleShot(500, settle)


def _missing_extra() -> str | None:
    """One line naming the extra to install if the app's libraries are missing."""
    from amrst.extras import MissingExtra, require

    try:
        for module in ("PySide6", "pyvista", "pyvistaqt", "superqt"):
            require(module, "the app")
    except MissingExtra as exc:
        return str(exc)
    return None


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``amrst-gui``."""
    args = parse_args(sys.argv[1:] if argv is None else argv)
    missing = _missing_extra()
    if missing is not None:
        print(f"amrst-gui: {missing}", file=sys.stderr)
        return 2
    logging.basicConfig(
        level=logging.INFO, format="%(levelname)s %(name)s: %(message)s"
    )
    from amrst_gui.app import create_app

    app = create_app(sys.argv[:1])
    from amrst_gui.main_window import MainWindow

    win = MainWindow()
    if args.size:
        w, _x, h = args.size.partition("x")
        win.resize(int(w), int(h))
    win.show()
    target, source, truth = resolve_inputs(args)
    shot = (
        _Screenshot(app, win, args.screenshot, args.run, args.tab)
        if args.screenshot and args.plot is None and args.plot_results is None
        else None
    )
    if args.plot is not None or args.plot_results is not None:
        _open_plot(app, win, args)
    elif args.campaign is not None:
        if not _open_campaign(win, args.campaign, args.tree):
            return 2
    elif target is None:
        win.status.show_message(
            "No scans yet: open a target and a source (File menu), "
            "or drop two files on the window."
        )
        if shot is not None:
            print(
                "amrst-gui: the bundled sample is missing; nothing to show.",
                file=sys.stderr,
            )
            return 1
    else:
        win.open_pair(target, source, truth)
    return app.exec()


if __name__ == "__main__":
    sys.exit(main())

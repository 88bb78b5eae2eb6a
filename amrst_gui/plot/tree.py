"""The Plot window's tree view: one tree's figures, its stem slices, its side view,
its mark, and the technician's own DBH.

The slice shown is chosen by height (``amrst.plot.view.SLICE_HEIGHTS_M``; breast height
first), or the whole tree from the side (**Side**), and the choice holds from one tree
to the next.

Emits ``mark_chosen(tree id, mark)`` with mark ``ok``, ``check``, ``not a tree`` or
``""`` (clear), and
``dbh_chosen(tree id, circle)`` with the technician's ``HandCircle`` at breast height
(None: forget it).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from PySide6.QtCore import Signal
from PySide6.QtGui import QKeySequence
from PySide6.QtWidgets import (
    QButtonGroup,
    QFormLayout,
    QHBoxLayout,
    QLabel,
    QPushButton,
    QStackedWidget,
    QVBoxLayout,
    QWidget,
)

from amrst.plot.diameter import BREAST_HEIGHT_M
from amrst.plot.flags import DBH_OK, HEIGHT_FLAGS, OUTLIER_SHARE, height_words
from amrst.plot.review import NOT_A_TREE, PlotReview
from amrst.plot.view import SLICE_HEIGHTS_M
from amrst_gui.plot.stem_map import scan_colour
from amrst_gui.plot.tree_side import TreeSideView
from amrst_gui.plot.tree_slice import TreeSliceView

if TYPE_CHECKING:
    from collections.abc import Collection

    from amrst.plot.inventory import Tree
    from amrst_gui.plot.jobs import PlotOutcome

#: The id of the Side button among the slice heights' (their indices).
SIDE = len(SLICE_HEIGHTS_M)
#: The rows of the tree's figures.
FIGURES = (
    "Position",
    "Height",
    "DBH",
    "DBH fit",
    "Lean",
    "Crown",
    "Points",
    "Seen from",
    "Your mark",
)

FIGURE_TIPS = {
    "Position": "The stem base, in the reference scan's frame (world coordinates "
    "when the files carry an offset), as trees.csv lists it",
    "DBH fit": "The DBH circle's fit: the arc of the stem its points cover, their "
    f"residual, and {OUTLIER_SHARE} (3DFin's checks); ok: {DBH_OK}",
    "Height": "The tree's highest point above the ground at its stem (the Side view "
    "shows it); " + "; ".join(f"{flag}: {text}" for flag, text in HEIGHT_FLAGS.items()),
    "Seen from": "The scans with points on the tree 0.3-2.5 m above its foot; where "
    "one of them needs "
    "review, the tree's figures rest on a pose nobody confirmed yet",
    "DBH": "The DBH the plot measured (its quality), and yours where you measured it",
}


def _value(value: object, unit: str = "", scale: float = 1.0, digits: int = 2) -> str:
    if isinstance(value, str) or value is None:
        return "–"
    number = float(value) * scale  # type: ignore[arg-type]
    return "–" if not np.isfinite(number) else f"{number:.{digits}f}{unit}"


def _narrow(button: QPushButton) -> QPushButton:
    """The button as wide as its text (a style's minimum width would push the stem
    map aside at 1366 px)."""
    button.setMaximumWidth(button.fontMetrics().horizontalAdvance(button.text()) + 24)
    return button


def figures(
    tree: Tree, review: PlotReview, unsure: Collection[int] = ()
) -> list[tuple[str, str]]:
    """The tree's figures, label and text (world coordinates, as trees.csv); the
    scans it is seen from that need review (``unsure``, from 1) are named."""
    s = tree.stem
    mark = review.marks.get(tree.tree_id)
    hand = review.dbh.get(tree.tree_id)
    yours = "" if hand is None else f"; yours {100 * hand.dbh_m:.1f} cm"
    x, y, z = tree.xyz
    # On the map's dark ground: the scan colours are made for it, not the panel.
    seen = ", ".join(
        f'<span style="color:{scan_colour(k - 1).name()}; background:#1f2126"> S{k} </span>'
        for k in tree.seen_from
    )
    doubt = [f"S{k}" for k in tree.seen_from if k in unsure]
    if doubt:
        seen += f" ({', '.join(doubt)} {'needs' if len(doubt) == 1 else 'need'} review)"
    return [
        ("Position", f"x {x:.2f}, y {y:.2f}, z {z:.2f} m"),
        (
            "Height",
            f"{height_words(s.height_m, s.height_seen_m, 2)} m ({s.height_flag})",
        ),
        ("DBH", f"{_value(s.dbh_m, ' cm', 100, 1)} ({s.dbh_quality}){yours}"),
        (
            "DBH fit",
            f"arc {_value(s.arc_deg, '°', digits=0)}, ±"
            f"{_value(s.rmse_m, ' mm', 1000, 1)}, "
            f"{_value(s.outlier_share, ' %', 100, 0)} of nearby points off it"
            + (f"\nwhy {s.dbh_quality}: {s.dbh_why}" if s.dbh_why else "")
            if np.isfinite(s.dbh_m)
            else s.dbh_why or "no circle holds the stem at 1.3 m",
        ),
        ("Lean", _value(s.lean_deg, "°", digits=1)),
        (
            "Crown",
            f"{_value(s.crown_width_m, ' m')} wide"
            if np.isfinite(s.crown_width_m)
            else "–",
        ),
        ("Points", f"{s.n_points:,}"),
        ("Seen from", seen or "–"),
        ("Your mark", mark or "not marked"),
    ]


class TreePanel(QWidget):
    """The selected tree: title, figures, its slices and side view, mark buttons and
    the DBH measured by hand."""

    mark_chosen = Signal(str, str)
    dbh_chosen = Signal(str, object)

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.setObjectName("tree_panel")
        self.tree_id: str | None = None
        self._shown: tuple[PlotOutcome, int] | None = None
        # A run writes the review file the marks go into: nothing is given meanwhile.
        self.locked = False
        self.review = PlotReview()
        self.height_index = SLICE_HEIGHTS_M.index(BREAST_HEIGHT_M)
        self.title = QLabel("No tree selected")
        self.title.setStyleSheet("font-weight: bold; font-size: 11pt;")
        self.hint = QLabel("Click a tree on the stem map, or a row of the list.")
        self.hint.setWordWrap(True)
        form = QFormLayout()
        form.setContentsMargins(0, 0, 0, 0)
        form.setVerticalSpacing(2)
        self.values: dict[str, QLabel] = {}
        for name in FIGURES:
            value = QLabel("–")
            value.setWordWrap(True)  # a DBH that failed every check says so at length
            value.setToolTip(FIGURE_TIPS.get(name, ""))
            value.setObjectName(f"tree_{name.lower().replace(' ', '_')}")
            form.addRow(f"<b>{name}</b>", value)
            self.values[name] = value
        self.slice_view = TreeSliceView(self)
        self.slice_view.setToolTip(
            "The points around the stem at the chosen height above the ground, "
            "coloured by the scan they came from, and the DBH circle (white; dashed "
            f"away from {BREAST_HEIGHT_M:g} m, where it was not fitted). Good: the "
            "points lie on the circle all round; a short arc, a branch or points off "
            "the circle make the DBH doubtful."
        )
        self.side_view = TreeSideView(self)
        self.views = QStackedWidget()
        self.views.addWidget(self.slice_view)
        self.views.addWidget(self.side_view)
        layout = QVBoxLayout(self)
        layout.setContentsMargins(6, 4, 6, 4)
        layout.addWidget(self.title)
        layout.addWidget(self.hint)
        layout.addLayout(form)
        layout.addLayout(self._height_row())
        layout.addWidget(self.views, 1)
        layout.addLayout(self._mark_row())
        layout.addLayout(self._hand_row())

    def _height_row(self) -> QHBoxLayout:
        """The buttons that choose the slice's height, or the side view."""
        heights = QHBoxLayout()
        heights.addWidget(QLabel("Slice at"))
        self.height_buttons = QButtonGroup(self)
        for k, z in enumerate(SLICE_HEIGHTS_M):
            button = QPushButton(f"{z:g} m")
            button.setCheckable(True)
            button.setChecked(k == self.height_index)
            button.setToolTip(f"The stem {z:g} m above the ground")
            self.height_buttons.addButton(button, k)
            heights.addWidget(_narrow(button))
        side = QPushButton("Side")
        side.setCheckable(True)
        side.setToolTip(
            "The whole tree from the south: its points by scan, the height (dashed) "
            "and the DBH at breast height. Check that the top is the tree's own."
        )
        self.height_buttons.addButton(side, SIDE)
        heights.addWidget(_narrow(side))
        self.height_buttons.idClicked.connect(self.show_height)
        return heights

    def _mark_row(self) -> QHBoxLayout:
        self.buttons = {}
        row = QHBoxLayout()
        for mark, text, key, tip in (
            ("ok", "Mark ok", "O", "The tree and its figures are right"),
            (
                "check",
                "Mark check",
                "C",
                "Something is wrong here: look again in the field",
            ),
            (
                NOT_A_TREE,
                "Not a tree",
                "X",
                "A shrub, a pole, a branch or a neighbour's part listed as a tree: it "
                "stays in trees.csv, marked so",
            ),
            ("", "Clear", "Del", "Remove your mark"),
        ):
            button = QPushButton(text)
            button.setShortcut(QKeySequence(key))  # the window's, not typed text
            button.setToolTip(f"{tip} ({key})")
            button.setEnabled(False)
            button.clicked.connect(lambda _=False, m=mark: self._mark(m))
            row.addWidget(button)
            self.buttons[mark] = button
        return row

    def _hand_row(self) -> QHBoxLayout:
        """Measure a DBH by hand on the breast-height slice, keep it, forget it."""
        self.measure_button = QPushButton("Measure DBH")
        self.measure_button.setCheckable(True)
        self.measure_button.setToolTip(
            f"Measure the DBH yourself on the {BREAST_HEIGHT_M:g} m slice: click "
            "points on the stem's outline all round (right click takes one back), "
            "then Keep (Enter). It goes into the inventory beside the measured DBH "
            "(dbh_hand_m). Esc cancels."
        )
        self.measure_button.toggled.connect(self._measure)
        self.keep_button = QPushButton("Keep DBH")
        self.keep_button.setToolTip("Keep the circle through your points as your DBH")
        self.keep_button.clicked.connect(self._keep)
        self.forget_button = QPushButton("Forget DBH")
        self.forget_button.setToolTip("Remove your DBH of this tree")
        self.forget_button.clicked.connect(self._forget)
        row = QHBoxLayout()
        for button in (self.measure_button, self.keep_button, self.forget_button):
            button.setEnabled(False)
            row.addWidget(button)
        self.slice_view.clicks_changed.connect(self._update_hand_buttons)
        self.slice_view.finished.connect(
            lambda keep: self._keep() if keep else self.measure_button.setChecked(False)
        )
        return row

    def show_tree(
        self,
        outcome: PlotOutcome | None,
        k: int | None,
        review: PlotReview | None = None,
    ) -> None:
        """Show tree ``k`` of ``outcome`` (None: no tree) with the ``review``'s mark
        and DBH of it. The tree shown again (a mark given) keeps a DBH being measured.
        """
        again = (
            self._shown is not None
            and self._shown[0] is outcome
            and self._shown[1] == k
        )
        self._shown = None if outcome is None or k is None else (outcome, k)
        self.review = review or PlotReview()
        if (
            again
            and self.slice_view.measuring
            and outcome is not None
            and k is not None
        ):
            for name, text in figures(outcome.trees[k], self.review, outcome.unsure):
                self.values[name].setText(text)
            self._update_hand_buttons()
            return
        self.measure_button.setChecked(False)
        if outcome is None or k is None:
            self.tree_id = None
            self.title.setText("No tree selected")
            self.hint.show()
            for value in self.values.values():
                value.setText("–")
            self.slice_view.set_slice(None, np.zeros(2), float("nan"), "")
            self.side_view.set_tree(None, None)
        else:
            tree = outcome.trees[k]
            self.tree_id = tree.tree_id
            self.title.setText(f"Tree {tree.tree_id}")
            self.hint.hide()
            for name, text in figures(tree, self.review, outcome.unsure):
                self.values[name].setText(text)
            self.show_height(self.height_index)
        self._update_buttons()

    def set_locked(self, locked: bool) -> None:
        """Refuse marks and DBHs (``locked``: a run goes on), or take them again."""
        if locked and self.slice_view.measuring:
            self.measure_button.setChecked(False)
        self.locked = locked
        self._update_buttons()

    def _update_buttons(self) -> None:
        for button in self.buttons.values():
            button.setEnabled(self.tree_id is not None and not self.locked)
        self._update_hand_buttons()

    def show_height(self, index: int) -> None:
        """Show the shown tree's slice at ``SLICE_HEIGHTS_M[index]``, or its side
        view (``SIDE``); a measuring under way ends."""
        if self.slice_view.measuring:
            self.measure_button.setChecked(False)
        self.height_index = index
        self.height_buttons.button(index).setChecked(True)
        self.views.setCurrentWidget(
            self.side_view if index == SIDE else self.slice_view
        )
        if self._shown is None:
            return
        outcome, k = self._shown
        if index == SIDE:
            profile = outcome.profiles[k] if k < len(outcome.profiles) else None
            tree = outcome.trees[k]
            hand = self.review.dbh.get(tree.tree_id)
            self.side_view.set_tree(tree, profile, hand)
            return
        sl = outcome.slices[k][index]
        fitted = sl.height_m == BREAST_HEIGHT_M
        tree = outcome.trees[k]
        circle = (
            "; no DBH fit"
            if not np.isfinite(tree.stem.dbh_m)
            else "; circle: the DBH fit"
            if fitted
            else "; circle: the DBH, for comparison"
        )
        hand = self.review.dbh.get(tree.tree_id) if fitted else None
        self.slice_view.set_slice(
            sl,
            tree.stem.dbh_xy if sl.centre is None else sl.centre,
            tree.stem.dbh_m / 2,
            f"{len(sl.xy)} points at {sl.height_m:g} m ± 5 cm{circle}"
            + ("; green: yours" if hand is not None else ""),
            fitted,
            hand,
        )

    def _mark(self, mark: str) -> None:
        if self.tree_id is not None:
            self.mark_chosen.emit(self.tree_id, mark)

    def _measure(self, on: bool) -> None:
        """Take clicks on the breast-height slice (the view turns to it)."""
        if on:
            self.show_height(SLICE_HEIGHTS_M.index(BREAST_HEIGHT_M))
        self.slice_view.measure(on)

    def _keep(self) -> None:
        circle = self.slice_view.circle()
        if self.tree_id is not None and circle is not None:
            self.measure_button.setChecked(False)
            self.dbh_chosen.emit(self.tree_id, circle)

    def _forget(self) -> None:
        if self.tree_id is not None:
            self.measure_button.setChecked(False)
            self.dbh_chosen.emit(self.tree_id, None)

    def unkept(self) -> str:
        """The DBH being measured and not kept, as a question names it ("": none)."""
        n = len(self.slice_view.clicks) if self.slice_view.measuring else 0
        if not n:
            return ""
        return (
            f"your DBH of {self.tree_id} measured and not kept ({n} "
            f"point{'s' if n > 1 else ''}; Keep DBH keeps it)"
        )

    def _update_hand_buttons(self) -> None:
        tree = self.tree_id is not None and self._shown is not None and not self.locked
        self.measure_button.setEnabled(tree)
        measuring = self.slice_view.measuring
        self.keep_button.setEnabled(measuring and self.slice_view.circle() is not None)
        self.forget_button.setEnabled(
            tree and not measuring and self.tree_id in self.review.dbh
        )

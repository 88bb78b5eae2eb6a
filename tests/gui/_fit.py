"""``truncated_texts(window)``: visible texts that do not fit their widget.

Checks what a technician reads: labels that do not wrap, buttons, line edits, tab
titles and the visible table headers. Elided labels (the status bar) and word-wrapped
labels cannot be cut off and are skipped.
"""

from __future__ import annotations


def truncated_texts(window) -> list[str]:
    from PySide6.QtWidgets import (
        QAbstractButton,
        QHeaderView,
        QLabel,
        QLineEdit,
        QTabBar,
    )

    from amrst_gui.panels.status import ElidedLabel

    out: list[str] = []

    def fits(widget, text: str, width: int, pad: int = 0) -> bool:
        return widget.fontMetrics().horizontalAdvance(text) + pad <= width

    for w in window.findChildren(QLabel):
        if not w.isVisible() or w.wordWrap() or isinstance(w, ElidedLabel):
            continue
        text = w.text()
        if not text or "<" in text or not w.visibleRegion().boundingRect().width():
            continue
        if not fits(w, text.replace("&&", "&"), w.contentsRect().width()):
            out.append(f"label {text!r} in {w.width()} px")
    for b in window.findChildren(QAbstractButton):
        if (
            not b.isVisible()
            or not b.text()
            or b.metaObject().className() in ("QToolButton",)
        ):
            continue
        text = b.text().replace("&&", "\0").replace("&", "").replace("\0", "&")
        if not fits(
            b,
            text,
            b.width(),
            12 + (b.iconSize().width() if not b.icon().isNull() else 0),
        ):
            out.append(f"button {text!r} in {b.width()} px")
    for e in window.findChildren(QLineEdit):
        if e.isVisible() and e.text() and not fits(e, e.text(), e.width(), 8):
            out.append(f"field {e.text()!r} in {e.width()} px")
    for bar in window.findChildren(QTabBar):
        if not bar.isVisible():
            continue
        for i in range(bar.count()):
            text = bar.tabText(i).replace("&", "")
            if not fits(bar, text, bar.tabRect(i).width(), 8):
                out.append(f"tab {text!r} in {bar.tabRect(i).width()} px")
    for h in window.findChildren(QHeaderView):
        if not h.isVisible() or h.orientation().name != "Horizontal":
            continue
        model = h.model()
        for i in range(h.count()):
            if h.isSectionHidden(i) or h.sectionViewportPosition(i) > h.width():
                continue
            text = str(model.headerData(i, h.orientation()) or "")
            if text and not fits(h, text, h.sectionSize(i), 8):
                out.append(f"header {text!r} in {h.sectionSize(i)} px")
    return out

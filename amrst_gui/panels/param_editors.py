"""One editor widget per parameter, chosen from the field's default and metadata.

Floats whose default is NaN mean "automatic" and get a text field that accepts
``auto``; tuples (e.g. neighbourhood scales) are typed as ``10, 30``.
"""

from __future__ import annotations

import math
import re
from typing import TYPE_CHECKING, Any, cast

from PySide6.QtWidgets import (
    QCheckBox,
    QComboBox,
    QDoubleSpinBox,
    QLineEdit,
    QSpinBox,
    QWidget,
)

from amrst.params.files import is_nan

if TYPE_CHECKING:
    import dataclasses

AUTO = "auto"


def field_label(name: str) -> str:
    """``max_tilt_deg`` -> ``max tilt``: the unit shows in the editor instead."""
    return re.sub(r"_(m|m3|deg|s)$", "", name).replace("_", " ")


def tooltip_for(field: dataclasses.Field) -> str:
    """Help text, unit and allowed range of one parameter."""
    meta = field.metadata
    lines = [f"{field.name}: {meta.get('help', 'no description')}"]
    if meta.get("unit"):
        lines.append(f"Unit: {meta['unit']}")
    if "min" in meta or "max" in meta:
        lines.append(f"Range: {meta.get('min', '-∞')} to {meta.get('max', '∞')}")
    if "choices" in meta:
        lines.append("Choices: " + ", ".join(map(str, meta["choices"])))
    if is_nan(field.default):
        lines.append(f"Type '{AUTO}' for the automatic choice.")
    if isinstance(field.default, tuple):
        lines.append("Several values, separated by commas.")
    return "\n".join(lines)


def _decimals(value: float, lo: float) -> int:
    nonzero = [abs(v) for v in (value, lo) if v]
    smallest = min(nonzero) if nonzero else 1.0
    digits = 3
    while smallest < 10 ** (-digits + 1) and digits < 9:
        digits += 1
    return digits


def make_editor(field: dataclasses.Field, value: Any) -> QWidget:
    """A widget for one parameter, showing ``value``."""
    meta = field.metadata
    w: QWidget
    if "choices" in meta:
        combo = QComboBox()
        # As wide as its longest choice: a cut name ("above_groun") misleads.
        combo.setSizeAdjustPolicy(QComboBox.SizeAdjustPolicy.AdjustToContents)
        for choice in meta["choices"]:
            combo.addItem(str(choice), choice)
        w = combo
    elif isinstance(value, bool):
        w = QCheckBox()
    elif isinstance(value, int):
        spin = QSpinBox()
        spin.setRange(int(meta.get("min", -(2**31))), int(meta.get("max", 2**31 - 1)))
        span = spin.maximum() - spin.minimum()
        spin.setSingleStep(max(1, span // 200) if "max" in meta else 1)
        w = spin
    elif isinstance(value, float) and not is_nan(field.default) and not is_nan(value):
        dspin = QDoubleSpinBox()
        lo, hi = float(meta.get("min", -1e9)), float(meta.get("max", 1e9))
        dspin.setDecimals(_decimals(value, lo))
        dspin.setRange(lo, hi)
        dspin.setSingleStep(max(abs(value) * 0.1, 10 ** -dspin.decimals()))
        w = dspin
    else:
        w = QLineEdit()
    unit = meta.get("unit", "")
    # A long unit ("fraction of wood points") would push the value out of a narrow
    # field; it stays in the tooltip ("Unit: ...").
    if unit and unit != "relative" and len(unit) <= 10 and hasattr(w, "setSuffix"):
        w.setSuffix(f" {unit}")
    w.setToolTip(tooltip_for(field))
    w.setObjectName(field.name)
    # Spin boxes size themselves to their largest value; the dock is narrow.
    w.setMinimumWidth(70)
    set_editor_value(w, value)
    return w


def set_editor_value(w: QWidget, value: Any) -> None:
    """Show ``value`` in an editor made by :func:`make_editor`."""
    if isinstance(w, QComboBox):
        w.setCurrentIndex(max(0, w.findData(value)))
    elif isinstance(w, QCheckBox):
        w.setChecked(bool(value))
    elif isinstance(w, QSpinBox | QDoubleSpinBox):
        w.setValue(value)
    else:
        # make_editor's only other editor is a QLineEdit.
        line = cast("QLineEdit", w)
        if isinstance(value, tuple):
            line.setText(", ".join(str(v) for v in value))
        else:
            line.setText(AUTO if is_nan(value) else str(value))


def editor_value(w: QWidget, like: Any) -> Any:
    """The value an editor holds, of the same type as ``like`` (the current value).

    Raises ValueError when the text cannot be read as that type.
    """
    if isinstance(w, QComboBox):
        return w.currentData()
    if isinstance(w, QCheckBox):
        return w.isChecked()
    if isinstance(w, QSpinBox):
        return int(w.value())
    if isinstance(w, QDoubleSpinBox):
        value = float(w.value())
        # The box rounds to its decimals: keep the exact value when unchanged.
        return (
            like
            if isinstance(like, float) and round(like, w.decimals()) == value
            else value
        )
    text = cast("QLineEdit", w).text().strip()  # make_editor's only other editor
    if isinstance(like, tuple):
        kind = type(like[0]) if like else float
        try:
            return tuple(kind(part) for part in re.split(r"[,;\s]+", text) if part)
        except ValueError as exc:
            raise ValueError(
                f"{w.objectName()}: '{text}' is not a list of numbers"
            ) from exc
    if isinstance(like, float):
        if text.lower() in (AUTO, "nan", ""):
            return like if is_nan(like) else float("nan")
        try:
            value = float(text)
        except ValueError as exc:
            raise ValueError(
                f"{w.objectName()}: '{text}' is not a number or 'auto'"
            ) from exc
        if not math.isfinite(value):  # a parameter file refuses it too
            raise ValueError(f"{w.objectName()}: give a finite number or 'auto'")
        return value
    return type(like)(text)

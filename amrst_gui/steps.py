"""The workflow steps, what each depends on, and the labels the UI shows. No Qt."""

from __future__ import annotations

import dataclasses
import math

from amrst.pipeline.steps import STEP_NAMES, get_step
from amrst.pipeline.steps import STEPS as ENGINE_STEPS
from amrst.pipeline.steps import groups_for as _groups_for
from amrst.pipeline.steps import later_steps as _later_steps

# The engine's step table is the one list of steps; the app adds its own two jobs
# (loading and exporting) around it.
STEPS = STEP_NAMES
# Jobs that run to the end once started (short, or writing files); Cancel still drops
# the steps queued after them. Loading stops between chunks of LAS/LAZ points.
UNSTOPPABLE = frozenset(
    {"export"} | {s.name for s in ENGINE_STEPS if not s.cancellable}
)

LABELS = {
    "load": "Load scans",
    **{s.name: s.label.replace("&", "&&") for s in ENGINE_STEPS},  # Qt mnemonics
    "export": "Export",
    "manual": "Manual pose",
}


def groups_for(step: str) -> tuple[str, ...]:
    """Parameter groups a step's result depends on, its own and upstream ones."""
    return _groups_for(step)


def own_groups(step: str) -> tuple[str, ...]:
    """Parameter groups that belong to this step alone (for the log and hints)."""
    return get_step(step).groups if step in STEPS else ()


def plain_label(step: str) -> str:
    """The label without Qt's mnemonic escaping."""
    return LABELS[step].replace("&&", "&")


def later_steps(step: str) -> tuple[str, ...]:
    """Steps whose results are built on ``step``'s result."""
    return _later_steps(step)


def values_equal(a, b) -> bool:
    """Equality of parameter values in which NaN ("automatic") equals NaN."""
    if a is b:
        return True
    if dataclasses.is_dataclass(a) and dataclasses.is_dataclass(b):
        return type(a) is type(b) and all(
            values_equal(getattr(a, f.name), getattr(b, f.name))
            for f in dataclasses.fields(a)
        )
    if (
        isinstance(a, float)
        and isinstance(b, float)
        and math.isnan(a)
        and math.isnan(b)
    ):
        return True
    return bool(a == b)

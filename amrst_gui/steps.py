"""The workflow steps, what each depends on, and the labels the UI shows. No Qt."""

from __future__ import annotations

import dataclasses
import math

STEPS = ("separate", "skeleton", "match", "coarse", "fine")
# Jobs that run to the end once started (short, or writing files); Cancel still drops
# the steps queued after them.
UNSTOPPABLE = frozenset({"load", "coarse", "export"})

LABELS = {
    "load": "Load scans",
    "separate": "Separate wood/leaves",
    "skeleton": "Skeleton && key points",
    "match": "Match tetrahedra",
    "coarse": "Accept coarse",
    "fine": "Fine registration",
    "export": "Export",
    "manual": "Manual pose",
}

# Parameter groups (fields of RegistrationParams) whose change makes a step's
# result stale; cumulative, because each step consumes the one before.
_OWN_GROUPS = {
    "separate": ("preprocess", "separate"),
    "skeleton": ("skeleton", "keypoints"),
    "match": ("match", "coarse", "trunk"),  # ranking, verification, trunk search
    "coarse": ("metrics", "measure"),  # the coarse and fine results are measured
    "fine": ("fine",),
}


def groups_for(step: str) -> tuple[str, ...]:
    """Parameter groups a step's result depends on, its own and upstream ones."""
    out: list[str] = []
    for name in STEPS[: STEPS.index(step) + 1]:
        out.extend(_OWN_GROUPS[name])
    return tuple(out)


def own_groups(step: str) -> tuple[str, ...]:
    """Parameter groups that belong to this step alone (for the log and hints)."""
    return _OWN_GROUPS.get(step, ())


def plain_label(step: str) -> str:
    """The label without Qt's mnemonic escaping."""
    return LABELS[step].replace("&&", "&")


def later_steps(step: str) -> tuple[str, ...]:
    """Steps whose results are built on ``step``'s result."""
    return STEPS[STEPS.index(step) + 1 :]


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

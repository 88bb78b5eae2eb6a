"""The workflow steps, what each depends on, and the labels the UI shows. No Qt."""

from __future__ import annotations

STEPS = ("separate", "skeleton", "match", "coarse", "fine")

LABELS = {
    "load": "Load scans",
    "separate": "Separate wood/leaves",
    "skeleton": "Skeleton && key points",
    "match": "Match tetrahedra",
    "coarse": "Accept coarse",
    "fine": "Fine registration",
    "export": "Export",
}

# Parameter groups (fields of RegistrationParams) whose change makes a step's
# result stale; cumulative, because each step consumes the one before.
_OWN_GROUPS = {
    "separate": ("preprocess", "separate"),
    "skeleton": ("skeleton", "keypoints"),
    "match": ("match", "coarse"),  # "coarse" ranks and verifies the candidates
    "coarse": ("metrics",),
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

"""The step table: the workflow's steps, in order, with what each needs and runs.

One entry per step. The command line (``register()``'s per-scan chain), the app's
actions and labels, and the app's runner (what a parameter change makes stale, what
runs before what) all read this table, so adding a step is one entry here plus the
engine function it names.

To add a step: write its engine function (per-scan steps take
``(item, params, reporter)`` and return the next item), add a ``Step`` at its place in
``STEPS`` with the parameter groups (fields of ``RegistrationParams``) it owns, and
give the app's session the code that applies its result (``amrst_gui/session.py``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from amrst.pipeline.analysis import prepare_scan, skeletonise_scan
from amrst.pipeline.link import coarse_from_matches, find_matches
from amrst.pipeline.refine import refine

if TYPE_CHECKING:
    from collections.abc import Callable


@dataclass(frozen=True, slots=True)
class Step:
    """One workflow step."""

    name: str  # identifier used by the app, the log and the files
    label: str  # what the user reads (plain text, no mnemonic)
    groups: tuple[str, ...]  # RegistrationParams fields this step alone depends on
    per_scan: bool  # runs once per scan (else once per link, on both scans)
    run: Callable[..., Any]  # the engine function
    cancellable: bool = True  # False: short, runs to the end once started


STEPS: tuple[Step, ...] = (
    Step(
        "separate",
        "Separate wood/leaves",
        ("preprocess", "scene", "separate"),  # the scene labels come with it
        True,
        prepare_scan,
    ),
    Step(
        "skeleton",
        "Skeleton & key points",
        ("skeleton", "keypoints"),
        True,
        skeletonise_scan,
    ),
    # Ranking, verification, the feature matcher and the trunk search all happen
    # while matching.
    Step(
        "match",
        "Match tetrahedra",
        ("match", "coarse", "global_match", "trunk"),
        False,
        find_matches,
    ),
    # The coarse and the fine results are measured (cloud metrics, tree measures);
    # the measurements check for Cancel between their parts.
    Step(
        "coarse",
        "Accept coarse",
        ("metrics", "measure"),
        False,
        coarse_from_matches,
    ),
    Step("fine", "Fine registration", ("fine",), False, refine),
)

STEP_NAMES: tuple[str, ...] = tuple(s.name for s in STEPS)


def get_step(name: str) -> Step:
    """Return the step called ``name``; KeyError names the known steps."""
    for s in STEPS:
        if s.name == name:
            return s
    raise KeyError(f"No step {name!r}; the steps are {', '.join(STEP_NAMES)}.")


def groups_for(name: str) -> tuple[str, ...]:
    """Parameter groups a step's result depends on: its own and every earlier step's."""
    out: list[str] = []
    for s in STEPS[: STEP_NAMES.index(get_step(name).name) + 1]:
        out.extend(s.groups)
    return tuple(out)


def later_steps(name: str) -> tuple[str, ...]:
    """Names of the steps whose results are built on ``name``'s result."""
    return STEP_NAMES[STEP_NAMES.index(get_step(name).name) + 1 :]

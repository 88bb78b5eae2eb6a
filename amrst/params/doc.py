"""The parameter reference page, docs/parameters.md, generated from the dataclasses.

``python -m amrst.params.doc`` rewrites the page; ``--check`` only compares it and
exits 1 when it is stale. tests/core/test_readme.py runs the same comparison, so the
documented defaults and units stay true.
"""

from __future__ import annotations

import dataclasses
import math
import sys
from pathlib import Path

from amrst.params.model import RegistrationParams

PAGE = Path(__file__).resolve().parents[2] / "docs" / "parameters.md"

_INTRO = """\
# Parameters

Every parameter of a registration, its default and unit. This page is generated from
the code by `python -m amrst.params.doc` (`--check` tells whether it is current; a
test fails when it is not).

A parameter file is JSON as `amrst register` writes it to `params.json`
(`schema_version` 1). Missing values take the defaults; unknown names, wrong types
and out-of-range values are refused with the parameter's name. Give one with
`amrst register --params FILE` or `amrst batch --params FILE`, or pick a preset with
`--preset NAME`: `Default (any tree)`, `Leaf-on broadleaf`, `Leafless (winter)`,
`Conifer`, `Paper (Ren et al.)` (the method paper's settings). In the app the
*Parameters* dock edits the same values (tooltips give the unit and typical range).
"""


def _fmt(value: object) -> str:
    if isinstance(value, float) and math.isnan(value):
        return "auto"
    if isinstance(value, tuple):
        return ", ".join(str(v) for v in value)
    return str(value)


def parameter_table() -> str:
    """Return the Markdown table: one row per parameter, grouped by stage."""
    rows = ["| stage.parameter | default | unit | what it does |", "|---|---|---|---|"]
    params = RegistrationParams()
    for stage_field in dataclasses.fields(params):
        stage = getattr(params, stage_field.name)
        for f in dataclasses.fields(stage):
            meta = f.metadata
            help_text = str(meta.get("help", "")).replace("|", r"\|")
            if "choices" in meta:
                help_text += f" Choices: {', '.join(meta['choices'])}."
            rows.append(
                f"| `{stage_field.name}.{f.name}` | {_fmt(getattr(stage, f.name))} "
                f"| {meta.get('unit', '')} | {help_text} |"
            )
    return "\n".join(rows)


def parameters_page() -> str:
    """Return the whole text of docs/parameters.md."""
    return f"{_INTRO}\n{parameter_table()}\n"


def main(argv: list[str] | None = None) -> int:
    """Rewrite docs/parameters.md, or with ``--check`` say whether it is current."""
    args = sys.argv[1:] if argv is None else argv
    if args not in ([], ["--check"]):
        print("usage: python -m amrst.params.doc [--check]", file=sys.stderr)
        return 2
    text = parameters_page()
    current = PAGE.read_text(encoding="utf-8") if PAGE.is_file() else ""
    if args == ["--check"]:
        if current == text:
            return 0
        print(f"{PAGE} is stale: run python -m amrst.params.doc", file=sys.stderr)
        return 1
    if current != text:
        from amrst.files.atomic import write_text_atomic

        write_text_atomic(PAGE, text)
        print(f"wrote {PAGE}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

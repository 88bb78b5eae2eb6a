"""The campaign manifest: one entry per tree, hand-editable (campaign.toml or .csv).

``campaign.toml`` (paths relative to the campaign folder)::

    [campaign]
    name = "plot 7"
    preset = ""            # optional: a preset for every tree (as amrst register --preset)
    params = ""            # optional: a parameter JSON for every tree (--params)

    [[tree]]
    id = "T001"                                   # names the results folder
    scans = ["T001/a.laz", "T001/b.laz", "T001/c.laz"]
    reference = "T001/a.laz"                      # optional: a scan above, or its number
    stem = [512345.2, 5456789.1]                  # optional: where it stands (world)
    truth = "T001/truth.json"                     # optional: known transforms

    [[tree]]
    id = "T002"
    scans = ["plot.e57#3", "plot.e57#4"]          # scans 3 and 4 of one E57 file

``manifest.csv`` (the CSV form; ``campaign.csv`` is the results table) holds the same with one row per tree: ``id,scans,reference,stem_x,
stem_y,truth``, the scans separated by ``;``. When both exist, campaign.toml is used.
"""

from __future__ import annotations

import csv
import io
import os
import re
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from amrst.errors import InvalidInput
from amrst.types import MAX_COORD_M

if TYPE_CHECKING:
    from collections.abc import Sequence

MANIFEST = "campaign.toml"
MANIFEST_CSV = "manifest.csv"  # campaign.csv is the results table
RESULTS = "results"
_ID = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]*$")
#: The characters a TOML basic string cannot hold as they are (tab it can).
_CONTROL = re.compile(r"[\x00-\x08\x0a-\x1f\x7f]")
#: The keys a tree's table and the [campaign] table take; another is a typo.
TREE_KEYS = ("id", "scans", "reference", "stem", "truth")
CAMPAIGN_KEYS = ("name", "preset", "params")
CSV_COLUMNS = ("id", "scans", "reference", "stem_x", "stem_y", "truth")


@dataclass(frozen=True, slots=True)
class TreeEntry:
    """One tree of a campaign: its scans (specs, relative paths) and options."""

    id: str
    scans: tuple[str, ...]
    reference: int = 0
    stem: tuple[float, float] | None = None
    truth: str | None = None


@dataclass(frozen=True, slots=True)
class Campaign:
    """A campaign folder and its manifest."""

    root: Path
    trees: tuple[TreeEntry, ...]
    name: str = ""
    preset: str = ""
    params: str = ""
    source: str = MANIFEST
    notes: tuple[str, ...] = field(default=())

    def results_dir(self, tree_id: str) -> Path:
        """Return the folder holding one tree's results."""
        return self.root / RESULTS / tree_id

    def tree(self, tree_id: str) -> TreeEntry:
        """Return the entry of ``tree_id``."""
        for entry in self.trees:
            if entry.id == tree_id:
                return entry
        raise InvalidInput(f"No tree {tree_id!r} in {self.root / self.source}.")


def _reference(value: Any, scans: tuple[str, ...], where: str) -> int:
    if value is None or value == "":
        return 0
    if isinstance(value, int) and not isinstance(value, bool):
        if 0 <= value < len(scans):
            return value
    elif isinstance(value, str):
        if value in scans:
            return scans.index(value)
        if value.isdigit() and int(value) < len(scans):
            return int(value)
        names = [Path(s).name for s in scans]
        if names.count(value) == 1:
            return names.index(value)
    raise InvalidInput(
        f"{where}: reference {value!r} is not one of its scans; give a scan as listed "
        f"in 'scans' or its number 0 to {len(scans) - 1}."
    )


def _refuse_nul(raw: dict[str, Any], where: str) -> None:
    """Refuse a NUL character in a value: no file name holds one, and opening it fails."""
    for key, value in raw.items():
        values = value if isinstance(value, list) else [value]
        if any(isinstance(v, str) and "\0" in v for v in values):
            raise InvalidInput(
                f"{where}: {key!r} holds a NUL character (an invisible zero byte); "
                "delete it."
            )


def _entry(raw: Any, where: str) -> TreeEntry:
    if not isinstance(raw, dict):
        raise InvalidInput(f"{where}: a tree must be a [[tree]] table, got {raw!r}.")
    _known_keys(raw, TREE_KEYS, where)
    tree_id = str(raw.get("id", "")).strip()
    if not _ID.match(tree_id):
        raise InvalidInput(
            f"{where}: tree id {tree_id!r} must start with a letter or digit and use only "
            "letters, digits, '.', '_' and '-' (it names the results folder)."
        )
    _refuse_nul(raw, f"{where} (tree {tree_id})")
    scans = raw.get("scans")
    if isinstance(scans, str):
        scans = [s.strip() for s in scans.split(";") if s.strip()]
    if not isinstance(scans, list) or not all(isinstance(s, str) for s in scans):
        raise InvalidInput(f"{where}: 'scans' must be a list of scan files.")
    if len(scans) < 2:
        raise InvalidInput(
            f"{where} (tree {tree_id}): {len(scans)} scan(s); a tree needs at least 2 "
            "(the reference and a scan to move onto it)."
        )
    scans_t = tuple(scans)
    listed = [os.path.normpath(s) for s in scans_t]
    twice = next(
        (s for s, n in zip(scans_t, listed, strict=True) if listed.count(n) > 1), None
    )
    if twice is not None:
        raise InvalidInput(
            f"{where} (tree {tree_id}): {twice} is listed twice; a scan is registered "
            "onto another scan, not onto itself."
        )
    stem = raw.get("stem")
    stem_xy = None
    if stem not in (None, "", []):
        try:
            if isinstance(stem, str) or any(isinstance(v, bool) for v in stem):
                raise TypeError("not numbers")
            x, y = (float(v) for v in stem)
            if not (abs(x) <= MAX_COORD_M and abs(y) <= MAX_COORD_M):  # NaN too
                raise ValueError("not a coordinate")
        except (TypeError, ValueError) as exc:
            raise InvalidInput(
                f"{where}: 'stem' must be [X, Y] in metres, each within "
                f"{MAX_COORD_M:g} m, got {stem!r}."
            ) from exc
        stem_xy = (x, y)
    truth = raw.get("truth") or None
    return TreeEntry(
        tree_id,
        scans_t,
        _reference(raw.get("reference"), scans_t, f"{where} (tree {tree_id})"),
        stem_xy,
        None if truth is None else str(truth),
    )


def _read_text(path: Path, save_as: str) -> str:
    """Return a manifest's text, refusing one that is not UTF-8 in one line.

    A byte-order mark is dropped: a spreadsheet's "CSV UTF-8" and some editors start
    the file with one. Line ends are kept as they are, as the CSV reader needs.
    """
    try:
        with open(path, newline="", encoding="utf-8-sig") as f:
            return f.read()
    except UnicodeDecodeError as exc:
        raise InvalidInput(f"{path} is not UTF-8 text; save it as {save_as}.") from exc


def _read_toml(path: Path) -> dict[str, Any]:
    if sys.version_info >= (3, 11):
        import tomllib
    else:  # pragma: no cover - Python 3.10
        import tomli as tomllib

    text = _read_text(path, "UTF-8")
    try:
        doc: dict[str, Any] = tomllib.loads(text)
        return doc
    except tomllib.TOMLDecodeError as exc:
        raise InvalidInput(
            f"{path} is not valid TOML ({exc}). Fix that line (see campaign.toml in "
            "docs/multiscan-and-campaigns.md), or move it away and run amrst campaign "
            "init again for a new one."
        ) from exc


def _known_keys(raw: dict[str, Any], known: tuple[str, ...], where: str) -> None:
    """Refuse a key the table does not take (a typo would silently do nothing)."""
    unknown = [str(k) for k in raw if k not in known]
    if unknown:
        raise InvalidInput(
            f"{where}: unknown key {unknown[0]!r}; the keys are {', '.join(known)}."
        )


def _read_csv(path: Path) -> dict[str, Any]:
    text = _read_text(path, "CSV UTF-8 (comma-separated)")
    reader = csv.DictReader(io.StringIO(text, newline=""))
    rows = list(reader)
    # A spreadsheet may end the header with an empty column.
    columns = [c for c in reader.fieldnames or [] if c]
    if "id" not in columns or "scans" not in columns:
        raise InvalidInput(
            f"{path} must be comma-separated with the columns {','.join(CSV_COLUMNS)} "
            f"(found {','.join(columns) or 'none'}); the scans of a tree are separated "
            "by ';'."
        )
    _known_keys(dict.fromkeys(columns), CSV_COLUMNS, str(path))
    trees = []
    for row in rows:
        entry: dict[str, Any] = {k: (v or "").strip() for k, v in row.items() if k}
        x, y = entry.pop("stem_x", ""), entry.pop("stem_y", "")
        if x or y:
            entry["stem"] = [x, y]
        trees.append(entry)
    return {"tree": trees}


def campaign_root(folder: str | os.PathLike[str]) -> Path:
    """Return the campaign folder given; an empty name would be the current folder."""
    if not os.fspath(folder):
        raise InvalidInput(
            "The campaign folder's name is empty: give the campaign folder."
        )
    return Path(folder)


def load_campaign(folder: str | os.PathLike[str]) -> Campaign:
    """Read a campaign folder's manifest (campaign.toml, else the CSV manifest).

    Raises
    ------
    InvalidInput
        No folder, no manifest, bad TOML/CSV, a bad entry, or two trees with one id.
    """
    root = campaign_root(folder)
    if not root.is_dir():
        raise InvalidInput(
            f"{root} is not a campaign folder. Create it with amrst campaign init."
        )
    toml, table = root / MANIFEST, root / MANIFEST_CSV
    if toml.is_file():
        doc, source = _read_toml(toml), MANIFEST
    elif table.is_file():
        doc, source = _read_csv(table), MANIFEST_CSV
    else:
        raise InvalidInput(f"{root} has no {MANIFEST}. Run: amrst campaign init {root}")
    head = doc.get("campaign", {})
    raw_trees = doc.get("tree", [])
    if not isinstance(head, dict):
        raise InvalidInput(
            f"{root / source}: [campaign] must be a table, got {head!r}."
        )
    _known_keys(head, CAMPAIGN_KEYS, f"{root / source}, [campaign]")
    _refuse_nul(head, f"{root / source}, [campaign]")
    if head.get("preset") and head.get("params"):
        raise InvalidInput(
            f"{root / source}, [campaign]: give a preset or a params file, not both "
            "(as amrst register --preset or --params); remove one of them."
        )
    _known_keys(doc, ("campaign", "tree"), str(root / source))
    if not isinstance(raw_trees, list):
        raise InvalidInput(
            f"{root / source}: 'tree' must be a list of [[tree]] tables."
        )
    if not raw_trees:
        raise InvalidInput(
            f"{root / source} lists no trees: add a [[tree]] table for each, or run "
            f"amrst campaign init {root} on a folder with one subfolder of scans per "
            "tree."
        )
    trees = [_entry(t, f"{source}, tree {i + 1}") for i, t in enumerate(raw_trees)]
    seen: set[str] = set()
    for t in trees:
        if t.id in seen:
            raise InvalidInput(
                f"{root / source}: two trees have the id {t.id!r}; ids must be unique."
            )
        seen.add(t.id)
    return Campaign(
        root,
        tuple(trees),
        str(head.get("name", root.name)),
        str(head.get("preset", "") or ""),
        str(head.get("params", "") or ""),
        source,
    )


def _toml_str(value: str) -> str:
    """Return ``value`` as a TOML basic string; a control character needs an escape."""
    text = value.replace("\\", "\\\\").replace('"', '\\"')
    return '"' + _CONTROL.sub(lambda m: f"\\u{ord(m[0]):04x}", text) + '"'


def manifest_text(campaign: Campaign) -> str:
    """Return campaign.toml text for ``campaign`` (what :func:`load_campaign` reads)."""
    lines = [
        "# AMRST campaign: one [[tree]] table per tree; paths are relative to this folder.",
        "# Edit freely: scans (FILE.e57#k picks scan k of a file), reference (a scan",
        "# or its number), stem = [X, Y], truth = a truth.json. The format: AMRST",
        "# Studio's docs/multiscan-and-campaigns.md.",
        "",
        "[campaign]",
        f"name = {_toml_str(campaign.name)}",
        f"preset = {_toml_str(campaign.preset)}",
        f"params = {_toml_str(campaign.params)}",
    ]
    return "\n".join(lines) + "\n" + tree_tables(campaign.trees)


def tree_tables(trees: Sequence[TreeEntry]) -> str:
    """Return the ``[[tree]]`` tables of ``trees`` (campaign.toml text)."""
    lines = []
    for t in trees:
        lines += ["", "[[tree]]", f"id = {_toml_str(t.id)}"]
        lines.append("scans = [" + ", ".join(_toml_str(s) for s in t.scans) + "]")
        lines.append(f"reference = {_toml_str(t.scans[t.reference])}")
        if t.stem is not None:
            lines.append(f"stem = [{t.stem[0]!r}, {t.stem[1]!r}]")
        if t.truth:
            lines.append(f"truth = {_toml_str(t.truth)}")
    return "\n".join(lines) + "\n" if lines else ""


def save_campaign(campaign: Campaign) -> Path:
    """Write ``campaign.toml`` atomically; return its path."""
    from amrst.files.atomic import write_text_atomic

    path = campaign.root / MANIFEST
    write_text_atomic(path, manifest_text(campaign))
    return path

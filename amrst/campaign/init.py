"""``amrst campaign init DIR``: build the manifest from a folder layout.

Layout: one subfolder per tree holding its scan files (any format amrst reads). The
tree id is the subfolder name. The reference is the scan the existing manifest names
for that tree, else a scan named ``target.*`` or ``reference.*`` (the pair case
folders' convention), else the first scan in name order. A subfolder with a single
E57 or PTX file holding several scans becomes one tree of those scans (``FILE#k``). A
``truth.json`` in the subfolder becomes the tree's truth.

Trees already in the manifest keep their entry as edited by hand (scans, reference,
stem, truth); new subfolders are added; what could not be paired is reported and left
out (a folder with one scan, no scan, or files amrst cannot read).
"""

from __future__ import annotations

import re
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

from amrst.campaign.manifest import (
    MANIFEST,
    RESULTS,
    Campaign,
    TreeEntry,
    load_campaign,
    save_campaign,
)
from amrst.errors import InvalidInput

if TYPE_CHECKING:
    import os

_REFERENCE_STEMS = ("target", "reference")


def _scan_files(folder: Path) -> list[Path]:
    from amrst import io

    exts = set(io.supported_extensions())
    return sorted(
        p
        for p in folder.iterdir()
        if p.is_file() and p.suffix.lower() in exts and not p.name.startswith(".")
    )


def _tree_id(name: str) -> str:
    clean = re.sub(r"[^A-Za-z0-9._-]", "_", name).lstrip("._-")
    return clean or "tree"


def _entry_for(folder: Path, root: Path) -> tuple[TreeEntry | None, str]:
    """Return the entry for one subfolder, or None and why it could not be paired."""
    from amrst.io.scans import list_scans

    files = _scan_files(folder)
    rel = [p.relative_to(root).as_posix() for p in files]
    if len(files) == 1 and files[0].suffix.lower() in (".e57", ".ptx"):
        try:
            count = len(list_scans(files[0]))
        except InvalidInput as exc:
            return None, f"{folder.name}: {exc}"
        rel = [f"{rel[0]}#{k}" for k in range(count)]
    if len(rel) < 2:
        found = "no scan file" if not rel else f"only one scan ({rel[0]})"
        return None, f"{folder.name}: {found}; a tree needs at least 2 scans."
    reference = 0
    for k, p in enumerate(files if len(files) == len(rel) else []):
        if p.stem.lower() in _REFERENCE_STEMS:
            reference = k
            break
    truth = folder / "truth.json"
    return (
        TreeEntry(
            _tree_id(folder.name),
            tuple(rel),
            reference,
            None,
            truth.relative_to(root).as_posix() if truth.is_file() else None,
        ),
        "",
    )


def init_campaign(folder: str | os.PathLike[str]) -> tuple[Campaign, list[str]]:
    """Build or update ``campaign.toml`` in ``folder`` from its subfolders.

    Returns
    -------
    campaign : Campaign
        As written.
    skipped : list of str
        One line per subfolder that could not be made a tree, saying why.
    """
    root = Path(folder)
    if not root.is_dir():
        raise InvalidInput(
            f"{root} is not a folder. Make a folder with one subfolder per tree holding "
            "its scan files, then run amrst campaign init on it."
        )
    old: dict[str, TreeEntry] = {}
    name, preset, params = root.resolve().name, "", ""
    if (root / MANIFEST).is_file():
        existing = load_campaign(root)
        old = {t.id: t for t in existing.trees}
        name, preset, params = existing.name, existing.preset, existing.params
    trees: list[TreeEntry] = []
    skipped: list[str] = []
    for sub in sorted(p for p in root.iterdir() if p.is_dir()):
        if sub.name == RESULTS or sub.name.startswith("."):
            continue
        entry, why = _entry_for(sub, root)
        if entry is None:
            if _tree_id(sub.name) in old:
                trees.append(old.pop(_tree_id(sub.name)))
            else:
                skipped.append(why)
            continue
        if entry.id in old:
            entry = old.pop(entry.id)
        elif any(t.id == entry.id for t in trees):
            entry = replace(entry, id=f"{entry.id}_{len(trees)}")
        trees.append(entry)
    trees += list(old.values())  # hand-made entries with no folder of their own
    loose = [p.name for p in _scan_files(root)]
    if loose:
        skipped.append(
            f"{len(loose)} scan file(s) directly in {root.name} ({', '.join(loose[:3])}"
            f"{'...' if len(loose) > 3 else ''}): put each tree's scans in a subfolder, "
            "or list them in campaign.toml by hand (FILE.e57#k for scans of one file)."
        )
    campaign = Campaign(root, tuple(trees), name, preset, params)
    save_campaign(campaign)
    return load_campaign(root), skipped

"""``amrst campaign init DIR``: build the manifest from a folder layout.

Layout: one subfolder per tree holding its scan files (any format amrst reads). The
tree id is the subfolder name. The reference is the scan the existing manifest names
for that tree, else a scan named ``target.*`` or ``reference.*`` (the pair case
folders' convention), else the first scan in name order. A subfolder with a single
E57 or PTX file holding several scans becomes one tree of those scans (``FILE#k``). A
``truth.json`` in the subfolder becomes the tree's truth.

Trees already in the manifest keep their entry as edited by hand (scans, reference,
stem, truth; a tree is known by its id or by its scans), and the file keeps its text:
the tables of new subfolders are added at its end. What could not be paired is
reported and left out (a folder with one scan, no scan, or files amrst cannot read).
"""

from __future__ import annotations

import re
from dataclasses import replace
from typing import TYPE_CHECKING

from amrst.campaign.manifest import (
    MANIFEST,
    MANIFEST_CSV,
    RESULTS,
    Campaign,
    TreeEntry,
    campaign_root,
    load_campaign,
    save_campaign,
    tree_tables,
)
from amrst.errors import InvalidInput
from amrst.files.atomic import write_text_atomic
from amrst.files.safefile import refuse_undecodable

if TYPE_CHECKING:
    import os
    from pathlib import Path

_REFERENCE_STEMS = ("target", "reference")
AGAIN = ", then run amrst campaign init again"


def _scan_files(folder: Path, root: Path) -> list[Path]:
    """Return the scan files in ``folder``, refusing one campaign.toml cannot name."""
    from amrst import io

    exts = set(io.supported_extensions())
    files = sorted(
        p
        for p in folder.iterdir()
        if p.is_file() and p.suffix.lower() in exts and not p.name.startswith(".")
    )
    for p in files:
        refuse_undecodable(p.relative_to(root), AGAIN)  # campaign.toml names it
    return files


def _tree_id(name: str) -> str:
    clean = re.sub(r"[^A-Za-z0-9._-]", "_", name).lstrip("._-")
    return clean or "tree"


def _entry_for(folder: Path, root: Path) -> tuple[TreeEntry | None, str]:
    """Return the entry for one subfolder, or None and why it could not be paired."""
    from amrst.io.scans import list_scans

    files = _scan_files(folder, root)
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
    root = campaign_root(folder)
    if not root.is_dir():
        raise InvalidInput(
            f"{root} is not a folder. Make a folder with one subfolder per tree holding "
            "its scan files, then run amrst campaign init on it."
        )
    manifest = root / MANIFEST
    existing = load_campaign(root) if manifest.is_file() else None
    old = {} if existing is None else {t.id: t for t in existing.trees}
    trees, skipped = _folder_trees(root, dict(old))
    from amrst.campaign.table import TABLE

    ours = {TABLE, MANIFEST_CSV}  # the campaign's own tables are no scans
    loose = [p.name for p in _scan_files(root, root) if p.name not in ours]
    if loose:
        skipped.append(
            f"{len(loose)} scan file(s) directly in {root.name} ({', '.join(loose[:3])}"
            f"{'...' if len(loose) > 3 else ''}): put each tree's scans in a subfolder, "
            "or list them in campaign.toml by hand (FILE.e57#k for scans of one file)."
        )
    if not trees:
        why = f" ({skipped[0]})" if skipped else ""
        raise InvalidInput(
            f"No tree found in {root}{why}: make one subfolder per tree holding its "
            "scan files (two or more), then run amrst campaign init again."
        )
    added = [t for t in trees if t.id not in old]
    if existing is None:
        refuse_undecodable(root.resolve(), AGAIN)  # the campaign's name
        save_campaign(Campaign(root, tuple(trees), root.resolve().name))
    elif added:
        write_text_atomic(
            manifest, manifest.read_text(encoding="utf-8") + tree_tables(added)
        )
    return load_campaign(root), skipped


def _folder_trees(
    root: Path, old: dict[str, TreeEntry]
) -> tuple[list[TreeEntry], list[str]]:
    """Return each subfolder's tree, and why the others make none.

    A tree the manifest has (``old``, by id or by its scans: an id changed by hand)
    keeps its entry; the manifest's entries with no subfolder come last.
    """
    by_scans = {frozenset(t.scans): t.id for t in old.values()}
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
        renamed = by_scans.get(frozenset(entry.scans), "")
        if entry.id in old:
            entry = old.pop(entry.id)
        elif renamed in old:
            entry = old.pop(renamed)
        elif any(t.id == entry.id for t in trees):
            entry = replace(entry, id=f"{entry.id}_{len(trees)}")
        trees.append(entry)
    return trees + list(old.values()), skipped  # hand-made entries last

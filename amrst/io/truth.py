"""Truth files: a JSON object whose ``T_target_source`` maps source into target.

The one reader of truth files for the command line (``--truth``), the app
(*File ▸ Load truth*) and the case folders of ``amrst bench``.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

from amrst.errors import InvalidInput
from amrst.files.safefile import load_json_file
from amrst.types import check_rigid, check_translation

if TYPE_CHECKING:
    import numpy as np

PathLike = str | os.PathLike[str]
_HINT = "a JSON file with a 4x4 'T_target_source' (row-major, source to target)"


def read_truth_document(path: PathLike) -> dict[str, Any]:
    """Read the whole truth JSON object, with a rigid ``T_target_source`` in it.

    Parameters
    ----------
    path : path
        A JSON file holding an object with a 4x4 ``T_target_source`` (row-major).

    Returns
    -------
    dict
        The document as read; ``T_target_source`` is checked, not converted.

    Raises
    ------
    InvalidInput
        If the path is empty, missing or unreadable, not a regular file (a folder,
        FIFO, device, socket, link loop) or over 10 MB, is not a JSON object, or its
        ``T_target_source`` is not a finite rigid 4x4 transform within 1e8 m.
    """
    p = Path(path)
    doc = load_json_file(path, "truth file", _HINT)
    if not isinstance(doc, dict) or "T_target_source" not in doc:
        raise InvalidInput(
            f"The truth file {p} holds no 'T_target_source'; give a JSON object with "
            "a 4x4 'T_target_source' (row-major, source to target), e.g. the "
            "truth.json that amrst simulate writes."
        )
    where = f"T_target_source in {p}"
    check_translation(check_rigid(doc["T_target_source"], where), where)
    return doc


def read_truth(path: PathLike) -> np.ndarray:
    """Read ``T_target_source`` of a truth file, checked to be rigid: (4, 4) float64."""
    doc = read_truth_document(path)
    return check_rigid(doc["T_target_source"], f"T_target_source in {Path(path)}")

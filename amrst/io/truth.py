"""Truth files: a JSON object whose ``T_target_source`` maps source into target.

The one reader of truth files for the command line (``--truth``), the app
(*File ▸ Load truth*) and the case folders of ``amrst bench``.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

from amrst.errors import InvalidInput
from amrst.types import check_rigid

if TYPE_CHECKING:
    import numpy as np

PathLike = str | os.PathLike[str]


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
        If the path is empty, a folder, missing or unreadable, is not a JSON object,
        or its ``T_target_source`` is not a finite rigid 4x4 transform.
    """
    if not str(path).strip():
        raise InvalidInput("The truth file path is empty; give a truth JSON file.")
    p = Path(path)
    if p.is_dir():
        raise InvalidInput(
            f"Truth file {p} is a folder; give the path of a JSON file with a 4x4 "
            "'T_target_source'."
        )
    try:
        doc = json.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InvalidInput(f"Truth file not found: {p}.") from None
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise InvalidInput(
            f"Cannot read T_target_source from {p}: {exc}. It must be JSON with a "
            "4x4 'T_target_source'."
        ) from exc
    if not isinstance(doc, dict) or "T_target_source" not in doc:
        raise InvalidInput(
            f"Cannot read T_target_source from {p}: it must hold a JSON object with "
            "a 4x4 'T_target_source' (row-major, source to target)."
        )
    check_rigid(doc["T_target_source"], f"T_target_source in {p}")
    return doc


def read_truth(path: PathLike) -> np.ndarray:
    """Read ``T_target_source`` of a truth file, checked to be rigid: (4, 4) float64."""
    doc = read_truth_document(path)
    return check_rigid(doc["T_target_source"], f"T_target_source in {Path(path)}")

"""The AMRST chain, stage by stage, as the CLI, the app and the benchmark run it.

register(target, source) reads like the method:
  1. preprocess each scan (outliers, thinning)         stages/preprocess.py
  2. separate wood and leaves                          stages/separate.py
  3. skeletonise the wood, 4. pick key points          stages/skeleton.py, keypoints.py
  5. match similar tetrahedra between the key points   stages/match.py
  6. verify and rank every match; coarse solution      stages/coarse.py
  7. refine with ICP (LM-ICP or robust point-to-plane)  stages/fine.py
  8. measure (NN-RMSE, Hausdorff, overlap)             stages/metrics.py
The app calls the same steps one at a time (the step table, ``steps.STEPS``: prepare_scan,
skeletonise_scan, find_matches, coarse_from_matches, refine; then evaluate) so the user
can look and overrule between them.

Modules: ``analysis`` (per scan, once per scan), ``link`` (one pair: matches and the
ranked candidates), ``sources`` and ``trunk_fallback`` (candidate sources besides the
tetrahedra), ``refine`` (fine registration and metrics of a link), ``register`` (the
whole chain for two scans), ``steps`` (the step table).
Engine stages work in each cloud's local coordinates; the transforms returned by
register() and used by export are in world coordinates (see amrst.types.world_transform).
"""

from amrst.params import RegistrationParams
from amrst.pipeline.analysis import (
    ScanAnalysis,
    analyse_scan,
    both_scans,
    prepare_scan,
    skeletonise_scan,
)
from amrst.pipeline.link import MatchResult, coarse_from_matches, find_matches
from amrst.pipeline.refine import evaluate, refine
from amrst.pipeline.register import RegistrationResult, register
from amrst.pipeline.steps import STEP_NAMES, STEPS, Step, get_step

__all__ = [
    "STEPS",
    "STEP_NAMES",
    "MatchResult",
    "RegistrationParams",
    "RegistrationResult",
    "ScanAnalysis",
    "Step",
    "analyse_scan",
    "both_scans",
    "coarse_from_matches",
    "evaluate",
    "find_matches",
    "get_step",
    "prepare_scan",
    "refine",
    "register",
    "skeletonise_scan",
]

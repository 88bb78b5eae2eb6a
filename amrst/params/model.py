"""The nested settings of a registration: ``RegistrationParams``."""

from __future__ import annotations

from dataclasses import dataclass, field

from amrst.measure import MeasureParams
from amrst.stages.coarse import CoarseParams
from amrst.stages.fine import FineParams
from amrst.stages.global_match import GlobalMatchParams
from amrst.stages.keypoints import KeypointParams
from amrst.stages.match import MatchParams
from amrst.stages.metrics import MetricsParams
from amrst.stages.preprocess import PreprocessParams
from amrst.stages.scene import SceneParams
from amrst.stages.separate import SeparateParams
from amrst.stages.skeleton import SkeletonParams
from amrst.stages.trunk import TrunkParams


@dataclass(frozen=True, slots=True, kw_only=True)
class RegistrationParams:
    """All settings, one field per stage (KISS-ICP style). Change with dataclasses.replace."""

    preprocess: PreprocessParams = field(default_factory=PreprocessParams)
    scene: SceneParams = field(default_factory=SceneParams)
    separate: SeparateParams = field(default_factory=SeparateParams)
    skeleton: SkeletonParams = field(default_factory=SkeletonParams)
    keypoints: KeypointParams = field(default_factory=KeypointParams)
    match: MatchParams = field(default_factory=MatchParams)
    coarse: CoarseParams = field(default_factory=CoarseParams)
    global_match: GlobalMatchParams = field(default_factory=GlobalMatchParams)
    trunk: TrunkParams = field(default_factory=TrunkParams)
    fine: FineParams = field(default_factory=FineParams)
    metrics: MetricsParams = field(default_factory=MetricsParams)
    measure: MeasureParams = field(default_factory=MeasureParams)

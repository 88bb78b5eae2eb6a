"""Several scans of one tree: links, spanning tree, joint refinement, export.

Public names::

    result = amrst.register_scans([ref, scan2, scan3], reference=0)
    result.T_reference_scan[k]   # (4, 4) world: scan k -> reference
    result.links                 # every pair with verdict and score
    result.paths[k]              # scans from the reference to scan k
"""

from amrst.multiscan.graph import Link
from amrst.multiscan.joint import JointResult
from amrst.multiscan.register import MultiScanResult, register_scans

__all__ = ["JointResult", "Link", "MultiScanResult", "register_scans"]

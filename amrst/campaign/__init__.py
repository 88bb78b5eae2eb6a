"""Campaigns: many trees, each with several scans, registered in batch on Dask.

A campaign is a folder with a manifest (campaign.toml, see
:mod:`amrst.campaign.manifest`), the scans, and ``results/<tree id>/`` per tree plus
``campaign.csv`` (and ``campaign.xlsx``) written by ``amrst batch``.
"""

from amrst.campaign.batch import BatchSummary, run_batch
from amrst.campaign.init import init_campaign
from amrst.campaign.manifest import Campaign, TreeEntry, load_campaign, save_campaign

__all__ = [
    "BatchSummary",
    "Campaign",
    "TreeEntry",
    "init_campaign",
    "load_campaign",
    "run_batch",
    "save_campaign",
]

"""Campaigns: sweeps of effect parameters, operating points, strategies and budgets over the
lockstep bench, run on Dask (this machine or a cluster); see docs/campaigns.md."""

from .runner import CampaignResult, read_table, run_campaign
from .scheduler import DispatchInfo, TaskError, dispatch
from .spec import CampaignSpec, load_spec

__all__ = [
    "CampaignResult",
    "CampaignSpec",
    "DispatchInfo",
    "TaskError",
    "dispatch",
    "load_spec",
    "read_table",
    "run_campaign",
]

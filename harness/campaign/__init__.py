"""Campaigns: many seeded flights of one base scenario over swept keys, as one table.

:mod:`~harness.campaign.spec` (the TOML spec → runs), :mod:`~harness.campaign.run` (one run,
its outcome, its process), :mod:`~harness.campaign.executors` (local processes or Ray),
:mod:`~harness.campaign.results` (results.csv), :mod:`~harness.campaign.campaign` (resume,
progress, summary) and :mod:`~harness.campaign.report` (tables and envelope maps).
"""

from harness.campaign.campaign import CampaignDirError, run_campaign
from harness.campaign.executors import EXECUTORS, ExecutorError
from harness.campaign.run import execute, run_outcome
from harness.campaign.spec import CampaignSpec, SpecError, builtin_specs, load_spec

__all__ = ["EXECUTORS", "CampaignDirError", "CampaignSpec", "ExecutorError", "SpecError",
           "builtin_specs", "execute", "load_spec", "run_campaign", "run_outcome"]

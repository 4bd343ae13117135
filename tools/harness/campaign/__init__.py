"""Campaigns: many seeded flights of one base scenario over swept keys, as one table.

Its modules: :mod:`~tfl_mav.tools.harness.campaign.spec` (the TOML spec → runs),
:mod:`~tfl_mav.tools.harness.campaign.run` (one run, its outcome, its process),
:mod:`~tfl_mav.tools.harness.campaign.executors` (local processes or Ray),
:mod:`~tfl_mav.tools.harness.campaign.results` (results.csv),
:mod:`~tfl_mav.tools.harness.campaign.campaign` (resume, progress, summary) and
:mod:`~tfl_mav.tools.harness.campaign.report` (tables and envelope maps).
"""

from tfl_mav.tools.harness.campaign.campaign import CampaignDirError, run_campaign
from tfl_mav.tools.harness.campaign.executors import EXECUTORS, ExecutorError
from tfl_mav.tools.harness.campaign.run import execute, run_outcome
from tfl_mav.tools.harness.campaign.spec import CampaignSpec, SpecError, builtin_specs, load_spec

__all__ = ["EXECUTORS", "CampaignDirError", "CampaignSpec", "ExecutorError", "SpecError",
           "builtin_specs", "execute", "load_spec", "run_campaign", "run_outcome"]

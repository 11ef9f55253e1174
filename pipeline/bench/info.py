"""`shaderball info`: the figures of a dataset folder (:func:`pipeline.check.info.dataset_info`),
or, given a spec file, its plan without timing (what `shaderball plan SPEC` prints, less the
timed renders: :func:`pipeline.bench.estimate.plan_spec`)."""

from __future__ import annotations

import os

from pipeline.bench.estimate import PlanRequest, plan_spec
from pipeline.check.info import dataset_info
from pipeline.check.request import InfoRequest


def info(request: InfoRequest):
    """The figures of ``request.directory``: a folder's (lines() and to_dict()), or a spec file's plan."""
    if os.path.isfile(request.directory):
        return plan_spec(PlanRequest(spec=request.directory, timing=False))
    return dataset_info(request.directory)

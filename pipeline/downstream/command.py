"""`shaderball study`'s one entry: the pixel study (pipeline.study.run) or, with
``--downstream``, the network's (pipeline.downstream.run, imported only then: it loads torch)."""

from __future__ import annotations

from pipeline.downstream.request import StudyCommandRequest
from pipeline.study.run import run_study


def study_command(request: StudyCommandRequest, *, progress=None, command: str = ""):
    """What the command prints: the pixel study's summary, or the downstream study's."""
    if not request.downstream:
        return run_study(request, progress=progress, command=command)
    from pipeline.downstream.run import run_downstream

    return run_downstream(request, progress=progress, command=command)

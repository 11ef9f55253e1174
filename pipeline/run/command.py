"""`shaderball build`'s one entry: the request handed over whole, what comes back printed."""

from __future__ import annotations

from collections.abc import Callable

from pipeline.errors import Printed
from pipeline.run.build import BuildSummary, Progress, build
from pipeline.run.cluster.connection import job_script
from pipeline.run.request import BuildRequest


def build_command(
    request: BuildRequest,
    *,
    progress: Callable[[Progress], None] | None = None,
    say: Callable[[str], None] | None = None,
) -> BuildSummary | Printed:
    """What `shaderball build` does with ``request``: the batch script each job would run
    (``print_job_script``), or the build; ``say`` hears where the workers are once they are."""
    options = request.cluster_options
    if request.print_job_script:
        script = job_script(options)
        return Printed({"job_script": script}, script)

    def started(where: str, dashboard: str | None) -> None:
        if say is not None:
            say(f"building with {where}" + (f"; dashboard {dashboard}" if dashboard else ""))

    return build(
        request.spec,
        request.out,
        cluster=options,
        allow_spec_change=request.allow_spec_change,
        progress=progress,
        on_start=started,
    )

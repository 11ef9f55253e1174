"""`shaderball build`'s request: the spec, the folder, and where the workers come from (a
:class:`ClusterOptions` part, declared once and nested)."""

from __future__ import annotations

from dataclasses import dataclass

from pipeline.dataset.spec_file import spec_operand
from pipeline.fields import Checked, field, part
from pipeline.fields.rules import Bool, Path
from pipeline.run.cluster.options import ClusterOptions


@dataclass(frozen=True)
class BuildRequest(Checked):
    """What `shaderball build` is asked: the spec, the folder, and where the workers come from."""

    spec: str = spec_operand()
    out: str = field(
        rule=Path("a new or empty folder, or a dataset folder built from the same spec"),
        doc="Dataset folder. Created if missing; an existing one built from the same spec is "
        "resumed (only missing or unverified samples are rendered); another spec is refused.",
        metavar="DIR",
    )
    allow_spec_change: bool = field(
        False,
        rule=Bool(),
        doc="Accept a spec that differs from DIR/spec.toml in dataset.name or dataset.version only "
        "(no sample depends on them); any other difference is refused.",
    )
    cluster_options: ClusterOptions = part(
        ClusterOptions, doc="Where the workers come from: local processes, a scheduler, or batch jobs."
    )
    print_job_script: bool = field(
        False,
        rule=Bool(),
        doc="slurm/pbs: print the batch script each job would run, then exit; nothing is submitted or written.",
    )

    def check_cross(self) -> None:
        if self.print_job_script and self.cluster_options.cluster not in ("slurm", "pbs"):
            raise self.field_error(
                "print_job_script", True, "give {cluster} slurm or {cluster} pbs", what="needs batch jobs"
            )

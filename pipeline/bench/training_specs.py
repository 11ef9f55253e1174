"""Specs whose datasets a downstream study (`shaderball study --downstream`, docs/accuracy.md)
found as good for training the network as the spec it studied, at a fraction of its build
time. `shaderball plan` names the cheaper one beside the studied spec.

Each entry is held to its study by tests/test_training_specs.py: the digest is the studied
spec's as it is now (a changed spec is another dataset, so its entry must be studied again),
the cheaper spec is that spec but for ``render.spp`` (and its name), and the verdict is the
report's own, word for word.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class CheaperForTraining:
    studied: str  # the spec the study ran on
    digest: str  # its spec digest (pipeline.dataset.spec_file.spec_digest)
    cheaper: str  # the spec to build for training instead
    verdict: str  # the study's decision, as its report says it
    report: str  # the study's results page


CHEAPER_FOR_TRAINING = (
    CheaperForTraining(
        studied="manifests/serve.toml",
        digest="363ec07d0548595d2a5b7c1e0cae3dfa324538028a11525e2e884d6558309a83",
        cheaper="manifests/serve-4spp.toml",
        verdict=(
            "4 spp passes (l1): its network is not worse beyond its interval in any figure, at 0.26x the spe"
            "c's build CPU time; relMSE ratio 1.03, at worst 1.12. At most 0.33x: worth a spec of its own."
        ),
        report="docs/results/downstream-64px/report.md",
    ),
)


def cheaper_for_training(digest: str) -> CheaperForTraining | None:
    """The entry of the spec of this digest, or None."""
    return next((entry for entry in CHEAPER_FOR_TRAINING if entry.digest == digest), None)

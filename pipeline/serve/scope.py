"""What the served network learned from: the objects and the light its training dataset held,
and the plain warning the network panel shows for a view outside it.

A network predicts what its training data showed it; the page lets a user pick any object and
any light, and a prediction for a torus under an environment map from a network that only saw
the shaderball under a sun and sky is a picture of nothing it learned. The page must say so
rather than show it as if it were valid.

Where it is read from: the run's config (``dataset_path``, and ``dataset_content.spec_digest``
that identifies the dataset it trained on). The dataset folder (or its publication) at that
path is read, if it is still the one trained on (its dataset.json's ``spec_digest`` is the
run's): its spec's ``[scene] objects`` and ``[lighting] source``, and the digests of its mesh
files and maps (dataset.json's ``sources``). A served ``--dataset`` with that digest is used
the same way where the run's path is gone. Where neither can be read the scope is unknown,
and every view but the default one (the shaderball under the sun and sky, what every network
before objects and maps was trained on) is warned about as such.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass

from pipeline.dataset.spec_file import parse_spec
from pipeline.errors import USER_ERRORS
from pipeline.publish.names import DATASET_DIR, INDEX_FILE
from pipeline.serve.scenes import DEFAULT_OBJECT, ObjectChoice
from pipeline.store.bounded_read import read_bytes
from pipeline.store.layout import Layout
from sky.environment import ENVIRONMENT_SUFFIXES, EnvironmentLight

#: Largest dataset.json read for the scope (the picker reads the same file within this).
DESCRIPTION_BYTES = 1 << 20
SUN_SKY = "sun_sky"
ENVIRONMENT = "environment"


@dataclass(frozen=True)
class TrainingScope:
    """The objects (built-in names, or mesh files by base name and SHA-256) and the light
    source ("sun_sky" or "environment", with its maps by SHA-256 -> base name) a network was
    trained on; ``known`` False where its dataset could not be read (``why`` says so)."""

    known: bool
    objects: tuple[tuple[str, str | None], ...] = ()  # (name, mesh file SHA-256 or None)
    light_source: str | None = None
    environments: tuple[tuple[str, str], ...] = ()  # (SHA-256, base name)
    why: str = ""

    def to_dict(self) -> dict:
        return {
            "known": self.known,
            "objects": [name for name, _ in self.objects],
            "light_source": self.light_source,
            "environments": [name for _, name in self.environments],
            "why": self.why or None,
        }

    def saw_object(self, choice: ObjectChoice) -> bool:
        if choice.sha256 is not None:
            return any(sha == choice.sha256 for _, sha in self.objects)
        return any(name == choice.name and sha is None for name, sha in self.objects)

    def saw_light(self, light) -> bool:
        if not isinstance(light, EnvironmentLight):
            return self.light_source == SUN_SKY
        return self.light_source == ENVIRONMENT and any(sha == light.digest for sha, _ in self.environments)

    def warning(self, choice: ObjectChoice, light) -> str | None:
        """None where the view is inside what the network learned; else one plain sentence."""
        asked = f"{_object_phrase(choice.id)} under {_light_phrase(light)}"
        if not self.known:
            if choice.name == DEFAULT_OBJECT and not isinstance(light, EnvironmentLight):
                return None
            return (
                f"what this network was trained on is not known here ({self.why}); its picture of "
                f"{asked} may be outside what it learned"
            )
        if self.saw_object(choice) and self.saw_light(light):
            return None
        return f"this network was trained on {self._trained()} only; its picture of {asked} is outside what it learned"

    def _trained(self) -> str:
        names = [_object_phrase(name) for name, _ in self.objects] or ["no object"]
        objects = names[0] if len(names) == 1 else ", ".join(names[:-1]) + " and " + names[-1]
        if self.light_source == ENVIRONMENT:
            maps = ", ".join(sorted(name for _, name in self.environments)) or "none"
            return f"{objects} under environment maps ({maps})"
        return f"{objects} under sun and sky"


def _object_phrase(name: str) -> str:
    return "the " + name.replace("_", " ") if name in ("shaderball", "sphere", "rounded_cube", "torus") else name


def _light_phrase(light) -> str:
    if isinstance(light, EnvironmentLight):
        return f"the environment map {os.path.basename(light.file)}"
    return "sun and sky"


def _read_dataset(root: str) -> tuple[dict, object]:
    """(dataset.json, spec) of a dataset folder or its publication."""
    published = os.path.isfile(os.path.join(root, INDEX_FILE))
    layout = Layout(os.path.join(root, DATASET_DIR) if published else root)
    description = json.loads(read_bytes(layout.description, DESCRIPTION_BYTES))
    if not isinstance(description, dict):
        raise ValueError("its dataset.json is not a JSON object")
    return description, parse_spec(layout.spec)


def scope_of(description: dict, spec) -> TrainingScope:
    sources = description.get("sources") if isinstance(description.get("sources"), dict) else {}
    objects = tuple(
        (name, None) if os.path.basename(name) == name else (os.path.basename(name), sources.get(name))
        for name in spec.scene.objects
    )
    maps = tuple(
        sorted(
            (sha, os.path.basename(path))
            for path, sha in sources.items()
            if path.lower().endswith(ENVIRONMENT_SUFFIXES)
        )
    )
    return TrainingScope(True, objects, spec.lighting.source, maps)


def training_scope(config, served_root: str | None = None) -> TrainingScope:
    """The scope of a run whose config is ``config`` (a run's config.json as a dict; None: a
    network with none), read from its dataset or the served one (``served_root``)."""
    if not isinstance(config, dict):
        return TrainingScope(False, why="the network carries no run config")
    content = config.get("dataset_content") if isinstance(config.get("dataset_content"), dict) else {}
    digest = content.get("spec_digest")
    tried = []
    for root in (config.get("dataset_path"), served_root):
        if not isinstance(root, str) or not root:
            continue
        try:
            description, spec = _read_dataset(root)
        except (OSError, ValueError, KeyError, TypeError, *USER_ERRORS) as exc:
            tried.append(f"{root}: {exc}")
            continue
        if digest is None or description.get("spec_digest") == digest:
            return scope_of(description, spec)
        tried.append(f"{root} is another dataset than the one it was trained on")
    why = "; ".join(tried) or "its run names no dataset"
    return TrainingScope(False, why=f"its training dataset cannot be read: {why}")

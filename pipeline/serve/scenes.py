"""What the page may put on stage: the objects and the environment maps `shaderball serve` offers.

The page names an object or a map by an id from /api/info, never by a path: a request can
only pick what the server was started with. That is the built-in objects, the mesh files and
maps given on the command line (``--object PATH``, ``--environment PATH``), and those a served
dataset's spec names (where their files are still here, byte for byte as the dataset
recorded them in dataset.json's ``sources``).

A file given on the command line passes the project's gates at start, before the port is
bound: a mesh through :func:`geometry.objects.build_object` (the mesh-file gate, then the
build: a file it cannot build is refused now, not at the first view), a map through
:func:`pipeline.render.envmap.load_environment` (the map gate: lat-long, bounded, finite,
non-negative). A bad one is refused naming the option, the file and the reason (exit code 2).
A dataset's file that is missing or changed is left out of the offer (logged), not refused:
its samples' materials are still served.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass

from geometry.errors import GeometryError
from geometry.meshfile import MESH_SUFFIXES, file_sha256
from geometry.objects import BUILTIN_OBJECTS, build_object
from pipeline.dataset.spec_file import environment_files
from pipeline.errors import USER_ERRORS
from pipeline.render.envmap import load_environment
from sky.environment import ENVIRONMENT_SUFFIXES, EnvironmentLight, list_environment_files

log = logging.getLogger(__name__)

#: What ``--object`` may be.
OBJECT_ALLOWED = f"a mesh file ({' '.join(MESH_SUFFIXES)}) that passes the mesh-file gate"
#: What ``--environment`` may be.
ENVIRONMENT_ALLOWED = (
    f"a lat-long HDR environment map ({' or '.join(ENVIRONMENT_SUFFIXES)}, width twice the height), or a folder of them"
)
#: The object a view shows when it names none: the page's behaviour before objects could be picked.
DEFAULT_OBJECT = BUILTIN_OBJECTS[0]


class SceneFileRefused(ValueError):
    """A file given to serve that a gate refused: ``option`` names the option, ``path`` the
    file, ``reason`` the gate's message (the server raises it as that option's field error)."""

    def __init__(self, option: str, path: str, reason: str):
        super().__init__(reason)
        self.option, self.path, self.reason = option, path, reason


@dataclass(frozen=True)
class ObjectChoice:
    """An object the page may pick: ``id`` what the page sends; ``name`` what
    :func:`geometry.objects.build_object` takes (a built-in name or an absolute path);
    ``origin``: "built-in", "file" (``--object``) or "dataset"; ``sha256``: a mesh file's."""

    id: str
    name: str
    origin: str
    sha256: str | None = None

    def to_dict(self) -> dict:
        return {"id": self.id, "origin": self.origin, "sha256": self.sha256}


@dataclass(frozen=True)
class EnvironmentChoice:
    """An environment map the page may pick: ``id`` (the file's base name, made unique),
    its absolute ``path`` and the SHA-256 of its bytes when it passed the gate."""

    id: str
    path: str
    sha256: str
    origin: str  # "file" (--environment) or "dataset"

    def light(self, rotation_deg: float, intensity: float) -> EnvironmentLight:
        return EnvironmentLight(self.path, self.sha256, rotation_deg, intensity)

    def to_dict(self) -> dict:
        return {"id": self.id, "origin": self.origin, "sha256": self.sha256}


@dataclass(frozen=True)
class Scenes:
    """Every object and map the server offers, by id, in the order the page lists them."""

    objects: dict[str, ObjectChoice]
    environments: dict[str, EnvironmentChoice]

    def listing(self) -> dict:
        return {
            "objects": [o.to_dict() for o in self.objects.values()],
            "environments": [e.to_dict() for e in self.environments.values()],
            "default_object": DEFAULT_OBJECT,
        }


def _unique(base: str, taken) -> str:
    """``base``, or ``base (2)``, ``base (3)``, ... where an id is taken (two files of one name)."""
    name, n = base, 1
    while name in taken:
        n += 1
        name = f"{base} ({n})"
    return name


def gate_object(path: str) -> ObjectChoice:
    """A mesh file given with ``--object``, built through the gate (cached; no Mitsuba)."""
    path = os.path.abspath(path)
    try:
        build_object(path)
        return ObjectChoice(os.path.basename(path), path, "file", file_sha256(path))
    except (GeometryError, OSError) as exc:
        raise SceneFileRefused("object", path, str(exc)) from None


def gate_environments(path: str) -> list[tuple[str, str]]:
    """The maps ``--environment`` ``path`` names (a file, or a folder's maps), each read whole
    through the map gate: [(absolute path, SHA-256)]."""
    try:
        files = list_environment_files([path])
    except USER_ERRORS as exc:
        raise SceneFileRefused("environment", os.path.abspath(path), str(exc)) from None
    out = []
    for file in files:
        try:
            out.append((file, load_environment(file).digest))
        except USER_ERRORS as exc:
            raise SceneFileRefused("environment", file, str(exc)) from None
    return out


def _dataset_files(spec, sources: dict) -> tuple[list[ObjectChoice], list[tuple[str, str]]]:
    """A served dataset's mesh files and maps that are here as it recorded them."""
    meshes, maps = [], []
    recorded = sources if isinstance(sources, dict) else {}
    try:
        env_files = environment_files(spec)
    except USER_ERRORS as exc:
        log.info("the dataset's environment maps are not offered: %s", exc)
        env_files = ()
    for name in spec.scene.objects:
        if name in BUILTIN_OBJECTS:
            meshes.append(ObjectChoice(name, name, "dataset"))
        elif _here_as_recorded(name, recorded):
            meshes.append(ObjectChoice(os.path.basename(name), name, "dataset", recorded[name]))
    for file in env_files:
        if _here_as_recorded(file, recorded):
            maps.append((file, recorded[file]))
    return meshes, maps


def _here_as_recorded(path: str, recorded: dict) -> bool:
    try:
        same = path in recorded and os.path.isfile(path) and file_sha256(path) == recorded[path]
    except OSError:
        same = False
    if not same:
        log.info("%s: named by the dataset but not here as it recorded it: not offered", path)
    return same


def open_scenes(object_files=(), environment_paths=(), dataset=None) -> Scenes:
    """What the server offers: the built-ins, then ``object_files`` and ``environment_paths``
    (each through its gate: :class:`SceneFileRefused`), then ``dataset``'s (a
    :class:`pipeline.serve.materials.DatasetSamples`) files that are here as it recorded them."""
    objects: dict[str, ObjectChoice] = {name: ObjectChoice(name, name, "built-in") for name in BUILTIN_OBJECTS}
    maps: dict[str, EnvironmentChoice] = {}
    file_objects = [gate_object(path) for path in object_files]
    file_maps = [(f, d, "file") for path in environment_paths for f, d in gate_environments(path)]
    dataset_objects, dataset_maps = ([], []) if dataset is None else _dataset_files(dataset.spec, dataset.sources)
    for choice in [*file_objects, *dataset_objects]:
        if any(o.name == choice.name for o in objects.values()):
            continue  # a built-in the dataset names, or a file given twice
        objects[_unique(choice.id, objects)] = ObjectChoice(
            _unique(choice.id, objects), choice.name, choice.origin, choice.sha256
        )
    for path, digest, origin in [*file_maps, *((f, d, "dataset") for f, d in dataset_maps)]:
        if any(m.path == path for m in maps.values()):
            continue
        key = _unique(os.path.basename(path), maps)
        maps[key] = EnvironmentChoice(key, path, digest, origin)
    return Scenes(objects, maps)

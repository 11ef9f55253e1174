"""Where a sample's files are read: a dataset folder (:class:`FolderFiles`, each path checked
to lie inside, each file read only at the size the manifest records) or a publication that
passed the reader (:class:`PublishedFiles`, each member read again at its checked offset in
its tar); and a publication's refusal as a user error of the training stage."""

from __future__ import annotations

import os

from pipeline.errors import ShaderballError, quoted
from pipeline.fields import FieldError
from pipeline.neural.config import A_DATASET, TrainConfig
from pipeline.publish.reader import Located, read_located
from pipeline.publish.refusal import Refused
from pipeline.store.bounded_read import OverBound, Recorded, UnsafePath, read_bytes, resolve_inside
from pipeline.store.layout import MANIFEST_FILE


def safe_path(root: str, rel: str) -> str:
    """``rel`` (a manifest path) inside ``root`` (pipeline.store.bounded_read.resolve_inside: no
    ``..``, not absolute, through no symbolic link), or a ShaderballError naming it."""
    try:
        return resolve_inside(root, rel)
    except UnsafePath as exc:
        raise ShaderballError(
            f"manifest: file path {quoted(rel)} is refused: {exc.strerror} (the dataset folder "
            f"{quoted(root)} must hold it; check it with `shaderball validate`)"
        ) from None


def dataset_refused(root: str, what: str, allowed: str = A_DATASET) -> FieldError:
    """``root``, the command's dataset (the field ``dataset``), refused: ``what`` is wrong
    with it, ``allowed`` says what to do."""
    return TrainConfig.field_error("dataset", root, allowed, what=what)


class FolderFiles:
    """The files of a dataset folder; a file's key is its manifest path, checked to lie inside
    (the path itself: no second string a sample)."""

    kind = "dataset folder"
    checker = "`shaderball validate`"

    def __init__(self, root: str):
        self.root = root

    def key(self, rel: str) -> str:
        safe_path(self.root, rel)
        return rel

    def path(self, key: str) -> str:
        return os.path.join(self.root, *key.split("/"))

    def read(self, key: str, size: int) -> bytes:
        """The file's bytes, read only at ``size``, the manifest's (a grown file is not read)."""
        try:
            return read_bytes(safe_path(self.root, key), Recorded(size, MANIFEST_FILE))
        except OverBound as exc:  # validate's size_mismatch, in its words
            raise ShaderballError(
                f"{self.path(key)}: {exc.strerror}; check the folder with `shaderball validate`"
            ) from None
        except OSError as exc:
            raise ShaderballError(
                f"{self.path(key)} cannot be read ({exc.strerror}); check the folder with `shaderball validate`"
            ) from None

    def label(self, key: str) -> str:
        return self.path(key)

    def changed(self, key: str) -> ShaderballError:
        return ShaderballError(
            f"{self.path(key)} does not match its SHA-256 in the manifest; repair the folder with "
            "`shaderball validate --repair`"
        )


class PublishedFiles:
    """The files of a publication that passed :meth:`pipeline.publish.reader.Publication.locate`;
    a file's key is its path in the dataset folder's layout, its bytes lie in a tar."""

    kind = "publication"
    checker = "`shaderball unpack`, which validates what it unpacks"

    def __init__(self, root: str, located: dict[str, Located]):
        self.root = root
        self.located = located

    def key(self, rel: str) -> str:
        if rel not in self.located:  # the reader checked every manifest path: not reached
            raise ShaderballError(f"{rel} is in no tar of the publication {quoted(self.root)}")
        return rel

    def read(self, key: str, size: int) -> bytes:
        """The member's bytes at its checked offset: ``size``, the manifest's, as the reader
        checked the member's (pipeline.publish.reader.read_located reads no more)."""
        try:
            if self.located[key].size != size:  # the reader checked it: not reached
                raise Refused("changed", f"{self.label(key)}: {self.located[key].size} bytes, the manifest says {size}")
            return read_located(self.root, self.located[key], check_sha256=False)
        except Refused as exc:  # read in a loader's worker, maybe: an error torch rebuilds from its message
            raise ShaderballError(
                f"{self.label(key)}: the publication does not verify ({exc.kind}): {exc.message}; check it with "
                "`shaderball verify`"
            ) from None
        except OSError as exc:
            raise ShaderballError(
                f"{self.label(key)} cannot be read ({exc.strerror}); check the publication with `shaderball verify`"
            ) from None

    def label(self, key: str) -> str:
        at = self.located[key]
        return f"{os.path.join(self.root, at.tar)}: member {at.name}"

    def changed(self, key: str) -> ShaderballError:
        return ShaderballError(
            f"{self.label(key)} does not match its SHA-256 in the manifest: the "
            "publication changed since it was verified; check it with `shaderball verify`"
        )


def refused(root: str, exc: Refused) -> ShaderballError:
    """A publication the reader refuses, as a user error of the training stage (exit code 2):
    when it is opened, naming the dataset; a file read later, naming the publication."""
    what = f"{quoted(root)} is a publication that does not verify ({exc.kind}): {exc.message}"
    return dataset_refused(root, what, "check it with `shaderball verify`")

"""The rules a spec file's sections share: the refusal naming ``file: section.field``
(:class:`SpecError`), the section mixin that raises it, and the rules of the keys that name
files and folders (SVBRDF folders, mesh files, environment maps), checked when a spec is read.
Pure: it looks at the filesystem, nothing else.
"""

from __future__ import annotations

import json
import os
from typing import Any, ClassVar

from pipeline.fields import Checked, FieldError
from pipeline.fields.rules import Reject, StrList

#: File suffixes (lower case) of imported SVBRDF map files, as in Deschaintre et al. 2018's
#: dataset (one PNG per material with the maps side by side).
SVBRDF_IMPORT_SUFFIXES: tuple[str, ...] = (".png",)


class SpecError(FieldError):
    """A bad spec field: names the file, the field, the value and what is allowed."""

    def __init__(
        self,
        section: str,
        field_name: str,
        value: Any,
        allowed: str,
        source: str | None = None,
        *,
        what: str | None = None,
    ):
        self.section = section
        self.field_name = field_name
        self.source = source
        where = f"{section}.{field_name}" if field_name else f"[{section}]"
        prefix = f"{source}: " if source else ""
        super().__init__(prefix + where, value, allowed, what=what, name=field_name)
        self.what = what

    def with_source(self, source: str) -> SpecError:
        return SpecError(self.section, self.field_name, self.value, self.allowed, source, what=self.what)


def list_files_with(folder: str, suffixes: tuple[str, ...]) -> tuple[str, ...]:
    """Sorted names (not paths) of the files directly in ``folder`` with one of ``suffixes``."""
    try:
        names = os.listdir(folder)
    except OSError:
        return ()
    return tuple(
        sorted(
            n
            for n in names
            if not n.startswith(".")
            and os.path.splitext(n)[1].lower() in suffixes
            and os.path.isfile(os.path.join(folder, n))
        )
    )


class Folders(StrList):
    def __init__(self):
        super().__init__(
            None,
            "existing folders (relative paths are taken from the spec "
            "file's folder), each holding at least one " + "/".join(SVBRDF_IMPORT_SUFFIXES) + " map file",
        )

    def check(self, value):
        value = super().check(value)
        for folder in value:
            if not folder or not os.path.isdir(folder):
                raise Reject(f"({json.dumps(folder)} is not a folder)")
            if not list_map_files(folder):
                raise Reject(f"({json.dumps(folder)} holds no " + "/".join(SVBRDF_IMPORT_SUFFIXES) + " file)")
        return value


def list_map_files(folder: str) -> tuple[str, ...]:
    """Sorted names (not paths) of the importable SVBRDF map files directly in ``folder``."""
    return list_files_with(folder, SVBRDF_IMPORT_SUFFIXES)


class Section(Checked):
    """Mixin: a spec section, checked when built; a refusal names ``section.field``."""

    SECTION: ClassVar[str]

    @classmethod
    def field_error(cls, name: str, value: Any, allowed: str, *, what: str | None = None) -> SpecError:
        return SpecError(cls.SECTION, name, value, allowed, what=what)


class Files(StrList):
    """A list of existing files with given suffixes, or (``folders``) folders holding some;
    ``names``: bare words also allowed (built-in objects). Relative paths are the spec
    folder's (made absolute when the spec is read, :mod:`pipeline.dataset.spec_file`)."""

    def __init__(self, suffixes: tuple[str, ...], what: str, *, names: tuple[str, ...] = (), folders: bool = False):
        self.suffixes, self.names, self.folders = suffixes, names, folders
        words = (", ".join(json.dumps(n) for n in names) + " or ") if names else ""
        kinds = "/".join(suffixes) + " files" + (" or folders holding some" if folders else "")
        super().__init__(None, what, doc_allowed=f"a list of distinct {words}{kinds}")

    @property
    def allowed(self) -> str:
        return self.doc_allowed

    def check(self, value):
        value = super().check(value)
        for item in value:
            if item in self.names:
                continue
            if self.folders and os.path.isdir(item):
                if not list_files_with(item, self.suffixes):
                    raise Reject(f"({json.dumps(item)} holds no " + "/".join(self.suffixes) + " file)")
                continue
            if os.path.splitext(item)[1].lower() not in self.suffixes:
                raise Reject(f"({json.dumps(item)} is neither a name nor a " + "/".join(self.suffixes) + " file)")
            if not os.path.isfile(item):
                raise Reject(f"({json.dumps(item)} is not a file)")
        return value

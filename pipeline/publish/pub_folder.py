"""PUB, the folder a publish writes: checked (new or empty) and held while it is written
(:func:`held_publication`), and what a publish killed mid-way left there, which the next one
clears (:func:`partial_publication`: its lock file beside only files publish writes)."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Callable

from pipeline.publish.names import DATASET_DIR, SUMS_FILE, allowed_file
from pipeline.publish.output import check_out, held_output
from pipeline.store.folder import is_temp_file, real_dir
from pipeline.store.layout import LOCK_FILE, SHARDS_DIR
from pipeline.store.lock import holder_text, stale_holder

#: How publish's messages name its output folder.
PUB_LABEL = "PUB"


# --------------------------------------------------------------------------- PUB, and a killed publish's


@contextlib.contextmanager
def held_publication(out: str, root: str, progress: Callable[[str], None] | None):
    """PUB checked (new or empty; pipeline.publish.output) and held for writing while the block
    writes it: (the Output, what it replaced). A PUB that holds only what a publish killed
    mid-way left (:func:`partial_publication`) is cleared first, saying so through
    ``progress``; what it replaced is that message, else None."""
    holder = partial_publication(out)
    check_out(out, root, PUB_LABEL, leftover=lambda _out: holder is not None)
    clear = None
    if holder is not None:
        replaced = f"found a partial publication (killed {holder_text(holder)}): replacing it"

        def clear(folder: str) -> bool:
            leftovers = publication_leftovers(folder)
            if leftovers is None:
                return False  # something else came in meanwhile: refused as filled
            if progress:
                progress(f"{folder}: {replaced}")
            for rel in leftovers:  # files, then their folders (each only if empty)
                path = os.path.join(folder, *rel.split("/"))
                if rel in (DATASET_DIR, SHARDS_DIR):
                    with contextlib.suppress(OSError):  # not empty: another process wrote into it
                        os.rmdir(path)
                else:
                    with contextlib.suppress(FileNotFoundError):
                        os.unlink(path)
            return True

    with held_output(out, "publish", PUB_LABEL, clear=clear) as output:
        yield output, (replaced if holder is not None else None)


def partial_publication(out: str) -> dict | None:
    """The description (pipeline.store.lock) of the publish that was killed while it wrote
    ``out``, when ``out`` holds nothing else: its lock file, left by a ``publish`` that is gone
    (:func:`pipeline.store.lock.stale_holder`), beside files publish writes (a publication's,
    temporary ones). Else None. (SHA256SUMS is written last, but a publish killed after it,
    before it let the folder go, did not finish either: the lock file is no publication's.)"""
    if not real_dir(out):
        return None
    holder = stale_holder(out)
    if holder is None or holder.get("purpose") != "publish" or publication_leftovers(out) is None:
        return None
    return holder


def publication_leftovers(out: str) -> list[str] | None:
    """What is in ``out`` besides its lock file, relative to it (files first, then the folders
    ``dataset`` and ``shards``), when each is something publish writes: a regular file of a
    publication (pipeline.publish.names), or a temporary file (pipeline.store.atomic), at the
    places publish puts them. Else None."""
    files, folders = [], []
    for sub in ("", DATASET_DIR, SHARDS_DIR):
        folder = os.path.join(out, sub)
        if sub:
            if not os.path.lexists(folder):
                continue
            if not real_dir(folder):
                return None
            folders.append(sub)
        with os.scandir(folder) as entries:
            for entry in entries:
                rel = f"{sub}/{entry.name}" if sub else entry.name
                if not sub and entry.name in (LOCK_FILE, DATASET_DIR, SHARDS_DIR):
                    continue
                ours = is_temp_file(entry.name) or allowed_file(rel) or rel == SUMS_FILE
                if not ours or not entry.is_file(follow_symlinks=False):
                    return None
                files.append(rel)
    return files + folders

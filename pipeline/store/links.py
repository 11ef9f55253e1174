"""No output through a link: what a command writes into a folder (a run folder, a dataset
folder, an output folder) is refused when its path is, or passes through, a symbolic link
inside that folder, before anything is written.

A link there sends the writes elsewhere (``RUN/evaluation-all -> /elsewhere`` would receive
results.json, results.md and grid.png), or has an atomic rename replace the link by a file
the user did not expect. The folder itself (``RUN``, ``DIR``, an ``out`` folder) may be a link:
the user named it. What is checked is every component below it, the last one included.

:func:`link_below` says why one path may not be written (None when it may); the commands
check every path they will write before they start (each refuses it as its own request's
field), and :func:`pipeline.store.atomic.atomic_file` checks again at the write
(``inside=``): :class:`ThroughLink`. A process that can write the folder could still swap a
component for a link between the check and the rename; such a writer can write the data
itself anyway.
"""

from __future__ import annotations

import os
import stat

from pipeline.errors import ShaderballError


class ThroughLink(ShaderballError):
    """A write refused because its path is, or passes through, a symbolic link inside the
    folder it writes into (exit 2, nothing written)."""


def _same(a: str, b: str) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def _inside(root: str, path: str) -> list[str] | None:
    """The components of ``path`` below ``root`` (however either is spelled: the first prefix
    of ``path`` that is the folder ``root`` is), or None when ``path`` is not inside it."""
    root_abs, target = os.path.abspath(root), os.path.abspath(path)
    rel = os.path.relpath(target, root_abs)
    if rel == os.curdir:
        return []
    if rel != os.pardir and not rel.startswith(os.pardir + os.sep):
        return rel.split(os.sep)
    if not os.path.isdir(root_abs):
        return None
    parts = target.split(os.sep)
    for n in range(len(parts) - 1, 0, -1):
        prefix = os.sep.join(parts[:n]) or os.sep
        if _same(prefix, root_abs):
            return parts[n:]
    return None


def link_below(root: str, path: str) -> str | None:
    """Why writing ``path`` would go through a symbolic link inside the folder ``root``: the
    first component of ``path`` below ``root`` (``path`` itself included) that is a link, said
    with its target; None when none is, when a component does not exist yet (it will be made,
    as a real folder or file) or when ``path`` is not inside ``root``."""
    parts = _inside(root, path)
    if not parts:
        return None
    walk = os.path.abspath(root)
    for part in parts:
        walk = os.path.join(walk, part)
        try:
            mode = os.lstat(walk).st_mode
        except OSError:
            return None  # not there yet (or not a folder: the write reports that)
        if stat.S_ISLNK(mode):
            try:
                target = os.readlink(walk)
            except OSError:
                target = "?"
            return f"{walk} is a symbolic link (to {target!r}) inside {root}: nothing is written through a link"
    return None


def first_link(roots, paths) -> tuple[str, str] | None:
    """(path, why) of the first of ``paths`` that :func:`link_below` refuses in any of
    ``roots`` (None when every one may be written)."""
    for path in paths:
        for root in roots:
            if root is None:
                continue
            why = link_below(root, path)
            if why:
                return path, why
    return None


def refuse_link(root: str, path: str) -> None:
    """:class:`ThroughLink` naming ``path`` when :func:`link_below` refuses it."""
    why = link_below(root, path)
    if why:
        raise ThroughLink(f"{path}: not written: {why}; remove the link and run the command again")

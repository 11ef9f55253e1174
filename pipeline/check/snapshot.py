"""The spec a dataset folder was built from: its snapshot ``DIR/spec.toml``, read through
:mod:`pipeline.store.folder` and checked by :mod:`pipeline.dataset.spec`, or a publication's
(verified) copy of it; and how two specs differ. Read by the checks, by a resumed build
(:mod:`pipeline.run.build`), by the publisher and by `evaluate --reference`."""

from __future__ import annotations

import os

from pipeline.dataset.spec import DatasetSpec
from pipeline.dataset.spec_file import parse_spec_bytes, spec_to_dict
from pipeline.errors import ShaderballError
from pipeline.store.folder import read_spec_snapshot
from pipeline.store.layout import Layout


def read_snapshot(root: str) -> DatasetSpec:
    """The spec snapshot ``DIR/spec.toml`` of a dataset folder: a regular file (not a link, a
    FIFO or a device; pipeline.store.folder), bounded, parsed; ShaderballError if not."""
    layout = Layout(root)
    try:
        data = read_spec_snapshot(layout)
    except FileNotFoundError:
        raise ShaderballError(f"{layout.spec}: missing") from None
    except OSError as exc:
        raise ShaderballError(f"{layout.spec}: cannot be read ({exc.strerror})") from None
    return parse_spec_bytes(data, source=layout.spec, base_dir=os.path.abspath(root))


def published_snapshot(data: bytes, root: str) -> DatasetSpec:
    """A publication's copy of the spec (``dataset/spec.toml``, its bytes already verified)."""
    return parse_spec_bytes(data, source=os.path.join(root, "dataset", "spec.toml"), base_dir=os.path.abspath(root))


def spec_differences(old: DatasetSpec, new: DatasetSpec) -> list[tuple[str, str, object, object]]:
    """(section, key, old value, new value) for every field that differs."""
    a, b = spec_to_dict(old), spec_to_dict(new)
    return [
        (section, key, a[section].get(key), b[section].get(key))
        for section in a
        for key in a[section]
        if a[section].get(key) != b[section].get(key)
    ]

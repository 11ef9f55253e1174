"""A checkpoint's tensors checked from their metadata, before any tensor is made or touched.

A checkpoint is untrusted input. Its zip archive is bounded first (its size and members:
:func:`pipeline.neural.run_checks.checkpoint_archive_problem`); but a tensor in it is
described by its storage (a member of the archive, bounded) *and* by a shape, strides and
an offset into that storage, which nothing bounds: a storage of 4 values with shape
``(2**40,)`` and stride ``(0,)`` is a few bytes in the file, and anything that reads it whole
(``torch.isfinite``) allocates 4 TiB. So every tensor is checked here, from the archive's
``data.pkl`` alone, against the architecture (the network the run's config describes, built
on the meta device or given), before ``torch.load`` is called:

- the names of the weights are the network's state dict's, no more, no fewer; each one's dtype
  and shape are the network's (:class:`Architecture`); Adam's state, where the checkpoint holds
  it, is one entry per parameter of the network (``step`` a scalar, the moments of the
  parameter's shape), of the parameter's dtype;
- its strides describe one dense layout of that shape (each value once: no stride 0, no
  overlap, no gap; a permutation of the dimensions, such as channels-last, is one), its
  offset and extent lie inside its storage;
- its storage is a member ``data/<key>`` of the archive of exactly ``numel x itemsize`` bytes;
- no tensor or storage is anywhere else in the file, and nothing but the globals
  ``torch.save`` writes for these (``torch._utils._rebuild_tensor_v2``,
  ``collections.OrderedDict`` for its empty backward hooks, ``torch.<Type>Storage``) is named.

Why a reader of our own, and which: ``data.pkl`` is read by the standard library's
pure-Python unpickler (``pickle._Unpickler``) whose ``find_class`` answers only those globals,
each with a stand-in that records its arguments and calls nothing of torch, and whose
``persistent_load`` records a storage's key, dtype and size without reading it. Nothing is
allocated beyond the Python objects the pickle itself spells (bounded by its size, itself
bounded by the archive's budget). The C unpickler is not used: its memo is an array that one
``LONG_BINPUT`` of index 2**32 resizes to 32 GiB. ``torch.load(weights_only=True)`` is not the
first reader either: its allow-list holds calls that allocate from one integer
(``bytearray(n)``), and reading on the meta device still runs it.

Only a checkpoint that passes is read by ``torch.load``, from the file descriptor checked
(``/proc/self/fd``: the same file, whatever is renamed meanwhile), with ``mmap=True`` (the
storages are the file's own pages: nothing torch's reader does can allocate a storage
larger than the file) and ``weights_only=True``; then every tensor it returned is compared
with the one checked (dtype, shape, strides, offset, storage size; none elsewhere), so the two
readers must agree before any value is read, and is copied out of the mapping.
"""

from __future__ import annotations

import collections
import io
import math
import pickle
import reprlib
import zipfile
from dataclasses import dataclass

import torch

#: The storage classes torch.save names in a checkpoint, by the name it spells, and their dtype.
STORAGE_DTYPES = {
    "FloatStorage": torch.float32,
    "DoubleStorage": torch.float64,
    "HalfStorage": torch.float16,
    "BFloat16Storage": torch.bfloat16,
    "LongStorage": torch.int64,
    "IntStorage": torch.int32,
    "ShortStorage": torch.int16,
    "CharStorage": torch.int8,
    "ByteStorage": torch.uint8,
    "BoolStorage": torch.bool,
}
#: Largest data.pkl read (a 100,000-epoch history pickles to ~40 MB).
MAX_PICKLE_BYTES = 64 << 20
#: Deepest nesting walked (a checkpoint's is 4: ``optimizer['state'][0]['exp_avg']``).
MAX_DEPTH = 16
#: Names listed in a message at most (then a count).
SHOWN = 4
#: Integers a checkpoint holds are 64-bit (torch's sizes, strides and offsets; Adam's indices).
INT64 = (-(2**63), 2**63 - 1)
#: An integer of at least this size is shown by its number of digits: Python refuses to print
#: one of over 4,300 digits (ValueError), so a message that names it would itself fail.
SHOWN_INT = 10**20


class CheckpointRefused(Exception):
    """Why a checkpoint's content cannot be used. ``fits`` False: the weights are of another
    network (names, dtypes, shapes: 'the weights do not fit'); True: the file is corrupt."""

    def __init__(self, text: str, fits: bool = True):
        super().__init__(text)
        self.text, self.fits = text, fits


@dataclass(frozen=True)
class Architecture:
    """What a checkpoint of one network holds: each weight's (dtype, shape) by name, and each
    parameter's, in the optimizer's order (``model.parameters()``)."""

    weights: dict
    parameters: list

    @classmethod
    def of(cls, model: torch.nn.Module) -> Architecture:
        """The network's state dict and parameters (a network on the meta device will do)."""
        weights = {name: (t.dtype, tuple(t.shape)) for name, t in model.state_dict().items()}
        parameters = [(t.dtype, tuple(t.shape)) for t in model.parameters()]
        return cls(weights, parameters)


@dataclass(frozen=True)
class StorageRef:
    """A storage as data.pkl names it: nothing read."""

    key: object
    dtype: torch.dtype
    numel: object
    location: object


class TensorRef:
    """A tensor as data.pkl describes it: ``_rebuild_tensor_v2``'s arguments, unchecked."""

    __slots__ = ("args",)

    def __init__(self, args: tuple):
        self.args = args


def _rebuild_tensor(*args) -> TensorRef:
    """The stand-in of ``torch._utils._rebuild_tensor_v2``: its arguments, recorded."""
    return TensorRef(args)


class _StorageClass:
    __slots__ = ("dtype",)

    def __init__(self, dtype):
        self.dtype = dtype


class _Reader(pickle._Unpickler):
    """The pure-Python unpickler, answering only the globals a checkpoint holds, with stand-ins."""

    def find_class(self, module, name):
        if (module, name) == ("torch._utils", "_rebuild_tensor_v2"):
            return _rebuild_tensor
        if (module, name) == ("collections", "OrderedDict"):
            return collections.OrderedDict
        if module == "torch" and name in STORAGE_DTYPES:
            return _StorageClass(STORAGE_DTYPES[name])
        raise CheckpointRefused(f"data.pkl names {module}.{name}, which no checkpoint of this network holds")

    def persistent_load(self, pid):
        if not (isinstance(pid, tuple) and len(pid) == 5 and pid[0] == "storage"):
            raise CheckpointRefused(f"data.pkl names a persistent object {_short(pid)}, not a storage")
        _kind, cls, key, location, numel = pid
        if not isinstance(cls, _StorageClass):
            raise CheckpointRefused(f"data.pkl names a storage of type {_short(cls)}")
        return StorageRef(key, cls.dtype, numel, location)


def int_text(value: int) -> str:
    """``value`` in decimal, or, from SHOWN_INT on, its size: never fails, whatever its size."""
    if -SHOWN_INT < value < SHOWN_INT:
        return str(value)
    # digits of |value| from its bits: exact for powers of ten, else one more at most
    digits = math.floor(abs(value).bit_length() * math.log10(2)) + 1
    return ("minus " if value < 0 else "") + f"an integer of about {digits:,} digits"


class _Bounded(reprlib.Repr):
    """reprlib's bounded repr (a few items of a container, the start of a string), with
    integers shown by :func:`int_text` (reprlib's own converts them whole first)."""

    def __init__(self):
        super().__init__()
        self.maxstring = self.maxother = 40

    def repr_int(self, value, level):
        return int_text(value)

    def repr_OrderedDict(self, value, level):
        return self.repr_dict(value, level)


def shown(value, limit: int = 80) -> str:
    """``value`` from an untrusted file, for a message: at most ``limit`` characters, and
    never an exception (an integer of any size, a container of any length or depth)."""
    text = _Bounded().repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


_short = shown


def _name(path: tuple) -> str:
    """A place in the checkpoint as Python spells it: ``model['enc.0.weight']``."""
    return path[0] + "".join(f"[{shown(key)}]" for key in path[1:]) if path else "the checkpoint"


def is_int(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_count(value) -> bool:
    """An integer >= 0 that torch holds as an int64 (a size, a stride, an offset)."""
    return is_int(value) and 0 <= value <= INT64[1]


def _int64_problem(value, path: tuple) -> str | None:
    if is_int(value) and not INT64[0] <= value <= INT64[1]:
        return f"{_name(path)} is {int_text(value)}, beyond the 64-bit integers a checkpoint holds"
    return None


_LEAVES = (str, bytes, int, float, bool, type(None))


def _walk(root):
    """(path, value) of every tensor or storage in ``root``, top down (a container reached twice
    is walked once: a pickle can share one, or hold itself); anything but plain data refused."""
    found, seen, stack = [], set(), [((), root)]
    while stack:
        path, value = stack.pop()
        if isinstance(value, (TensorRef, StorageRef, torch.Tensor, torch.TypedStorage, torch.UntypedStorage)):
            found.append((path, value))
            continue
        if isinstance(value, _LEAVES):
            problem = _int64_problem(value, path)
            if problem:
                raise CheckpointRefused(problem)
            continue
        if type(value) not in (dict, collections.OrderedDict, list, tuple) or getattr(value, "__dict__", None):
            raise CheckpointRefused(f"{_name(path)} is a {type(value).__name__}, which no checkpoint holds")
        if id(value) in seen:
            continue
        seen.add(id(value))
        if len(path) >= MAX_DEPTH:
            raise CheckpointRefused(f"{_name(path[:4])}...: nested deeper than a checkpoint is ({MAX_DEPTH} levels)")
        items = value.items() if isinstance(value, dict) else enumerate(value)
        children = []
        for key, child in items:
            if not isinstance(key, (str, int)) or isinstance(key, bool):
                raise CheckpointRefused(f"{_name(path)} has a key {_short(key)}, not a name or a number")
            if _int64_problem(key, ()):
                raise CheckpointRefused(
                    f"{_name(path)} has a key {int_text(key)}, beyond the 64-bit integers a checkpoint holds"
                )
            children.append((path + (key,) if path else (str(key),), child))
        stack.extend(reversed(children))
    return found


def read_tensor_refs(archive: zipfile.ZipFile) -> tuple[object, dict]:
    """(what data.pkl holds, with stand-ins for tensors; {path: TensorRef} of every tensor in
    it) from the checkpoint's data.pkl alone (:class:`_Reader`); CheckpointRefused when it
    holds anything a checkpoint does not, or a tensor whose storage is not its record."""
    pickles = [m for m in archive.infolist() if m.filename.endswith("/data.pkl") and m.filename.count("/") == 1]
    if len(pickles) != 1:
        raise CheckpointRefused(f"{len(pickles)} data.pkl records, where torch.save writes one")
    member = pickles[0]
    if member.file_size > MAX_PICKLE_BYTES:
        raise CheckpointRefused(f"data.pkl of {member.file_size} bytes, over the {MAX_PICKLE_BYTES} a checkpoint holds")
    prefix = member.filename[: -len("data.pkl")]
    order = _member_bytes(archive, prefix + "byteorder", 16)
    if order not in (None, b"little"):
        raise CheckpointRefused(f"byteorder {_short(order)}: torch.save here writes little-endian storages")
    try:
        root = _Reader(io.BytesIO(archive.read(member)), encoding="utf-8").load()  # as torch.load reads it
    except CheckpointRefused:
        raise
    except Exception as exc:  # a torn or hand-made pickle raises any of several types
        raise CheckpointRefused(f"data.pkl is not a pickle this reader accepts ({type(exc).__name__})") from None
    sizes = {m.filename: m.file_size for m in archive.infolist()}
    tensors, storages = {}, {}
    for path, value in _walk(root):
        if not isinstance(value, TensorRef):
            raise CheckpointRefused(f"{_name(path)} is a storage outside any tensor")
        storage_problem = _storage_problem(value, prefix, sizes)
        if storage_problem:
            raise CheckpointRefused(f"tensor {_name(path)}: {storage_problem}")
        storage = value.args[0]
        # torch.load keeps the first reading of a key: another dtype or size for it would be read as the first
        if storages.setdefault(storage.key, (storage.dtype, storage.numel)) != (storage.dtype, storage.numel):
            raise CheckpointRefused(f"tensor {_name(path)}: its storage data/{storage.key} is named twice, differently")
        tensors[path] = value
    return root, tensors


def _member_bytes(archive: zipfile.ZipFile, name: str, limit: int) -> bytes | None:
    try:
        info = archive.getinfo(name)
    except KeyError:
        return None
    return archive.read(info) if info.file_size <= limit else b"(too long)"


def _storage_problem(tensor: TensorRef, prefix: str, sizes: dict) -> str | None:
    """Why a tensor's storage is not a member of the archive holding exactly its values."""
    if not tensor.args or not isinstance(tensor.args[0], StorageRef):
        return "its storage is not one of the archive's"
    storage = tensor.args[0]
    if not isinstance(storage.key, str) or not storage.key.isascii() or not storage.key.isalnum():
        return f"its storage's key {_short(storage.key)} is not a record name"
    if not isinstance(storage.location, str) or len(storage.location) > 32:
        return f"its storage's location {_short(storage.location)} is not a device"
    if not _is_count(storage.numel):
        return f"its storage's size {_short(storage.numel)} is not a count (an integer from 0 to 2**63-1)"
    record = f"{prefix}data/{storage.key}"
    if record not in sizes:
        return f"its storage data/{storage.key} is not in the archive"
    nbytes = storage.numel * storage.dtype.itemsize
    if sizes[record] != nbytes:
        return (
            f"its storage claims {storage.numel} {_dtype(storage.dtype)} values ({nbytes} bytes), "
            f"its record data/{storage.key} holds {sizes[record]} bytes"
        )
    return None


def _dtype(dtype) -> str:
    return str(dtype).removeprefix("torch.")


def layout_problem(tensor: TensorRef) -> str | None:
    """Why ``_rebuild_tensor_v2``'s arguments are not one dense tensor inside its storage."""
    if len(tensor.args) not in (6, 7):
        return f"{len(tensor.args)} rebuild arguments, where torch.save writes 6"
    storage, offset, size, stride, requires_grad, hooks, *metadata = tensor.args
    if not _is_count(offset):
        return f"offset {_short(offset)} is not a count (an integer from 0 to 2**63-1)"
    for what, value in (("shape", size), ("strides", stride)):
        if not isinstance(value, tuple) or len(value) > 8 or not all(map(_is_count, value)):
            return f"{what} {_short(value)} is not a tuple of at most 8 counts (integers from 0 to 2**63-1)"
    if len(stride) != len(size):
        return f"strides {stride} for a shape of {len(size)} dimensions {size}"
    if not isinstance(requires_grad, bool) or not (hooks is None or (isinstance(hooks, dict) and not hooks)):
        return "it carries gradients' flags or hooks, which torch.save of a weight does not write"
    if metadata and metadata[0] not in (None, {}):
        return "it carries metadata, which torch.save of a weight does not write"
    expected = 1
    for n, s in sorted((n, s) for s, n in zip(size, stride) if s > 1):
        if n != expected:
            return (
                f"strides {stride} for shape {size}: not one dense layout (values overlap or are skipped; "
                f"a stride of {n} where {expected} belongs)"
            )
        expected *= s
    numel = math.prod(size)
    if numel and offset + numel > storage.numel:
        return (
            f"offset {offset} + {numel} values, past the end of its storage of {storage.numel} "
            f"{_dtype(storage.dtype)} values"
        )
    return None


def check_tensors(tensors: dict, arch: Architecture) -> None:
    """CheckpointRefused naming the first tensor that is not where, or what, ``arch`` has."""
    names = {path[1] for path in tensors if len(path) == 2 and path[0] == "model"}
    missing = [n for n in arch.weights if n not in names]
    extra = sorted(names - set(arch.weights))
    if missing or extra:
        parts = [f"{label} {_list(items)}" for label, items in (("missing", missing), ("unexpected", extra)) if items]
        raise CheckpointRefused(f"weights {'; '.join(parts)}", fits=False)
    for path, tensor in tensors.items():
        want = _expected(path, arch)
        if want is None:
            raise CheckpointRefused(f"tensor {_name(path)}: a tensor where a checkpoint of this network holds none")
        dtype, shape = want
        got = tensor.args[0].dtype
        if got != dtype:
            raise CheckpointRefused(
                f"tensor {_name(path)}: dtype {_dtype(got)}, where the network's is {_dtype(dtype)}", fits=False
            )
        size = tensor.args[2] if len(tensor.args) > 2 else None
        if size != shape:
            raise CheckpointRefused(
                f"size mismatch for {_name(path)}: shape {_short(size)} in the checkpoint, {shape} in the network",
                fits=False,
            )
        problem = layout_problem(tensor)
        if problem:
            raise CheckpointRefused(f"tensor {_name(path)}: {problem}")


def _list(items) -> str:
    shown = ", ".join(map(str, items[:SHOWN]))
    return shown + (f" and {len(items) - SHOWN} more" if len(items) > SHOWN else "")


def _expected(path: tuple, arch: Architecture):
    """(dtype, shape) a tensor at ``path`` must have, or None where no tensor belongs."""
    if len(path) == 2 and path[0] == "model":
        return arch.weights.get(path[1])
    if len(path) == 4 and path[:2] == ("optimizer", "state") and is_int(path[2]) and isinstance(path[3], str):
        if not 0 <= path[2] < len(arch.parameters):
            return None
        dtype, shape = arch.parameters[path[2]]
        return (dtype, ()) if path[3] == "step" else (dtype, shape)
    return None


def loaded_problem(ckpt, tensors: dict) -> str | None:
    """Why what torch.load returned differs from what was checked (None: it is the same)."""
    try:
        found = dict(_walk(ckpt))
    except CheckpointRefused as exc:
        return exc.text
    if set(found) != set(tensors):
        return f"torch.load found {len(found)} tensors where {len(tensors)} were checked"
    for path, tensor in found.items():
        ref = tensors[path]
        _storage, offset, size, stride, *_ = ref.args
        if not (
            isinstance(tensor, torch.Tensor)
            and tensor.layout == torch.strided
            and tensor.device.type == "cpu"
            and tensor.dtype == ref.args[0].dtype
            and tuple(tensor.shape) == size
            and tensor.stride() == stride
            and tensor.storage_offset() == offset
            and tensor.untyped_storage().nbytes() == ref.args[0].numel * ref.args[0].dtype.itemsize
        ):
            return f"tensor {_name(path)} read by torch.load differs from the one checked"
    return None


def copied(ckpt: dict) -> dict:
    """``ckpt`` (checked by :func:`loaded_problem`: tensors only as weights and in the
    optimizer's state) with its tensors copied out of the file's mapping, as plain tensors."""
    ckpt = dict(ckpt)
    if isinstance(ckpt.get("model"), dict):
        ckpt["model"] = {name: t.clone() if isinstance(t, torch.Tensor) else t for name, t in ckpt["model"].items()}
    optimizer = ckpt.get("optimizer")
    if isinstance(optimizer, dict) and isinstance(optimizer.get("state"), dict):
        state = {
            index: {k: v.clone() if isinstance(v, torch.Tensor) else v for k, v in entry.items()}
            if isinstance(entry, dict)
            else entry
            for index, entry in optimizer["state"].items()
        }
        ckpt["optimizer"] = {**optimizer, "state": state}
    return ckpt

"""Every number and sequence a checkpoint holds is checked for range and length before it is
formatted or used: an integer of 5,000 digits where a storage's size, an offset, a shape, a
stride, ``version``, ``epoch`` or a key belongs (Python refuses to print one, so a refusal
that names it would itself fail), an optimizer whose ``betas`` has one value or whose moments
are not finite, a history with a NaN loss. Each is refused by a resumed run (and infer),
exit 2, one line naming the file and what is wrong, nothing written."""

import collections
import math
import pickletools
import shutil
import warnings
import zipfile

import pytest
import torch

from pipeline.neural import checkpoint_meta
from support.neural_fakes import TINY, assert_checkpoint_refused

torch.set_num_threads(1)
#: 5,000 decimal digits: over the 4,300 Python converts to text.
HUGE = 10**4999 + 7


class Forged:
    """A tensor as torch.save writes it, with the offset, shape and strides given."""

    def __init__(self, like: torch.Tensor, offset, size, stride):
        self.storage = like.detach().clone().contiguous().untyped_storage()
        self.dtype, self.rest = like.dtype, (offset, tuple(size), tuple(stride))

    def __reduce_ex__(self, protocol):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            typed = torch.TypedStorage(wrap_storage=self.storage, dtype=self.dtype, _internal=True)
        return torch._utils._rebuild_tensor_v2, (typed, *self.rest, False, collections.OrderedDict())


def _long4(value: int) -> bytes:
    data = value.to_bytes((value.bit_length() + 8) // 8, "little", signed=True)
    return b"\x8b" + len(data).to_bytes(4, "little") + data


def _patch_first_storage(path, part: str) -> None:
    """Replaces the first storage's ``part`` ('key' or 'size') in data.pkl by HUGE, and writes
    the archive again as torch.save does (members stored)."""
    with zipfile.ZipFile(path) as archive:
        members = [(info.filename, archive.read(info)) for info in archive.infolist()]
    name, pickled = next((n, d) for n, d in members if n.endswith("/data.pkl"))
    ops = list(pickletools.genops(pickled))
    at = next(i for i, (op, _arg, _pos) in enumerate(ops) if op.name == "BINPERSID")
    # the persistent id: MARK 'storage' <class> key location size TUPLE [BINPUT] BINPERSID
    tuple_at = max(i for i in range(at) if ops[i][0].name == "TUPLE")
    values = [i for i in range(tuple_at) if ops[i][0].name not in ("BINPUT", "LONG_BINPUT")][-3:]
    which = values[0] if part == "key" else values[2]
    start, end = ops[which][2], ops[which + 1][2]
    patched = pickled[:start] + _long4(HUGE) + pickled[end:]
    with zipfile.ZipFile(path, "w", zipfile.ZIP_STORED) as archive:
        for member, data in members:
            archive.writestr(member, patched if member == name else data)


def _weight(ckpt):
    return next((n, t) for n, t in ckpt["model"].items() if t.dim() == 2)


def _storage_size(ckpt):
    return "size", "an integer of about 5,000 digits"


def _storage_key(ckpt):
    return "key", "an integer of about 5,000 digits"


def _offset(ckpt):
    name, t = _weight(ckpt)
    ckpt["model"][name] = Forged(t, HUGE, t.shape, t.stride())
    return None, f"model['{name}']: offset an integer of about 5,000 digits"


def _shape(ckpt):
    name, t = _weight(ckpt)
    ckpt["model"][name] = Forged(t, 0, (HUGE, t.shape[1]), t.stride())
    return None, f"model['{name}']: shape (an integer of about 5,000 digits, {t.shape[1]})"


def _stride(ckpt):
    name, t = _weight(ckpt)
    ckpt["model"][name] = Forged(t, 0, t.shape, (t.stride()[0], HUGE))
    return None, f"model['{name}']: strides ({t.stride()[0]}, an integer of about 5,000 digits)"


def _version(ckpt):
    ckpt["version"] = HUGE
    return None, "version is an integer of about 5,000 digits, beyond the 64-bit integers"


def _epoch(ckpt):
    ckpt["epoch"] = HUGE
    return None, "epoch is an integer of about 5,000 digits, beyond the 64-bit integers"


def _optimizer_key(ckpt):
    state = ckpt["optimizer"]["state"]
    state[HUGE] = state.pop(0)
    return None, "optimizer['state'] has a key an integer of about 5,000 digits"


def _history_key(ckpt):
    ckpt["history"][0][HUGE] = 1
    return None, "history[0] has a key an integer of about 5,000 digits"


def _history_value(ckpt):
    ckpt["history"][0]["time_s"] = HUGE
    return None, "history[0]['time_s'] is an integer of about 5,000 digits"


def _one_beta(ckpt):
    ckpt["optimizer"]["param_groups"][0]["betas"] = (0.9,)
    return None, "optimizer['param_groups'][0]['betas'] is (0.9,), not two numbers from 0 to 1"


def _nan_beta(ckpt):
    ckpt["optimizer"]["param_groups"][0]["betas"] = (0.9, math.nan)
    return None, "optimizer['param_groups'][0]['betas'] is (0.9, nan), not two numbers from 0 to 1"


def _no_eps(ckpt):
    del ckpt["optimizer"]["param_groups"][0]["eps"]
    return None, "optimizer['param_groups'][0] has no 'eps'"


def _amsgrad(ckpt):
    ckpt["optimizer"]["param_groups"][0]["amsgrad"] = True
    return None, "optimizer['param_groups'][0]['amsgrad'] is True, where this run's Adam has False"


def _params(ckpt):
    ckpt["optimizer"]["param_groups"][0]["params"] = [0]
    return None, "optimizer['param_groups'][0]['params'] is not the network's parameters in order"


def _step_int(ckpt):
    ckpt["optimizer"]["state"][0]["step"] = 3
    return None, "optimizer['state'][0]['step'] is an int, not a tensor"


def _moment_missing(ckpt):
    del ckpt["optimizer"]["state"][1]["exp_avg_sq"]
    return None, "optimizer['state'][1] has no 'exp_avg_sq'"


def _nan_moment(ckpt):
    ckpt["optimizer"]["state"][0]["exp_avg"].view(-1)[0] = math.nan
    return None, "optimizer['state'][0]['exp_avg']: 1 value(s) are NaN or infinite"


def _negative_moment(ckpt):
    ckpt["optimizer"]["state"][0]["exp_avg_sq"].view(-1)[0] = -1.0
    return None, "optimizer['state'][0]['exp_avg_sq']: 1 value(s) are negative"


def _nan_loss(ckpt):
    ckpt["history"][0]["train_loss"] = math.nan
    return None, "history[0]: train_loss is NaN, not a finite number"


def _nan_psnr(ckpt):
    ckpt["history"][0]["test_psnr"] = math.nan
    return None, "history[0]: test_psnr is NaN, not a PSNR >= 0 dB"


#: case: (edit of the trusted checkpoint, which commands must refuse it)
CASES = {
    "storage-size-5000-digits": (_storage_size, ("infer", "resume")),
    "storage-key-5000-digits": (_storage_key, ("infer", "resume")),
    "offset-5000-digits": (_offset, ("infer", "resume")),
    "shape-5000-digits": (_shape, ("infer", "resume")),
    "stride-5000-digits": (_stride, ("infer", "resume")),
    "version-5000-digits": (_version, ("infer", "resume")),
    "epoch-5000-digits": (_epoch, ("infer", "resume")),
    "optimizer-key-5000-digits": (_optimizer_key, ("resume",)),
    "history-key-5000-digits": (_history_key, ("infer", "resume")),
    "history-value-5000-digits": (_history_value, ("infer", "resume")),
    "betas-one-value": (_one_beta, ("resume",)),
    "betas-nan": (_nan_beta, ("resume",)),
    "eps-missing": (_no_eps, ("resume",)),
    "amsgrad-without-its-state": (_amsgrad, ("resume",)),
    "params-one": (_params, ("resume",)),
    "step-an-int": (_step_int, ("resume",)),
    "moment-missing": (_moment_missing, ("resume",)),
    "moment-nan": (_nan_moment, ("resume",)),
    "moment-negative": (_negative_moment, ("resume",)),
    "history-nan-loss": (_nan_loss, ("infer", "resume")),
    "history-nan-psnr": (_nan_psnr, ("infer", "resume")),
}


def _forge(run, dest, case):
    broken = shutil.copytree(run, dest)
    path = broken / "checkpoint.pt"
    ckpt = torch.load(path, map_location="cpu", weights_only=True)  # the test's own reading
    patch, words = CASES[case][0](ckpt)
    torch.save(ckpt, path)
    if patch:
        _patch_first_storage(path, patch)
    return broken, words


@pytest.mark.slow
@pytest.mark.parametrize("case", list(CASES))
def test_a_number_out_of_range_is_refused_naming_it(tiny_run, reference, tmp_path, case):
    broken, words = _forge(tiny_run, tmp_path / "broken", case)
    out = tmp_path / "out"
    commands = {
        "infer": ["infer", broken, "--out", out / "ball.exr"],
        "resume": ["train", reference, "--out", broken, "--epochs", 2, *TINY],
    }
    assert_checkpoint_refused(broken, out, {name: commands[name] for name in CASES[case][1]}, words)


@pytest.mark.parametrize(
    "value, text",
    [
        (12, "12"),
        (-(10**19), "-10000000000000000000"),
        (10**4999, "an integer of about 5,000 digits"),
        (-(10**5999), "minus an integer of about 6,000 digits"),
        ((1, 10**5000, "x" * 500), "(1, an integer of about 5,001 digits, 'xxxxxxxxxxxxxxxxx...xxxxxxxxxxxxxxxxxx')"),
        (list(range(10**6)), "[0, 1, 2, 3, 4, 5, ...]"),
        ({10**5000: [1]}, "{an integer of about 5,001 digits: [1]}"),
    ],
    ids=["small", "20-digits", "5000-digits", "minus-6000-digits", "tuple", "long-list", "dict-key"],
)
def test_an_untrusted_value_is_shown_bounded(value, text):
    """The one formatter of a checkpoint's values: an integer Python will not print, shown
    by its size; strings and containers cut short."""
    assert checkpoint_meta.shown(value, limit=200) == text

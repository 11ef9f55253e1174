"""libLLVM selection for drjit, and Mitsuba variant resolution."""

import os
import subprocess
import sys

import pytest

from pipeline.errors import SetupError
from pipeline.render import mitsuba_env


def _touch(folder, name):
    path = folder / name
    path.write_bytes(b"")
    return path


def test_newest_usable_libllvm_is_chosen(tmp_path):
    _touch(tmp_path, "libLLVM-14.so.1")
    _touch(tmp_path, "libLLVM-15.so.1")
    want = _touch(tmp_path, "libLLVM.so.19.1")
    _touch(tmp_path, "libLLVM-17.so")
    assert mitsuba_env.find_libllvm((str(tmp_path / "libLLVM*.so*"),)) == str(want)


def test_only_broken_versions_means_none(tmp_path):
    _touch(tmp_path, "libLLVM-15.so.1")
    assert mitsuba_env.find_libllvm((str(tmp_path / "libLLVM*"),)) is None


def test_user_choice_is_respected_and_checked(monkeypatch, tmp_path):
    monkeypatch.setenv("DRJIT_LIBLLVM_PATH", str(tmp_path / "missing.so"))
    with pytest.raises(SetupError, match="apt-get install libllvm19"):
        mitsuba_env.select_libllvm()
    real = _touch(tmp_path, "libLLVM-18.so")
    monkeypatch.setenv("DRJIT_LIBLLVM_PATH", str(real))
    assert mitsuba_env.select_libllvm() == str(real)


def test_no_llvm_says_what_to_install(monkeypatch):
    monkeypatch.delenv("DRJIT_LIBLLVM_PATH", raising=False)
    monkeypatch.setattr(mitsuba_env, "find_libllvm", lambda *a: None)
    with pytest.raises(SetupError, match="libllvm19"):
        mitsuba_env.select_libllvm()


def test_fresh_process_renders_with_selected_llvm():
    """A new interpreter without DRJIT_LIBLLVM_PATH gets a working LLVM backend."""
    env = {k: v for k, v in os.environ.items() if k != "DRJIT_LIBLLVM_PATH"}
    code = (
        "from pipeline.render.mitsuba_env import load_mitsuba; import os;"
        "mi = load_mitsuba('llvm');"
        "img = mi.render(mi.load_dict(mi.cornell_box()), spp=1);"
        "print(mi.variant(), img.shape, os.environ['DRJIT_LIBLLVM_PATH'])"
    )
    out = subprocess.run(
        [sys.executable, "-c", code],
        env=env,
        capture_output=True,
        text=True,
        cwd=os.path.dirname(os.path.dirname(__file__)),
        timeout=300,
    )
    assert out.returncode == 0, out.stderr
    variant, *_rest = out.stdout.split()
    assert variant == "llvm_ad_rgb"
    assert "libLLVM" in out.stdout


def test_unknown_variant_is_named(mi):
    with pytest.raises(SetupError, match="render.variant: 'vulkan'"):
        mitsuba_env.resolve_variant("vulkan")
    assert mitsuba_env.resolve_variant("scalar") == "scalar_rgb"

"""Shared fixtures. Mitsuba is loaded through pipeline.render.mitsuba_env so libLLVM is selected first."""

import importlib.util
import sys
from pathlib import Path

import pytest

from pipeline.render.mitsuba_env import load_mitsuba
from support import VARIANT

REPO = Path(__file__).resolve().parents[1]


def crash_module():
    """scripts/crash_test.py as a module (the crash, resume and cluster tests share its helpers)."""
    if "crash_test" in sys.modules:
        return sys.modules["crash_test"]
    spec = importlib.util.spec_from_file_location("crash_test", REPO / "scripts" / "crash_test.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules["crash_test"] = module
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="session")
def mi():
    return load_mitsuba(VARIANT)


@pytest.fixture(scope="session")
def cache_dir(tmp_path_factory) -> str:
    """The geometry and G-buffer cache of this session."""
    return str(tmp_path_factory.getbasetemp() / "shaderball-cache")


@pytest.fixture(scope="session")
def ball(cache_dir):
    """The default shaderball, built once a session (the geometry, G-buffer and raster tests)."""
    from geometry import ShaderballParams, build_shaderball

    return build_shaderball(ShaderballParams(), cache_dir=cache_dir)


@pytest.fixture(scope="session")
def reference(tmp_path_factory) -> Path:
    """An uninterrupted smoke build, shared by the crash, resume and cluster tests."""
    return crash_module().shared_reference(tmp_path_factory)[0]


@pytest.fixture(scope="session")
def smoke(tmp_path_factory) -> Path:
    """The smoke dataset, built once per session (once per machine under xdist), shared by the
    publish and validate tests: read it, or copy it before a change."""
    from support.publishing import smoke_build

    return smoke_build(tmp_path_factory)


@pytest.fixture(scope="session")
def tiny_run(reference, tmp_path_factory) -> Path:
    """A run trained one epoch on the reference dataset with ``support.neural_fakes.TINY``, shared
    by the checkpoint, run-file and link tests: read it, or copy it before a change."""
    from click.testing import CliRunner

    from cli import main
    from support.neural_fakes import TINY

    out = tmp_path_factory.mktemp("tiny") / "run"
    result = CliRunner().invoke(main, ["train", str(reference), "--out", str(out), "--epochs", "1", *TINY])
    assert result.exit_code == 0, result.output
    return out


@pytest.fixture(scope="module")
def app(reference, tmp_path_factory):
    """A `shaderball serve` app on a free port with the reference dataset and a tiny network
    trained on it (the serve tests'; a module may define its own ``app``)."""
    from support.serving import start_app, train_tiny_run

    run = train_tiny_run(reference, tmp_path_factory.mktemp("serve") / "run")
    app = start_app(reference, run)
    yield app
    app.close()


@pytest.fixture(scope="module")
def http(app):
    """JSON requests over real HTTP to the module's ``app``."""
    from support.serving import Client

    return Client(app.url)

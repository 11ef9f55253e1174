"""The shape of the code: pure domain packages, one owner of the Mitsuba variant, no import cycles.

docs/architecture.md states these rules; this file is what keeps them true (the layer
contract itself: tests/test_architecture_layers.py). Every check
reads the source with ``ast`` (no module is imported), except the purity check, which
imports the domain packages in a fresh interpreter and looks at ``sys.modules``.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PROJECT_PACKAGES = ("pipeline", "sky", "materials", "geometry")
DOMAIN_PACKAGES = ("sky", "materials", "geometry")
#: What the domain packages must never import.
FORBIDDEN_IN_DOMAIN = ("mitsuba", "drjit", "dask", "distributed", "dask_jobqueue", "OpenEXR", "pipeline")
#: Heavy libraries: the only imports allowed inside functions.
LAZY_ALLOWED = (
    "mitsuba",
    "drjit",
    "dask",
    "distributed",
    "dask_jobqueue",
    "OpenEXR",
    "trimesh",
    "xatlas",
    "torch",
    "PIL",
    "colour",
    "bokeh",
    "matplotlib",
    "pyoidn",
    "flip_evaluator",
    "mlcroissant",
    "skimage",
    "webdataset",
    "scipy",
)
#: Project modules that need an optional extra (torch): the neural stage's commands
#: (pipeline.neural.command, which the CLI imports at start) import them when a command runs.
LAZY_PROJECT_MODULES = ("pipeline.neural", "pipeline.downstream.run")  # they load torch
#: The one module of the neural stage that may import the others inside a function: the
#: command line imports it at start, so it loads no torch.
TORCH_FREE_ENTRIES = ("pipeline.neural.command",)
VARIANT_NAMES = ("llvm_ad_rgb", "cuda_ad_rgb", "scalar_rgb", "llvm_ad_spectral", "cuda_ad_spectral")
MITSUBA_ENV = "pipeline/render/mitsuba_env.py"
#: Strings that name a variant as a fact, not a choice: (module, the text's start), and why.
PROVENANCE = {
    ("sky.policy", "mitsuba 3.9.1, llvm_ad_rgb"): "FLOOR_MEASURED_ON says what the floor table was "
    "measured on; it is stored in every render's record, so its bytes are part of the dataset",
}


def project_modules() -> dict[str, Path]:
    """Module name -> path for every module of the project's packages and cli.py."""
    modules = {"cli": REPO / "cli.py"}
    for package in PROJECT_PACKAGES:
        for path in sorted((REPO / package).rglob("*.py")):
            rel = path.relative_to(REPO).with_suffix("")
            name = ".".join(rel.parts)
            modules[name.removesuffix(".__init__")] = path
    return modules


MODULES = project_modules()


def imports(path: Path) -> list[tuple[str, bool, int]]:
    """(imported module, at module level?, line) for every import statement of ``path``."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    top_level = {id(node) for node in tree.body}
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(alias.name, id(node) in top_level, node.lineno) for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found.append((node.module, id(node) in top_level, node.lineno))
            # `from pipeline.render import bsdf` imports the module pipeline.render.bsdf
            found += [
                (f"{node.module}.{alias.name}", id(node) in top_level, node.lineno)
                for alias in node.names
                if f"{node.module}.{alias.name}" in MODULES
            ]
    return found


def root(name: str) -> str:
    return name.split(".")[0]


@pytest.mark.parametrize("package", DOMAIN_PACKAGES)
def test_domain_packages_import_nothing_of_the_renderer_the_cluster_or_the_pipeline(package):
    offenders = [
        f"{path.relative_to(REPO)}:{line} imports {name}"
        for path in sorted((REPO / package).rglob("*.py"))
        for name, _top, line in imports(path)
        if root(name) in FORBIDDEN_IN_DOMAIN
    ]
    assert not offenders, "\n".join(offenders)


def test_importing_every_domain_module_loads_no_renderer_cluster_or_pipeline():
    names = [m for m in MODULES if root(m) in DOMAIN_PACKAGES]
    code = (
        "import sys\n"
        f"for name in {names!r}:\n"
        "    __import__(name)\n"
        f"bad = sorted(m for m in sys.modules if m.split('.')[0] in {FORBIDDEN_IN_DOMAIN!r})\n"
        "print(' '.join(bad))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "", f"importing the domain packages loaded: {out.stdout}"


def test_only_mitsuba_env_sets_the_variant_or_names_one():
    offenders = []
    for name, path in MODULES.items():
        if path.relative_to(REPO).as_posix() == MITSUBA_ENV:
            continue
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            if isinstance(node, ast.Attribute) and node.attr == "set_variant":
                offenders.append(f"{name}:{node.lineno} calls set_variant")
            if isinstance(node, ast.Constant) and isinstance(node.value, str):
                named = [v for v in VARIANT_NAMES if v in node.value]
                if any(name == m and node.value.startswith(s) for m, s in PROVENANCE):
                    continue
                if named:
                    offenders.append(f"{name}:{node.lineno} names the variant {named[0]!r}")
    assert not offenders, "\n".join(offenders)
    env = (REPO / MITSUBA_ENV).read_text(encoding="utf-8")
    assert env.count("mi.set_variant(") == 1


def test_no_import_cycles_among_the_projects_modules():
    graph = {name: set() for name in MODULES}
    for name, path in MODULES.items():
        for imported, _top, _line in imports(path):
            # a module imports its package's __init__ too; edges to packages count
            if imported in MODULES and imported != name:
                graph[name].add(imported)
    # Tarjan's strongly connected components: any component of two or more is a cycle.
    index, low, stack, on_stack, cycles = {}, {}, [], set(), []
    counter = [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on_stack.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                cycles.append(sorted(component))

    sys.setrecursionlimit(max(sys.getrecursionlimit(), 10_000))
    for v in graph:
        if v not in index:
            visit(v)
    assert not cycles, f"import cycles: {cycles}"


def test_the_projects_own_imports_are_at_module_top():
    offenders = [
        f"{path.relative_to(REPO)}:{line} imports {name} inside a function"
        for module, path in MODULES.items()
        for name, top, line in imports(path)
        if not top
        and root(name) in PROJECT_PACKAGES + ("cli",)
        and not (
            name.startswith(LAZY_PROJECT_MODULES)
            and (not module.startswith(LAZY_PROJECT_MODULES) or module in TORCH_FREE_ENTRIES)
        )
    ]
    assert not offenders, "\n".join(offenders)


def test_lazy_imports_are_heavy_libraries_only():
    stdlib = set(sys.stdlib_module_names)
    offenders = [
        f"{path.relative_to(REPO)}:{line} imports {name} lazily"
        for path in MODULES.values()
        for name, top, line in imports(path)
        if not top
        and root(name) not in LAZY_ALLOWED
        and root(name) not in stdlib
        and root(name) not in PROJECT_PACKAGES
    ]
    assert not offenders, "\n".join(offenders)


def test_dask_is_known_to_one_place():
    """pipeline.run.cluster: its connection runs dask; its options parse --memory with dask's
    own unit parser (the value goes to dask); its watch knows none."""
    users = sorted(
        {
            name
            for name, path in MODULES.items()
            for imported, _top, _line in imports(path)
            if root(imported) in ("dask", "distributed", "dask_jobqueue")
        }
    )
    assert users == ["pipeline.run.cluster.connection", "pipeline.run.cluster.options"], users
    options = [
        imported
        for imported, _top, _line in imports(MODULES["pipeline.run.cluster.options"])
        if root(imported) in ("dask", "distributed", "dask_jobqueue")
    ]
    assert options == ["dask.utils"], options


def test_every_pipeline_sub_package_says_what_it_owns():
    """What it may import is the generated last paragraph (tests/test_architecture_layers.py);
    what it owns is the prose above it."""
    for init in sorted((REPO / "pipeline").glob("*/__init__.py")):
        doc = ast.get_docstring(ast.parse(init.read_text(encoding="utf-8")))
        paragraphs = (doc or "").split("\n\n")
        assert len(paragraphs) >= 2 and paragraphs[-1].startswith("Layer "), (
            f"{init.relative_to(REPO)}: docstring must say what it owns, then its layer (scripts/layers.py --write)"
        )


@pytest.mark.parametrize(
    "module, never",
    [
        ("pipeline.publish.reader", ("torch", "pipeline.neural", "pipeline.run", "mitsuba", "dask")),
        ("pipeline.image.tonemap", ("torch", "pipeline.neural", "pipeline.render", "mitsuba")),
        ("pipeline.check.validate", ("pipeline.run", "pipeline.render.renderer", "pipeline.neural", "mitsuba", "dask")),
        ("pipeline.neural.command", ("torch",)),
        ("cli", ("torch",)),
    ],
)
def test_readers_load_neither_training_code_nor_the_build(module, never):
    """Reading a publication, tone-mapping an image or validating a folder loads no torch, no
    training stage, no build and no renderer (readers low in the layers)."""
    code = f"import sys, {module}\nprint(' '.join(sorted(m for m in sys.modules if m.startswith({never!r}))))\n"
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "", f"importing {module} loaded: {out.stdout}"


#: The longest a library function may be: a longer one does several things, each of which wants a name.
MAX_FUNCTION_LINES = 80


def test_no_library_function_is_over_80_lines():
    long = []
    for package in ("pipeline", "sky", "materials", "geometry"):
        for path in sorted((REPO / package).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text())):
                if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    lines = node.end_lineno - node.lineno + 1
                    if lines > MAX_FUNCTION_LINES:
                        long.append(f"{path.relative_to(REPO)}:{node.lineno} {node.name} ({lines} lines)")
    assert not long, "split by what each part does: " + "; ".join(long)

"""The package's layers (docs/design.md, "Layers"): every module of torchakvf, parsed with ``ast``,
imports only from its own subpackage and from the layers below its own. Every import counts:
module level, inside functions, under ``if``, relative and absolute, and ``import_module`` of a
literal name. Layers cannot form a cycle, so a re-added cycle fails here."""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

import torchakvf

PACKAGE = Path(torchakvf.__file__).parent

#: Bottom to top. A subpackage (or top-level module) may import the layers below its own; the
#: names of one layer are independent of each other. "torchakvf" is the package's __init__ (the
#: public API, which imports the stages below it).
LAYERS = (
    ("errors", "scipy_reference"),      # the scipy reference is the tests' oracle: it imports nothing of ours
    ("devices", "threads", "restarts", "progress"),
    ("mesh",),
    ("operators",),
    ("solvers",),                       # the remedy decision lives here, with the factorizations
    ("fields",),
    ("cluster",),
    ("merge_options",),                 # method "merge"'s weights and over-segmentation, held by options
    ("options",),
    ("parts",),
    ("io", "shapes"),                   # files in and out; the built-in shapes
    ("data",),
    ("torchakvf",),
    ("pipeline", "interop"),
    ("evaluate",),
    ("bench",),
    ("cli",),
)
LEVEL = {name: i for i, layer in enumerate(LAYERS) for name in layer}


def node_of(module: str) -> str:
    """The layer name of a dotted module of the package: its subpackage or top-level module,
    "torchakvf" for the package itself."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else parts[0]


def module_name(path: Path, package: Path = PACKAGE) -> str:
    rel = path.relative_to(package.parent).with_suffix("")
    parts = list(rel.parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imported_modules(source: str, module: str, is_package: bool) -> list[tuple[str, int]]:
    """[(dotted module of the package, line)] that ``source`` (the text of ``module``) imports
    anywhere. ``from X import y`` yields X.y where y may be a submodule (``from .. import shapes``)
    and X where it is a name; the caller keeps the package's own."""
    here = module if is_package else module.rpartition(".")[0]
    out = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            out += [(a.name, node.lineno) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = here.split(".")[:len(here.split(".")) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module
            out += [(f"{target}.{a.name}", node.lineno) for a in node.names]
        elif (isinstance(node, ast.Call) and getattr(node.func, "attr", getattr(node.func, "id", None))
              in ("import_module", "__import__") and node.args and isinstance(node.args[0], ast.Constant)
              and isinstance(node.args[0].value, str)):
            out.append((node.args[0].value, node.lineno))
    return sorted(((t, line) for t, line in out if t.split(".")[0] == "torchakvf"), key=lambda x: x[1])


def target_node(target: str) -> str:
    """The layer a dotted import target lands in: ``torchakvf.x.<anything>`` -> x where x is a
    subpackage or top-level module, else the package itself (``from torchakvf import __version__``)."""
    name = node_of(target)
    if name != "torchakvf" and ((PACKAGE / name).is_dir() or (PACKAGE / f"{name}.py").is_file()):
        return name
    return "torchakvf"


def package_imports(package: Path = PACKAGE) -> list[tuple[str, str, int, str]]:
    """[(importing node, imported node, line, "module -> target")] of every import between two
    different layer names of the package."""
    edges = []
    for path in sorted(package.rglob("*.py")):
        module = module_name(path, package)
        for target, line in imported_modules(path.read_text(encoding="utf-8"), module, path.name == "__init__.py"):
            a, b = node_of(module), target_node(target)
            if a != b:
                edges.append((a, b, line, f"{module}:{line} imports {target}"))
    return edges


def test_every_subpackage_and_module_has_a_layer():
    found = {node_of(module_name(p)) for p in PACKAGE.rglob("*.py")}
    assert found == set(LEVEL), f"unlisted: {sorted(found - set(LEVEL))}, gone: {sorted(set(LEVEL) - found)}"
    assert len(LEVEL) == sum(len(layer) for layer in LAYERS)      # no name in two layers


def test_no_module_imports_its_own_layer_or_one_above():
    bad = [f"{where} ({a}, layer {LEVEL[a]} -> {b}, layer {LEVEL[b]})"
           for a, b, _, where in package_imports() if LEVEL[b] >= LEVEL[a]]
    assert not bad, "imports against the layers (tests/test_layers.py LAYERS):\n" + "\n".join(bad)


def test_imports_are_found_wherever_they_are():
    # A module of torchakvf/solvers with every way of importing: each one is seen.
    source = """
import torchakvf.mesh.batch
from torchakvf.errors import SolverError
from . import lobpcg
from .factor import mesh_shift

def f():
    from ..fields.akvf import akvf
    if True:
        from .. import shapes, __version__
    importlib.import_module("torchakvf.parts.segment")

class C:
    def g(self):
        import torchakvf
"""
    found = [(target_node(t), line) for t, line in imported_modules(source, "torchakvf.solvers.x", False)]
    assert found == [("mesh", 2), ("errors", 3), ("solvers", 4), ("solvers", 5), ("fields", 8),
                     ("shapes", 10), ("torchakvf", 10), ("parts", 11), ("torchakvf", 15)]
    # In a package's __init__, "." is the package itself.
    assert imported_modules("from .akvf import akvf", "torchakvf.fields", True) == [("torchakvf.fields.akvf.akvf", 1)]


def test_a_cycle_fails_the_layers(tmp_path):
    # The checker on a copy of two stages where the lower one imports the upper inside a function.
    root = tmp_path / "torchakvf"
    for sub, text in (("solvers", "def f():\n    from ..fields import akvf\n"),
                      ("fields", "from ..solvers import f\n")):
        (root / sub).mkdir(parents=True)
        (root / sub / "__init__.py").write_text(text)
    edges = {(a, b) for a, b, _, _ in package_imports(root)}
    assert edges == {("solvers", "fields"), ("fields", "solvers")}
    assert [(a, b) for a, b in edges if LEVEL[b] >= LEVEL[a]] == [("solvers", "fields")]


@pytest.mark.parametrize("old, new", [
    ("torchakvf.fields.akvf_result:AKVFResult", "torchakvf.solvers.akvf_result:AKVFResult"),
    ("torchakvf.fields:AKVFResult", "torchakvf.solvers.akvf_result:AKVFResult"),
    ("torchakvf.fields.whitney:whitney_face_vectors", "torchakvf.operators.whitney:whitney_face_vectors"),
    ("torchakvf.fields:whitney_face_vectors", "torchakvf.operators.whitney:whitney_face_vectors"),
])
def test_moved_names_keep_their_old_spelling(old, new):
    import importlib

    def get(spec):
        module, name = spec.split(":")
        return getattr(importlib.import_module(module), name)

    assert get(old) is get(new)

"""Architecture rules, read from the source with ``ast`` (nothing is imported but the package for
its public names): no import cycle among car_napari's modules, no reach into another subpackage's
private modules or names, Qt and napari only in ``car_napari._widgets``, the top-level API, and
no symlinks in the repository."""

import ast
import shutil
import subprocess
from pathlib import Path

import pytest

TOP = Path(__file__).resolve().parents[1]
PACKAGE = TOP / "car_napari"
# car_napari's own top-level private modules (car_napari/_<name>.py: _progress, _validation,
# _linalg, ...) are shared by every subpackage; a private subpackage (_widgets) is not
SHARED_PRIVATE = {p.stem for p in PACKAGE.glob("_*.py") if p.name != "__init__.py"}
GUI_PACKAGES = {
    "napari", "qtpy", "PyQt5", "PyQt6", "PySide2", "PySide6", "magicgui", "vispy", "superqt",
}
GUI_HOME = "car_napari._widgets"


def _module_name(path):
    parts = list(path.relative_to(TOP).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


MODULES = {_module_name(p): p for p in sorted(PACKAGE.rglob("*.py"))}
PACKAGES = {name for name, path in MODULES.items() if path.name == "__init__.py"}


def _ancestors(module):
    parts = module.split(".")
    return {".".join(parts[:i]) for i in range(1, len(parts))}


def _is_type_checking(node):
    test = node.test
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def _import_nodes(tree):
    """Every import statement, at module level or inside functions and classes, except those
    under ``if TYPE_CHECKING:`` (never executed)."""
    skipped = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and _is_type_checking(node):
            skipped.update(id(child) for stmt in node.body for child in ast.walk(stmt))
    return [node for node in ast.walk(tree)
            if isinstance(node, ast.Import | ast.ImportFrom) and id(node) not in skipped]


def _resolve(module, node):
    """The absolute module a ``from ... import`` statement reads from."""
    if node.level == 0:
        return node.module
    package = module if module in PACKAGES else module.rpartition(".")[0]
    base = package.split(".")
    if node.level > 1:
        base = base[: -(node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def _imports(module):
    """``(line, target, names)`` for each import in ``module``: ``target`` the absolute module
    named, ``names`` the names taken from it (empty for ``import x.y``)."""
    tree = ast.parse(MODULES[module].read_text(), filename=str(MODULES[module]))
    found = []
    for node in _import_nodes(tree):
        if isinstance(node, ast.Import):
            found.extend((node.lineno, alias.name, ()) for alias in node.names)
        else:
            names = tuple(alias.name for alias in node.names)
            found.append((node.lineno, _resolve(module, node), names))
    return found


IMPORTS = {module: _imports(module) for module in MODULES}


def _edges(module):
    """The car_napari modules that ``module`` makes Python execute by name. ``import a.b`` and
    ``from a import b`` where ``a.b`` is a submodule give an edge to ``a.b``; ``from a import
    name`` gives an edge to ``a`` (its ``__init__`` for a package), except for the importing
    module's own parent packages when the name is a submodule: Python runs those anyway."""
    edges = set()
    for _, target, names in IMPORTS[module]:
        if target not in MODULES:
            continue
        if not names:
            edges.add(target)
            continue
        for name in names:
            sub = f"{target}.{name}"
            if sub in MODULES:
                edges.add(sub)
                if target not in _ancestors(module):
                    edges.add(target)
            else:
                edges.add(target)
    edges.discard(module)
    return edges


def _cycles(graph):
    """The strongly connected components of more than one module (Tarjan), sorted."""
    index, low, stack, on_stack, components = {}, {}, [], set(), []

    def visit(node):
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for succ in sorted(graph[node]):
            if succ not in index:
                visit(succ)
                low[node] = min(low[node], low[succ])
            elif succ in on_stack:
                low[node] = min(low[node], index[succ])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == node:
                    break
            if len(component) > 1:
                components.append(sorted(component))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return components


def _a_cycle(graph, component):
    """One concrete cycle inside a strongly connected component (a breadth-first path back)."""
    members = set(component)
    start = component[0]
    paths, seen = [[start]], {start}
    while paths:
        path = paths.pop(0)
        for succ in sorted(graph[path[-1]] & members):
            if succ == start:
                return path + [start]
            if succ not in seen:
                seen.add(succ)
                paths.append(path + [succ])
    return component


def test_the_import_graph_is_read():
    # a guard for the rules below: they see the package and its imports
    assert {"_progress", "_validation", "_linalg"} <= SHARED_PRIVATE
    assert "_widgets" not in SHARED_PRIVATE
    assert {"car_napari", "car_napari.model", "car_napari._progress", GUI_HOME} <= set(MODULES)
    assert "car_napari.model" in _edges("car_napari")


def test_the_cycle_finder_finds_cycles():
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a", "d"}, "d": set(), "e": {"d"}}
    assert _cycles(graph) == [["a", "b", "c"]]
    assert _a_cycle(graph, ["a", "b", "c"]) == ["a", "b", "c", "a"]
    assert _cycles({"a": {"b"}, "b": set()}) == []


def test_no_import_cycle():
    graph = {module: _edges(module) for module in MODULES}
    cycles = [" -> ".join(_a_cycle(graph, c)) + f"   (component: {', '.join(c)})"
              for c in _cycles(graph)]
    assert not cycles, "import cycles among car_napari's modules:\n" + "\n".join(cycles)


def _subpackage(module):
    """The top-level part of car_napari a module belongs to ("model", "_widgets", "_progress",
    ...); None for car_napari/__init__.py itself."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else None


def _private_reach(module, target, names):
    """The dotted names a module imports that are private to another subpackage."""
    own = _subpackage(module)
    bad = []
    for name in names or (None,):
        dotted = target if name is None else f"{target}.{name}"
        parts = dotted.split(".")
        if parts[0] != "car_napari" or len(parts) < 2:
            continue
        owner = parts[1]
        if owner == own or owner in SHARED_PRIVATE:
            continue
        if any(p.startswith("_") and not p.startswith("__") for p in parts[1:]):
            bad.append(dotted)
    return bad


def test_no_import_of_another_subpackages_private_names():
    found = [
        f"{MODULES[module].relative_to(TOP)}:{line}: {dotted}"
        for module, imports in IMPORTS.items()
        for line, target, names in imports
        for dotted in _private_reach(module, target, names)
    ]
    assert not found, (
        "private names of another subpackage (use its public face, or move the helper to a "
        "shared car_napari/_<name>.py):\n" + "\n".join(found)
    )


def test_the_private_rule_sees_a_reach():
    # independent checks of the rule on made-up imports
    assert _private_reach("car_napari.cli", "car_napari.segmentation._segment", ("x",))
    assert _private_reach("car_napari.cli", "car_napari.segmentation", ("_helper",))
    assert _private_reach("car_napari", "car_napari.model._kernels", ())
    assert not _private_reach("car_napari.cli", "car_napari._validation", ("as_image",))
    assert not _private_reach("car_napari._widgets.texture", "car_napari._progress", ("drain",))
    assert not _private_reach("car_napari.model.estimation", "car_napari.model._kernels", ("k",))
    assert not _private_reach("car_napari.cli", "car_napari.segmentation", ("segment",))


def test_gui_toolkits_only_in_the_widgets():
    found = [
        f"{MODULES[module].relative_to(TOP)}:{line}: {target}"
        for module, imports in IMPORTS.items()
        if not (module == GUI_HOME or module.startswith(GUI_HOME + "."))
        for line, target, _ in imports
        if target and target.split(".")[0] in GUI_PACKAGES
    ]
    assert not found, (
        f"Qt/napari/magicgui imported outside {GUI_HOME} (the core stays GUI-free, "
        "even lazily):\n" + "\n".join(found)
    )


TOP_LEVEL = [
    "segment", "iter_segment", "detect_mammogram_rois", "iter_detect_mammogram_rois",
    "segment_tissue", "iter_segment_tissue",
    "restore", "iter_restore", "restore_multichannel", "iter_restore_multichannel",
    "estimate_psf", "inpaint", "iter_inpaint", "detect_scratches", "TextureModel", "BTFModel",
    "DynamicTextureModel", "texture_features", "rank", "fit_car", "select_support", "predict",
    "synthesize", "local_parameters", "illumination_invariants", "Progress",
]


def test_top_level_api():
    import car_napari as car

    missing = [name for name in TOP_LEVEL if not hasattr(car, name)]
    assert not missing, f"car_napari lacks {missing}"
    not_exported = [name for name in TOP_LEVEL if name not in car.__all__]
    assert not not_exported, f"car_napari.__all__ lacks {not_exported}"
    dangling = [name for name in car.__all__ if not hasattr(car, name)]
    assert not dangling, f"car_napari.__all__ names what car_napari lacks: {dangling}"
    assert len(set(car.__all__)) == len(car.__all__), "car_napari.__all__ repeats a name"
    assert all(callable(getattr(car, name)) for name in TOP_LEVEL)


def test_no_symlink_in_the_repository():
    if shutil.which("git") is None or not (TOP / ".git").exists():
        pytest.skip("not a git checkout")
    listing = subprocess.run(["git", "ls-files", "-s"], cwd=TOP, capture_output=True,
                             text=True, check=True).stdout
    links = [line.split("\t", 1)[1] for line in listing.splitlines() if line.startswith("120000")]
    assert not links, f"symlinks in the repository (break on Windows and in wheels): {links}"

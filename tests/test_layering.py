"""The package's rooms and the one direction their imports point in (docs/architecture.md).

Every import in `jaxpose/` and `experiments/`, at the top of a module or inside a function, is read with
`ast`; each module belongs to a layer, and a module may import only from its own layer or one below.
No private name (`_name`) is imported from another module.  A new module must be given its layer here,
which is the moment to decide where it belongs.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

import paths

# Lowest first.  A key ending in "." is a package prefix; the others are single modules.
LAYERS: list[tuple[str, tuple[str, ...]]] = [
    ("geometry and joints", (
        "jaxpose", "jaxpose.camera", "jaxpose.rotations", "jaxpose.triangulation", "jaxpose.robust", "jaxpose.skeleton",
        "jaxpose.layouts", "jaxpose.metrics", "jaxpose.chunks", "jaxpose.logs", "jaxpose.compilation_cache", "jaxpose.flip",
    )),
    ("files users bring and take away", ("jaxpose.formats.",)),
    ("the data contract", ("jaxpose.data.",)),
    ("data sets, the simulator, calibration", ("jaxpose.datasets.", "jaxpose.synthetic.", "jaxpose.calibration.")),
    ("the user's rig project", ("jaxpose.rig.",)),
    ("training and evaluation", (
        "jaxpose.model", "jaxpose.losses", "jaxpose.viz", "jaxpose.training.",
    )),
    ("serving and the command lines", (
        "jaxpose.serving.", "jaxpose.reconstruction.", "jaxpose.predict", "jaxpose.export", "jaxpose.calibrate", "jaxpose.reconstruct",
    )),
    ("experiments", ("experiments.",)),
]


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(paths.REPO).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def layer_of(module: str) -> int:
    for index, (_, members) in enumerate(LAYERS):
        for member in members:
            if module == member or (member.endswith(".") and (module + ".").startswith(member)):
                return index
    raise KeyError(module)


def _sources() -> list[Path]:
    return sorted(p for folder in ("jaxpose", "experiments") for p in (paths.REPO / folder).rglob("*.py"))


def _imports(path: Path) -> list[tuple[int, str, tuple[str, ...]]]:
    """(line, imported module, names taken from it) for every jaxpose/experiments import in the file."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name, ()) for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.append((node.lineno, node.module, tuple(alias.name for alias in node.names)))
    return [(line, module, names) for line, module, names in found if module.split(".")[0] in ("jaxpose", "experiments")]


def _target(module: str, name: str) -> str:
    """`from package import name` imports a submodule where one exists."""
    candidate = f"{module}.{name}"
    base = paths.REPO / Path(*candidate.split("."))
    return candidate if base.with_suffix(".py").exists() or (base / "__init__.py").exists() else module


def _edges() -> list[tuple[str, str, str, tuple[str, ...]]]:
    edges = []
    for path in _sources():
        source = _module_name(path)
        for line, module, names in _imports(path):
            targets = {_target(module, name) for name in names} or {module}
            for target in targets:
                edges.append((f"{path.relative_to(paths.REPO)}:{line}", source, target, names))
    return edges


def test_every_module_has_a_layer():
    unplaced = []
    for path in _sources():
        try:
            layer_of(_module_name(path))
        except KeyError:
            unplaced.append(_module_name(path))
    assert not unplaced, f"give these modules a layer in tests/test_layering.py LAYERS: {unplaced}"


def test_imports_point_down_the_layers():
    upward = [
        f"{where}: {source} ({LAYERS[layer_of(source)][0]}) imports {target} ({LAYERS[layer_of(target)][0]})"
        for where, source, target, _ in _edges()
        if layer_of(target) > layer_of(source)
    ]
    assert not upward, "imports against the direction:\n" + "\n".join(upward)


def test_no_private_name_crosses_a_module():
    private = [
        f"{where}: {source} imports {name} from {target}"
        for where, source, target, names in _edges()
        for name in names
        if name.startswith("_") and target != source
    ]
    assert not private, "\n".join(private)


@pytest.mark.parametrize("module, expected", [("jaxpose.rig.project", 4), ("jaxpose.formats.trc", 1), ("jaxpose.camera", 0),
                                              ("experiments.rig", 7), ("jaxpose.data", 2)])
def test_layer_lookup(module, expected):
    assert layer_of(module) == expected


def report() -> str:
    """Lines per room, imports between rooms and the modules over 450 lines, as markdown."""
    names = [name for name, _ in LAYERS]
    files, lines, big = [0] * len(LAYERS), [0] * len(LAYERS), []
    for path in _sources():
        layer, count = layer_of(_module_name(path)), len(path.read_text().splitlines())
        files[layer] += 1
        lines[layer] += count
        if count > 450:
            big.append(f"{path.relative_to(paths.REPO)} ({count})")
    between: dict[tuple[int, int], int] = {}
    for _, source, target, _ in _edges():
        key = (layer_of(source), layer_of(target))
        between[key] = between.get(key, 0) + 1
    out = ["| room (layer) | modules | lines |", "|---|---|---|"]
    out += [f"| {i} {names[i]} | {files[i]} | {lines[i]} |" for i in range(len(LAYERS))]
    out += [f"| total | {sum(files)} | {sum(lines)} |", "", "Imported modules per importing room (same room aside):", ""]
    for source in range(len(LAYERS)):
        targets = [f"{names[t]} {between[(source, t)]}" for t in range(len(LAYERS)) if t != source and (source, t) in between]
        out.append(f"- {names[source]} -> {', '.join(targets) or 'nothing'}")
    out += ["", f"Modules over 450 lines: {', '.join(big) or 'none'}"]
    return "\n".join(out)


if __name__ == "__main__":
    print(report())

"""The packages' layers point down only (docs/architecture.md): ipc, then the geometry
(perception.geometry), then perception, grasping, sim and launch_scripts. Every import in
every module counts, also one inside a function."""

import ast
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
#: The layers, bottom first; a module may import its own layer and those below it.
LAYERS = ("ipc", "perception.geometry", "perception", "grasping", "sim", "launch_scripts")
PACKAGES = ("ipc", "perception", "grasping", "sim", "launch_scripts")


def rank(module: str) -> int:
    return LAYERS.index("perception.geometry" if module.startswith("perception.geometry") else module.split(".")[0])


def imports(path: Path) -> set[str]:
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found.add(node.module)
    return {name for name in found if name.split(".")[0] in PACKAGES}


def modules() -> list[tuple[str, Path]]:
    return [(".".join(path.relative_to(REPO).with_suffix("").parts).removesuffix(".__init__"), path)
            for package in PACKAGES for path in sorted((REPO / package).rglob("*.py"))]


@pytest.mark.parametrize("module, path", modules(), ids=[m for m, _ in modules()])
def test_imports_point_down(module, path):
    above = sorted(name for name in imports(path) if rank(name) > rank(module))
    assert not above, f"{module} imports {above}, a layer above its own ({LAYERS[rank(module)]})"


def test_nothing_in_perception_imports_sim_and_every_layer_has_modules():
    layers = {rank(m) for m, _ in modules()}
    assert layers == set(range(len(LAYERS)))
    assert not [m for m, p in modules() if m.startswith("perception") and any(n.startswith("sim") for n in imports(p))]

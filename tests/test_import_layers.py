"""The packages import one way: sim <- contract <- robot, and {sim, contract, robot} <- {learner, app} <- cli;
learner and app never import each other.

Every import statement of every module is read (those inside functions too), so a lazy import cannot hide an
arrow that runs back up.
"""

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
ALLOWED: dict[str, set[str]] = {
    "sim": set(),
    "contract": {"sim"},
    "robot": {"contract", "sim"},
    "learner": {"contract", "robot", "sim"},
    "app": {"contract", "robot", "sim"},
    "cli": {"app", "contract", "learner", "robot", "sim"},
}
"""What each package of the project may import, besides itself and third-party packages."""


def imported_packages(path: Path) -> set[tuple[int, str]]:
    """(line, top-level package) of each of the project's packages that the module at path imports."""
    found: set[tuple[int, str]] = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names = [node.module]
        else:
            continue
        found |= {(node.lineno, name.split(".")[0]) for name in names if name.split(".")[0] in ALLOWED}
    return found


def arrows_back_up() -> list[str]:
    problems = []
    for package, allowed in ALLOWED.items():
        for path in sorted((ROOT / package).rglob("*.py")):
            for line, target in sorted(imported_packages(path)):
                if target != package and target not in allowed:
                    problems.append(f"{path.relative_to(ROOT)}:{line} imports {target}")
    return problems


def test_no_import_runs_back_up() -> None:
    assert arrows_back_up() == []


def test_the_check_sees_a_lazy_import_back_up(tmp_path: Path) -> None:
    module = tmp_path / "module.py"
    module.write_text("import os\n\ndef f():\n    from learner.train import Trainer\n    import app.main\n")
    assert imported_packages(module) == {(4, "learner"), (5, "app")}


def test_every_package_is_checked() -> None:
    packages = {path.parent.name for path in ROOT.glob("*/__init__.py")} - {"tests", "bench", "migrations"}
    assert packages == set(ALLOWED)


def test_routers_import_no_other_router() -> None:
    """A router imports the app's dependencies, schemas and shared helpers (app.views, app.previews, …), never
    another router: what two routers show lives in a helper both import."""
    problems = []
    for path in sorted((ROOT / "app" / "routers").glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            if isinstance(node, ast.ImportFrom) and (node.level > 0 or (node.module or "").startswith("app.routers")):
                problems.append(f"{path.relative_to(ROOT)}:{node.lineno} imports {node.module or '.'}")
            elif isinstance(node, ast.Import):
                problems += [
                    f"{path.relative_to(ROOT)}:{node.lineno} imports {alias.name}"
                    for alias in node.names
                    if alias.name.startswith("app.routers")
                ]
    assert problems == []

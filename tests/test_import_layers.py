"""The packages import one way: sim <- contract <- robot, and {sim, contract, robot} <- {learner, app} <- cli;
learner and app never import each other. Only robot/ moves an arm: it alone calls a robot's moves, it imports no
torch (the acting policy is handed in), only the cli and the learner's end of the link import its driver
(robot.drive), and the app imports robot.base alone.

Every import statement of every module is read (those inside functions too), so a lazy import cannot hide an
arrow that runs back up.
"""

import ast
import subprocess
import sys
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


MOVES = {"send_action", "reset_scene", "hold_safe", "let_go"}
"""The calls that move an arm or hand it over (robot/base.py): only robot/ makes them."""


def project_modules() -> list[Path]:
    return [path for package in ALLOWED for path in sorted((ROOT / package).rglob("*.py"))]


def imported_modules(path: Path) -> set[tuple[int, str]]:
    """(line, module) of every module the file imports, in full (`robot.drive.actor`)."""
    found: set[tuple[int, str]] = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            found |= {(node.lineno, alias.name) for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found |= {(node.lineno, f"{node.module}.{alias.name}") for alias in node.names}
    return found


def move_calls(path: Path) -> list[tuple[int, str]]:
    """(line, name) of every call in the file of a method named like one of MOVES."""
    return [
        (node.lineno, node.func.attr)
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path)))
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr in MOVES
    ]


def test_only_robot_calls_what_moves_an_arm() -> None:
    problems = [
        f"{path.relative_to(ROOT)}:{line} calls {name}"
        for path in project_modules()
        if path.relative_to(ROOT).parts[0] != "robot"
        for line, name in move_calls(path)
    ]
    assert problems == []


def test_robot_imports_no_torch() -> None:
    problems = [
        f"{path.relative_to(ROOT)}:{line} imports {name}"
        for path in sorted((ROOT / "robot").rglob("*.py"))
        for line, name in imported_modules(path)
        if name.split(".")[0] == "torch"
    ]
    assert problems == []


def test_a_robot_process_loads_no_torch() -> None:
    """Importing the robot's process and everything it imports leaves torch unloaded: the acting policy is handed
    in from the learner's side."""
    code = "import sys, robot.drive.process, robot.drive.link; print('torch' in sys.modules)"
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True)
    assert done.stdout.strip() == "False"


def test_only_the_learners_end_of_the_link_and_the_cli_import_the_driver() -> None:
    allowed = {ROOT / "learner" / "actor_handle.py"}
    problems = [
        f"{path.relative_to(ROOT)}:{line} imports {name}"
        for path in project_modules()
        if path.relative_to(ROOT).parts[0] not in ("robot", "cli") and path not in allowed
        for line, name in imported_modules(path)
        if name.startswith("robot.drive")
    ]
    assert problems == []


def test_the_app_imports_only_robot_base() -> None:
    problems = [
        f"{path.relative_to(ROOT)}:{line} imports {name}"
        for path in sorted((ROOT / "app").rglob("*.py"))
        for line, name in imported_modules(path)
        if name.split(".")[0] == "robot" and not name.startswith("robot.base.")
    ]
    assert problems == []


def test_the_move_check_sees_a_call(tmp_path: Path) -> None:
    module = tmp_path / "module.py"
    module.write_text("def f(env):\n    env.unwrapped.let_go()\n    env.step(0)\n")
    assert move_calls(module) == [(2, "let_go")]

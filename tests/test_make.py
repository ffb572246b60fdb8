"""The Makefile: `make run` installs only what runs, `make test` adds the test tools (each with its own stamp)."""

import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def _plan(target: str, venv: Path) -> str:
    """What `make TARGET` would run for a fresh virtual environment (make -n: nothing is run)."""
    done = subprocess.run(
        ["make", "-n", "-C", str(ROOT), f"VENV={venv}", target], capture_output=True, text=True, timeout=60
    )
    assert done.returncode == 0, done.stderr
    return done.stdout


def test_make_run_installs_the_project_only_and_make_test_the_test_tools(tmp_path: Path) -> None:
    venv = tmp_path / "venv"
    run = _plan("run", venv)
    assert "pip install --quiet -e .\n" in run and ".[dev]" not in run
    assert f"touch {venv}/.installed\n" in run
    test = _plan("test", venv)
    assert "pip install --quiet -e '.[dev]'" in test and f"touch {venv}/.installed-dev" in test
    # once the runtime is installed, `make test` adds only the test tools
    venv.mkdir()
    (venv / ".installed").touch()
    again = _plan("test", venv)
    assert ".[dev]" in again and "pip install --quiet -e .\n" not in again

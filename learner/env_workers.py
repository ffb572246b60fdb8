"""Training envs stepped in parallel, each in a process of its own (TrainConfig.env_processes).

On the loop's thread the envs of a batch step one after another. With env_processes each training env lives in a
worker process: the loop sends every env its action (`step_async`), then collects the results (`step_wait`), so
the envs' physics and camera renders run at once on as many cores (a GPU host's spare CPU cores; on the CPU path
the update thread takes the second core already). A `ProcessEnv` answers what the loop asks of an env: step,
reset, render, the state snapshot a query candidate's display render is made from (taken in the worker after each
step and reset and sent with the result, so asking for it costs no round trip), and the generator state a
checkpoint keeps (`env.unwrapped.np_random.bit_generator.state`, read and set in the worker).

Workers start with "spawn" (a fresh interpreter: no copy of the learner's torch threads or EGL contexts), make
their env with `contract.envs.make_env` (the operator's RAQ_ENV_MODULES is read there as here), and exit when their
pipe closes. An error in a worker is raised in the learner with the worker's traceback.
"""

import contextlib
import multiprocessing
import traceback
from multiprocessing.connection import Connection
from typing import Any

import gymnasium
import numpy as np

from contract.envs import make_env

START_SECONDS = 120.0
"""How long a worker may take to import its modules and make its env."""


def _snapshot(env: gymnasium.Env) -> Any | None:
    unwrapped = env.unwrapped
    return unwrapped.state_snapshot() if hasattr(unwrapped, "restore_snapshot") else None


def _step(env: gymnasium.Env, action: np.ndarray) -> tuple[tuple, Any]:
    return env.step(action), _snapshot(env)


def _reset(env: gymnasium.Env, seed: int | None) -> tuple[tuple, Any]:
    return env.reset(seed=seed), _snapshot(env)


def _restore_snapshot(env: gymnasium.Env, snapshot: Any) -> None:
    env.unwrapped.restore_snapshot(snapshot)


def _rng_state(env: gymnasium.Env) -> dict[str, Any] | None:
    try:
        return env.unwrapped.np_random.bit_generator.state
    except AttributeError:
        return None


def _set_rng_state(env: gymnasium.Env, state: dict[str, Any]) -> None:
    env.unwrapped.np_random.bit_generator.state = state


def _spaces(env: gymnasium.Env) -> tuple[gymnasium.Space, gymnasium.Space, bool]:
    return env.action_space, env.observation_space, _snapshot(env) is not None


COMMANDS = {
    "step": _step, "reset": _reset, "render": lambda env: env.render(), "restore_snapshot": _restore_snapshot,
    "rng_state": _rng_state, "set_rng_state": _set_rng_state, "spaces": _spaces,
}  # fmt: skip


def serve(connection: Connection, env_id: str, image_size: int, display_size: int) -> None:
    """A worker process: make the env, then answer (command, args) with (True, result) or (False, traceback)."""
    try:
        env = make_env(env_id, image_size=image_size, display_size=display_size)
    except Exception:
        connection.send((False, traceback.format_exc()))
        return
    connection.send((True, None))
    try:
        while True:
            try:
                command, args = connection.recv()
            except EOFError:  # the learner closed the pipe (or exited)
                return
            if command == "close":
                return
            try:
                connection.send((True, COMMANDS[command](env, *args)))
            except Exception:
                connection.send((False, traceback.format_exc()))
    finally:
        env.close()


class WorkerError(RuntimeError):
    """An env's worker process failed (its traceback is the message) or went away."""


class _RemoteBitGenerator:
    """`np_random.bit_generator` of the worker's env: its `state` read and set there."""

    def __init__(self, env: "ProcessEnv") -> None:
        self.env = env

    @property
    def state(self) -> dict[str, Any] | None:
        return self.env.call("rng_state")

    @state.setter
    def state(self, value: dict[str, Any]) -> None:
        self.env.call("set_rng_state", value)


class _RemoteGenerator:
    """`np_random` of the worker's env (its `bit_generator.state`, as a checkpoint reads and sets it)."""

    def __init__(self, env: "ProcessEnv") -> None:
        self.bit_generator = _RemoteBitGenerator(env)


class _RemoteUnwrapped:
    """What the loop reads from `env.unwrapped`: the generator."""

    def __init__(self, env: "ProcessEnv") -> None:
        self.env = env
        self.np_random = _RemoteGenerator(env)


class _RemoteUnwrappedWithSnapshots(_RemoteUnwrapped):
    """... and the state snapshot protocol (`contract.envs.snapshot_of`), for an env that has it."""

    def state_snapshot(self) -> Any:
        return self.env.snapshot

    def restore_snapshot(self, snapshot: Any) -> None:
        self.env.call("restore_snapshot", snapshot)
        self.env.snapshot = snapshot


def process_envs(count: int, env_id: str, *, image_size: int, display_size: int) -> list["ProcessEnv"]:
    """`count` envs in worker processes of their own, started together and ready."""
    envs = [ProcessEnv(env_id, image_size=image_size, display_size=display_size) for _ in range(count)]
    try:
        return [env.wait_ready() for env in envs]
    except BaseException:
        for env in envs:
            env.close()
        raise


class ProcessEnv:
    """A training env in a worker process, used like the gymnasium env itself (step, reset, render, close,
    action_space, unwrapped's snapshots and generator) once `wait_ready`; `step_async` / `step_wait` let several
    step at once."""

    def __init__(self, env_id: str, *, image_size: int, display_size: int) -> None:
        context = multiprocessing.get_context("spawn")
        self.connection, child = context.Pipe()
        self.process = context.Process(
            target=serve, args=(child, env_id, image_size, display_size), daemon=True, name=f"env {env_id}"
        )
        self.process.start()
        child.close()
        self.snapshot: Any = None
        self.closed = False

    def wait_ready(self) -> "ProcessEnv":
        """Wait for the worker to have made its env (its error is raised here); read its spaces."""
        self._result(timeout=START_SECONDS)
        self.action_space, self.observation_space, snapshots = self.call("spaces")
        self.unwrapped = (_RemoteUnwrappedWithSnapshots if snapshots else _RemoteUnwrapped)(self)
        return self

    @property
    def pid(self) -> int | None:
        return self.process.pid

    def call(self, command: str, *args: Any) -> Any:
        self._send(command, *args)
        return self._result()

    def _send(self, command: str, *args: Any) -> None:
        try:
            self.connection.send((command, args))
        except OSError as error:  # (a broken pipe: the worker is gone)
            raise WorkerError(f"the env worker (pid {self.pid}) went away: {error!r}") from error

    def _result(self, timeout: float | None = None) -> Any:
        try:
            if timeout is not None and not self.connection.poll(timeout):
                raise WorkerError(f"the env worker did not start within {timeout:.0f} s")
            ok, value = self.connection.recv()
        except (EOFError, ConnectionError) as error:
            raise WorkerError(f"the env worker (pid {self.pid}) went away: {error!r}") from error
        if not ok:
            raise WorkerError(f"in the env worker (pid {self.pid}):\n{value}")
        return value

    def step_async(self, action: np.ndarray) -> None:
        self._send("step", action)

    def step_wait(self) -> tuple:
        outcome, self.snapshot = self._result()
        return outcome

    def step(self, action: np.ndarray) -> tuple:
        self.step_async(action)
        return self.step_wait()

    def reset(self, *, seed: int | None = None) -> tuple:
        outcome, self.snapshot = self.call("reset", seed)
        return outcome

    def render(self) -> np.ndarray | None:
        return self.call("render")

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        with contextlib.suppress(OSError, ValueError):  # (the worker may be gone already)
            self.connection.send(("close", ()))
        self.process.join(timeout=10.0)
        if self.process.is_alive():
            self.process.kill()
            self.process.join()
        self.connection.close()

"""A robot's own process: the one process that opens the robot's camera and moves its arm (`raq robot ENV`, or
`raq actor --run ID` for the runs of one run's robot only).

It makes the robot's env once, which never moves the arm (robot/base.py), and then, until it is stopped:
- stamps its row in the store every ROBOT_REPORT_SECONDS with what it does (contract/store/robot_processes.py);
- while no run drives the robot, publishes the camera's frame for the pages: every FRAME_WATCHED_SECONDS while a
  page watches, else every FRAME_IDLE_SECONDS. The web server shows these frames, previews them and captures goal
  photos from them; it never opens the camera itself;
- drives the run whose learner opens the link (the actor loop of robot/drive/actor.py over robot/drive/link.py's
  `StoreLink`, acting with the policy the learner's side hands in: `Acting`), sized for that run, for as long as
  that learner keeps it; the arm is held safe between learners.

A learner of a robot env links to it (learner/actor_handle.py) and never drives the robot itself: without a robot
process its run waits, and says how to start one. One process serves a robot, whatever the host: a second one
refuses to start and names the first (contract/store/robot_processes.py); one that finds, after a pause, that
another took the robot over lets go of the arm, touching nothing, and ends. A run driven again (its learner was
quiet for a while) goes on from the step its last actor reached, so no warm-up action is sent twice.
"""

import contextlib
import threading
import time
import traceback

import gymnasium as gym
import numpy as np

from contract.actor_messages import Failure, driving, encode_message
from contract.checkpoint_location import ACTOR_POLICY_FILENAME, checkpoint_url, sibling
from contract.config import TrainConfig
from contract.envs import encode_png
from contract.store import RunStatus, Store, is_transient
from contract.store.robot_holds import holder_name, robot_name
from contract.store.robot_processes import (
    FRAME_IDLE_SECONDS,
    FRAME_WATCHED_SECONDS,
    ROBOT_REPORT_SECONDS,
    RobotProcessStatus,
    RobotServed,
)
from robot.base import control_rate, is_robot
from robot.drive.actor import Acting, ActorLoop, ActorSettings, ActorState, open_env
from robot.drive.link import StoreLink

IDLE_SECONDS = 0.1
"""How often an idle robot process looks for a learner and for a page watching."""
WAITING_FOR_LEARNER = "waiting for a learner"
"""A robot process's state between learners (the arm held safe)."""


class RobotProcess:
    """The robot's camera and arm, and which run drives them."""

    def __init__(
        self, store: Store, *, env_id: str, checkpoint_base: str, acting: Acting, only_run: int | None = None
    ) -> None:
        """`acting`: how its actors act (learner/acting.py's SAC_ACTING); `only_run`: drive that run only, and end
        when it ends (`raq actor --run ID`)."""
        self.store, self.env_id, self.checkpoint_base, self.only_run = store, env_id, checkpoint_base, only_run
        self.acting = acting
        self.robot, self.holder = robot_name(env_id), holder_name()
        self.state = "opening the robot"
        self.stop = threading.Event()
        self.frame_at = -np.inf
        self.env: gym.Env | None = None
        self.sizes: tuple[int, int] | None = None  # (image_size, display_size) of the env as made
        self.status: RobotProcessStatus | None = None  # the row as last written (whether a page watches)
        self.ended_links: dict[int, object] = {}  # run id: its learner's last keep-alive when its actor ended
        self.failed_claims: dict[int, int] = {}  # run id: the claim its actor failed at
        self.reached: dict[int, tuple[int, int]] = {}  # run id: (claim, step) its last actor reached
        self.displaced: str | None = None  # why another process serves the robot now (this one lets go and ends)
        self.actor: ActorLoop | None = None
        self.reporter = threading.Thread(target=self._report, name="robot-report", daemon=True)

    @property
    def has_camera(self) -> bool:
        return self.env is not None and is_robot(self.env)

    def serve(self) -> str:
        """Serve until stopped, or until the one run it serves ends. Returns why it ended; RobotServed when another
        process serves the robot (nothing opened)."""
        self.status = self.store.report_robot_process(
            robot=self.robot, env_id=self.env_id, holder=self.holder, state=self.state
        )
        self.reporter.start()
        try:
            if self.only_run is not None:
                self._sized_for(self._run_config(self.only_run))
            else:
                self.env = open_env(TrainConfig(env_id=self.env_id))  # (the env's own default sizes)
                self.sizes = None
            self.state = WAITING_FOR_LEARNER
            while not self.stop.is_set() and self.displaced is None:
                run_id = self._learner_waiting()
                if isinstance(run_id, str):
                    return run_id
                if run_id is not None:
                    self._drive(run_id)
                    continue
                self._publish_frame()
                self.stop.wait(IDLE_SECONDS)
            return self.displaced or "stopped"
        finally:
            self.stop.set()
            self.reporter.join(timeout=2 * ROBOT_REPORT_SECONDS)
            if self.env is not None:
                with contextlib.suppress(Exception):  # (held by the actor already; touched here by nobody else's)
                    if self.displaced is None:
                        self.env.unwrapped.stop()  # type: ignore[attr-defined]
                    else:
                        self.env.unwrapped.let_go()  # type: ignore[attr-defined]
                self.env.close()
            with contextlib.suppress(Exception):
                self.store.robot_process_ended(robot=self.robot, holder=self.holder)

    # ------------------------------------------------------------------ between runs
    def _learner_waiting(self) -> int | str | None:
        """The run whose learner has the link open (lowest id), None, or why to end (`only_run` ended)."""
        try:
            if self.only_run is not None:
                run = self.store.get_run(run_id=self.only_run)
                if run.status not in RunStatus.LIVE:
                    return f"run {run.status}"
                waiting = self.store.runs_awaiting_actor(env_id=self.env_id, run_id=self.only_run)
            else:
                waiting = self.store.runs_awaiting_actor(env_id=self.env_id)
            for run_id in waiting:  # (a link whose learner's last keep-alive was before its actor ended is over)
                if run_id in self.failed_claims and self.store.run_claim(run_id=run_id) == self.failed_claims[run_id]:
                    continue
                if self.store.actor_link(run_id=run_id).learner_seen_at != self.ended_links.get(run_id):
                    return run_id
        except Exception as error:  # the store away: keep waiting (the arm is held)
            if not is_transient(error):
                raise
        return None

    def _publish_frame(self) -> None:
        """The camera's frame for the pages: often while one watches, else now and then."""
        if not self.has_camera:
            return
        now = time.monotonic()
        watched = self.status is not None and self.status.watched
        if now - self.frame_at < (FRAME_WATCHED_SECONDS if watched else FRAME_IDLE_SECONDS):
            return
        self.frame_at = now
        try:
            pixels = np.ascontiguousarray(self.env.unwrapped.read_camera(), dtype=np.uint8)  # type: ignore[union-attr]
            self.status = self.store.report_robot_process(
                robot=self.robot, env_id=self.env_id, holder=self.holder, state=self.state,
                frame_png=encode_png(pixels),
            )  # fmt: skip
        except RobotServed as error:
            self._displace(str(error))
        except Exception as error:  # the store away, or the camera gave nothing this time: the next try
            if not is_transient(error):
                print(f"robot {self.robot}: no camera frame: {type(error).__name__}: {error}", flush=True)

    def _report(self) -> None:
        """Stamp the robot's row every ROBOT_REPORT_SECONDS, whatever the main thread is doing."""
        while not self.stop.is_set():
            try:
                self.status = self.store.report_robot_process(
                    robot=self.robot, env_id=self.env_id, holder=self.holder, state=self.state
                )
            except RobotServed as error:
                self._displace(str(error))
                return
            except Exception:  # noqa: BLE001, S110 - the store away: stamped at the next try
                pass
            self.stop.wait(ROBOT_REPORT_SECONDS)

    def _displace(self, why: str) -> None:
        """Another process took the robot over (this one was paused past ROBOT_PROCESS_LIVE_SECONDS): the actor lets
        go of the arm without touching it, and this process ends."""
        print(f"robot {self.robot}: {why}; letting go of the arm", flush=True)
        self.displaced = f"displaced: {why}"
        if self.actor is not None:
            self.actor.lose_hold()

    # ------------------------------------------------------------------ a run
    def _run_config(self, run_id: int) -> TrainConfig:
        run = self.store.get_run(run_id=run_id)
        return TrainConfig.from_dict({**run.config_values(), "device": "cpu", "precision": "fp32"})

    def _sized_for(self, config: TrainConfig) -> None:
        """The env at the run's observation and display sizes: a robot's view is set; another env is made anew
        (it moves no arm)."""
        sizes = (config.image_size, config.display_size)
        if self.env is not None and is_robot(self.env):
            self.env.unwrapped.set_view(image_size=config.image_size, display_size=config.display_size)
        elif self.env is None or self.sizes != sizes:
            if self.env is not None:
                self.env.close()
                self.env = None
            self.env = open_env(config)
        self.sizes = sizes

    def _drive(self, run_id: int) -> None:
        """Drive the run for its learner until that learner closes the link or is gone (the arm held safe). An error
        of the robot's (or of the run's settings) fails the run with it; this process holds the arm and goes on."""
        self.state = driving(run_id)
        link: StoreLink | None = None
        actor: ActorLoop | None = None
        try:
            config = self._run_config(run_id)
            self._sized_for(config)
            hz = control_rate(config.env_id, config.control_hz, env=self.env)
            if hz <= 0:
                raise ValueError(
                    f"{config.env_id} is not a robot env: give the run a control_hz to drive it in real time"
                )
            settings = ActorSettings(
                config.to_dict(), run_id=run_id, database_url=self.store.url, control_hz=hz,
                person_reset=config.reset_every_episode,
            )  # fmt: skip
            policy_url = sibling(checkpoint_url(self.checkpoint_base, run_id), ACTOR_POLICY_FILENAME)
            print(f"robot {self.robot}: driving run {run_id} for its learner", flush=True)
            link = StoreLink(
                self.store, run_id=run_id, policy_url=policy_url, hz=hz, read_weights=self.acting.read_weights
            )
            actor = self.actor = ActorLoop(
                settings, link.connection, link.outbox, self.acting, env=self.env, reached=self.reached.get(run_id)
            )
            actor.run()
        except Exception:
            failure = Failure(traceback.format_exc())
            with contextlib.suppress(Exception):  # (not driven again at this claim: its learner fails the run)
                self.failed_claims[run_id] = self.store.run_claim(run_id=run_id)
            print(f"robot {self.robot}: run {run_id}'s actor failed:\n{failure.traceback}", flush=True)
            with contextlib.suppress(Exception):
                self.env.unwrapped.stop()  # type: ignore[union-attr]
            with contextlib.suppress(Exception):  # (after the steps posted before it)
                if link is not None:
                    link.outbox.put(failure)
                else:
                    self.store.post_actor_messages(run_id=run_id, messages=[encode_message(failure)])
        finally:
            if link is not None:
                link.close()
                self.ended_links[run_id] = link.learner_seen_at
            if actor is not None and actor.started:
                self.reached[run_id] = (actor.claim, actor.step)
            self.actor = None
            self.state = WAITING_FOR_LEARNER
        if actor is not None and actor.exit_reason == ActorState.CLOSED:  # (the run's card: its learner let go)
            with contextlib.suppress(Exception):
                self.store.report_actor(run_id=run_id, state=ActorState.CLOSED)
        ended = "failed" if actor is None else actor.state
        print(f"robot {self.robot}: run {run_id}'s actor ended ({ended}); {WAITING_FOR_LEARNER}", flush=True)


def serve_robot(
    store: Store, *, env_id: str, checkpoint_base: str, acting: Acting, only_run: int | None = None,
    stop: threading.Event | None = None,
) -> str:  # fmt: skip
    """Run the robot's process (see the module) until `stop` is set, Ctrl-C, or `only_run` ends; why it ended."""
    process = RobotProcess(store, env_id=env_id, checkpoint_base=checkpoint_base, acting=acting, only_run=only_run)
    if stop is not None:
        threading.Thread(target=lambda: (stop.wait(), process.stop.set()), daemon=True).start()
    return process.serve()

"""The real-time actor: a robot env stepped at its own control rate in a process of its own, never waiting for
the learner.

A robot's actor runs in the robot's own process (robot/drive/process.py); a paced simulated env's beside its
learner (learner/actor_handle.py: `ActorProcess`). Either is linked to its learner through the store
(robot/drive/link.py): the learner sends it fresh policy weights every `policy_sync_seconds` and a keep-alive four
times a second, and reads the actor's transitions as they come. The actor acts with what the learner's side hands
it (`Acting`: learner/acting.py's copy of pi, so that robot/ holds no network code). Its loop, once per
control period (1 / control_hz seconds): act (uniformly at random until the warm-up's end or the first weights,
then the policy, sampling), step the env, send the transition, and sleep to the next period (`Pace`: a late step is
sent late and the period restarts from it, no catching up). Between episodes it sends the arm to its start pose
(env.reset()), then asks a person to reset the scene when the env says it needs one (`needs_person_reset`) or the
run says so (`reset_every_episode`), and waits for their Ready, publishing the camera's view meanwhile; a Stop and
Resume while it waits bring it back to waiting, the arm sent to its start pose again.

What the actor shares with the person goes through the store (`Store.report_actor`, read by the queue and run
pages): the camera's newest frame, its state, and the controls it obeys (Stop robot, Resume, Ready). A thread of
its own reads the controls every CONTROL_POLL_SECONDS, so a stop is honoured within one control period.

The watchdog: the arm is held safe (`env.stop()`) as soon as the link says the learner is gone (its process
died), its keep-alives have been silent `watchdog_seconds`, or the store has been unreachable that long. Without
a learner the actor exits; after a database outage it stays stopped until a person presses Resume.

A robot moves only on the store's word: before every move (a step, or the reset to the start pose) the actor asks
the store whether it holds the robot for its run's current claim and whether a Stop is pending
(`Store.may_move_robot`), and on a yes arms the env for ARM_SECONDS (robot/base.py refuses every move otherwise). A
Stop found there, or read by the control thread, disarms it at once and holds until a person presses Resume, however
many actors, learners or robot processes come and go meanwhile. A process that has lost its hold, or may have (no
renewal confirmed within HOLD_SURE_SECONDS), never holds the arm safe: it lets go, touching nothing.
"""

import contextlib
import os
import threading
import time
from dataclasses import dataclass, field
from typing import Any

import gymnasium
import numpy as np

from contract.actor_messages import (
    Acting,
    ActorSettings,
    Close,
    EpisodeStart,
    PolicyWeights,
    Ready,
    Start,
    StateChange,
    SuccessMarked,
    Transition,
)
from contract.config import TrainConfig
from contract.envs import display_image, encode_png, make_env, model_image, scale_action
from contract.store import Store
from contract.store.bounded import BoundedStore
from contract.store.robot_holds import HOLD_LAPSES_SECONDS, holder_name, robot_name
from robot.base import CameraBusy, RobotNotArmed, is_robot

CONTROL_POLL_SECONDS = 0.05
"""How often the actor's control thread reads Stop, Resume and Ready from the store."""
FRAME_SECONDS = 0.5
"""How often the actor publishes the camera's newest frame for the live view."""
ACTOR_NICENESS = -5
"""The actor's scheduling priority where the system allows it (root, or CAP_SYS_NICE): ahead of the learner."""
LATE_SHARE = 0.1
"""A step later than this share of the control period after its tick is late: the period restarts from it."""
HOLD_RENEW_SECONDS = 0.25
"""How often the control thread renews the actor's hold on its robot (the hold allows moves for
MOVE_WITHIN_SECONDS after each renewal)."""
CAMERA_BUSY_SECONDS = 30.0
"""How long the actor asks again for a robot whose camera another process has open."""
CAMERA_RETRY_SECONDS = 0.25
"""How often it asks."""
TAKE_RETRY_SECONDS = 0.5
"""How often an actor whose robot another run holds asks for it again."""
STORE_ANSWER_SECONDS = 0.3
"""The longest the actor waits for one answer of the store before it counts the store as away (so the watchdog is
looked at within about this long of its time, however the link fails)."""
ARM_SECONDS = 0.5
"""How long the store's yes to a move arms the robot's env (counted from when the question was sent): a move the
actor reaches later than this, after a pause of its process say, is refused."""
HOLD_SURE_SECONDS = HOLD_LAPSES_SECONDS - 0.25
"""The hold is surely still this process's within this many seconds of a renewal the store confirmed (counted from
when it was sent, before the database stamped it); later it may have lapsed and been taken, so the arm is let go of
rather than held. A silent store trips the watchdog (2 s) about 2.3 s after the last renewal it confirmed, and the
loop sees it within STORE_ANSWER_SECONDS more: the arm is held, not let go."""


def open_env(config: TrainConfig) -> gymnasium.Env:
    """The run's env, made here; a robot whose camera another process has (robot.base.CameraBusy: the server's
    live view hands it over once the run is claimed) is asked again until CAMERA_BUSY_SECONDS have passed."""
    deadline = time.monotonic() + CAMERA_BUSY_SECONDS
    while True:
        try:
            return make_env(config.env_id, image_size=config.image_size, display_size=config.display_size)
        except CameraBusy:
            if time.monotonic() >= deadline:
                raise
            time.sleep(CAMERA_RETRY_SECONDS)


class ActorState:
    """What the actor is doing, as the pages show it."""

    STARTING = "starting"
    ACTING = "acting"
    DRIVEN_BY_HAND = "driven by hand"
    DEMO_WAITING = "demo: waiting for the person's keys"
    WAITING_FOR_RESET = "waiting for reset"
    STOPPED = "stopped"
    LEARNER_GONE = "held safe: learner gone"
    DATABASE_GONE = "held safe: database unreachable"
    CLAIM_LOST = "let go: the run was taken over"
    CLOSED = "closed"

    @staticmethod
    def robot_busy(run_id: int) -> str:
        """Waiting for the robot, which another run's actor holds."""
        return f"robot busy with run {run_id}"


EXIT_REASONS = (ActorState.LEARNER_GONE, ActorState.CLAIM_LOST, ActorState.CLOSED)
"""Why the actor exits: there is no learner to act for."""


@dataclass
class Controls:
    """The person's controls as the control thread last read them, how the store answered, and the Evaluate now
    round of the episode under way."""

    stop_requested: bool = False
    reset_count: int = 0
    """How many times a person pressed Ready."""
    evaluation_pending: int = 0
    """Episodes of Evaluate now not begun yet (the actor takes them one by one from the store)."""
    evaluation_round: int | None = None
    """The Evaluate now round of the episode under way (None: a training episode)."""
    last_answer: float = field(default_factory=time.monotonic)
    """When the store last answered (monotonic)."""
    back_at: float = 0.0
    """When the store last answered after a silence longer than the watchdog time (monotonic): it was away, and the
    learner's keep-alives could not cross it either."""
    asked_after: float = 0.0
    """Only answers to reports sent after this moment (monotonic) set the controls: one sent before the actor marked
    the robot stopped itself may still say "not stopped"."""
    takeover_action: np.ndarray | None = None
    """The person's newest action in a take-over (None: none)."""
    takeover_seq: int = 0
    takeover_seen_at: float = -np.inf
    """When the control thread first saw the person's newest action (monotonic): it is fresh for one period."""
    success_marks: int | None = None
    """How many times the success key was pressed, as last read (None: not read yet)."""
    demo_pending: int = 0
    """Episodes of Record demos not begun yet."""
    demo: bool = False
    """The episode under way is a demo: driven by hand only (the robot waits while no key is held)."""
    demo_ended: bool = False
    """The success key ended the demo episode under way."""


# ====================================================================== the actor process
class Pace:
    """When the next action may be sent. While the steps keep time, one control period after the previous tick (so
    the rate holds on average); after a step more than LATE_SHARE of a period late, one period after that step was
    sent, so a late step is never followed by an early one. No two actions are closer than (1 - LATE_SHARE)
    periods, across episodes too."""

    def __init__(self, period: float) -> None:
        self.period = period
        self.tick = -np.inf
        """When the next action is due (monotonic)."""
        self.last_sent: float | None = None

    def sent(self, at: float) -> None:
        """An action was sent at `at` (monotonic): the next is due one period after its tick, or after it if late."""
        on_time = at - self.tick <= LATE_SHARE * self.period
        self.tick = (self.tick if on_time else at) + self.period
        self.last_sent = at

    def restart(self, now: float) -> None:
        """A new episode: its first action is due now, or a full period after the previous action."""
        self.tick = now if self.last_sent is None else max(now, self.last_sent + self.period)


class ActorLoop:
    """The actor's state in its process."""

    def __init__(
        self, settings: ActorSettings, connection: Any, outbox: Any, acting: Acting,
        env: gymnasium.Env | None = None, reached: tuple[int, int] | None = None,
    ) -> None:  # fmt: skip
        """`connection` (poll, recv) brings the learner's messages and `outbox` (put) takes the actor's: the ends of
        its link through the store (robot/drive/link.py). `acting` makes the policy it acts with. `env`: one already
        made (a robot's process keeps its robot between learners), else the run's env is made here. `reached`: the
        (claim, step) an earlier actor of the run reached; for the same claim the run goes on from there."""
        with contextlib.suppress(OSError):  # the robot's clock before the learner's updates, where allowed
            os.setpriority(os.PRIO_PROCESS, 0, ACTOR_NICENESS)
        self.settings, self.connection, self.outbox = settings, connection, outbox
        self.config = TrainConfig.from_dict({**settings.config, "device": "cpu", "precision": "fp32"})
        cfg = self.config
        self.owns_env = env is None
        self.env: gymnasium.Env = env or open_env(cfg)
        self.action_space = self.env.action_space
        self.policy = acting.policy(cfg, int(self.action_space.shape[0]))
        # every call answers within STORE_ANSWER_SECONDS: a silent link reads as the store away, and the watchdog
        # holds the arm within watchdog_seconds however the link fails
        self.store = BoundedStore(Store(settings.database_url), seconds=STORE_ANSWER_SECONDS)
        self.period = 1.0 / settings.control_hz
        self.pace = Pace(self.period)
        self.step = 0  # (the learner's "start" says where the run is)
        self.last_keepalive = time.monotonic()
        self.store_away = False  # the watchdog last found the store unreachable
        self.controls = Controls()
        self.wake = threading.Event()  # set by the control thread when a stop comes in
        self.state = ActorState.STARTING
        self.frame: np.ndarray | None = None
        self.started = False  # the learner sent the step its run is at
        self.reached = reached
        # a robot is driven by one actor, for its run's current claim (contract/store/robot_holds.py); another env
        # (simulated, paced) has no hold
        self.robot = robot_name(cfg.env_id) if is_robot(self.env) else None
        self.holder, self.claim = holder_name(), 0
        self.holding = False  # this actor holds the robot (taken, and not let go)
        self.hold_confirmed_at = -np.inf  # when the last take or renewal the store confirmed was sent (monotonic)
        self.hold_lost = False  # a renewal found the hold gone: the run's claim moved on, or another took it
        self.exit_reason: str | None = None  # the learner's pipe closed, or it closed the actor
        self.done = threading.Event()
        self.control_thread = threading.Thread(target=self._control_loop, name="actor-controls", daemon=True)

    # ------------------------------------------------------------------ the control thread
    def _control_loop(self) -> None:
        """Read the controls; publish the state and, every FRAME_SECONDS, the newest camera frame."""
        last_frame = last_renewal = 0.0
        while not self.done.is_set():
            now = time.monotonic()
            if self.holding and not self.hold_lost and now - last_renewal >= HOLD_RENEW_SECONDS:
                with contextlib.suppress(Exception):  # (the store away: the moves wait, and the watchdog holds)
                    if self.store.renew_robot(robot=self.robot, holder=self.holder):
                        self.hold_confirmed_at = max(self.hold_confirmed_at, now)
                    else:
                        self.lose_hold()
                    last_renewal = now
            png = None
            if self.frame is not None and now - last_frame >= FRAME_SECONDS:
                png, last_frame = encode_png(self.frame), now
            asked = time.monotonic()
            try:
                status = self.store.report_actor(run_id=self.settings.run_id, state=self.state, frame_png=png)
            except Exception:  # the store is unreachable: the watchdog counts from the last answer
                pass
            else:
                controls, answered = self.controls, time.monotonic()
                if answered - controls.last_answer > float(self.config.watchdog_seconds):
                    controls.back_at = answered
                controls.last_answer = answered
                if asked >= controls.asked_after:
                    controls.stop_requested, controls.reset_count = status.stop_requested, status.reset_count
                    controls.evaluation_pending = status.evaluation_pending
                    self._take_person_action(status.takeover_action, status.takeover_seq, answered)
                    controls.demo_pending = status.demo_pending
                    self._take_success_marks(status.success_marks)
                if status.stop_requested:
                    self._disarm()
                    self.wake.set()
            self.done.wait(CONTROL_POLL_SECONDS)

    def _take_person_action(self, action: list[float] | None, seq: int, seen_at: float) -> None:
        """A take-over's newest action as the store has it (None: handed back)."""
        controls = self.controls
        if action is None or len(action) != int(self.action_space.shape[0]):
            controls.takeover_action = None
            return
        if seq != controls.takeover_seq:
            controls.takeover_seq, controls.takeover_seen_at = seq, seen_at
        controls.takeover_action = np.clip(np.asarray(action, dtype=np.float32), -1.0, 1.0)

    def _take_success_marks(self, marks: int) -> None:
        """A success key pressed since the last read goes to the learner (and ends a demo episode)."""
        controls = self.controls
        if controls.success_marks is not None and marks > controls.success_marks:
            self.outbox.put(SuccessMarked())
            if controls.demo:
                controls.demo_ended = True
                self.wake.set()
        controls.success_marks = marks

    def _person_action(self) -> np.ndarray | None:
        """The person's action while they drive by hand: sent within one control period of when it was seen, so a
        page whose connection dropped hands the arm back within a period; None: the policy drives."""
        controls = self.controls
        action = controls.takeover_action
        if action is None or controls.stop_requested or time.monotonic() - controls.takeover_seen_at >= self.period:
            return None
        return action

    def lose_hold(self) -> None:
        """The robot is this actor's no longer (its run claimed again, another process serving the robot): no move
        from now on, and the loop lets go and ends."""
        self.hold_lost = True
        self._disarm()
        self.wake.set()

    def _disarm(self) -> None:
        """No move from now until the store says yes again (robot/base.py's guard; other envs have none)."""
        disarm = getattr(self.env.unwrapped, "disarm", None)
        if disarm is not None:
            disarm()

    # ------------------------------------------------------------------ the watchdog
    def _read_learner(self) -> None:
        """Take the learner's messages (policies, keep-alives, start, close); EOFError means it is gone.
        Called between the steps, so that loading a policy never delays one."""
        while self.exit_reason is None and self.connection.poll():
            try:
                message = self.connection.recv()
            except (EOFError, OSError):
                self.exit_reason = ActorState.LEARNER_GONE
                return
            if isinstance(message, PolicyWeights):
                self.policy.load(message.modules)
            elif isinstance(message, Start):
                self.step, self.claim, self.started = int(message.step), int(message.claim), True
                if self.reached is not None and self.reached[0] == self.claim:  # (driven again, same learner)
                    self.step = max(self.step, self.reached[1])
                if self.step:  # a run taken over: its random actions go on from here, not again from the first
                    self.policy.go_on_from(self.step)
            elif isinstance(message, Close):
                self.exit_reason = ActorState.CLOSED
            self.last_keepalive = time.monotonic()

    def _watchdog(self) -> str | None:
        """Why the arm must be held safe now, or None (a check of clocks and flags: it costs nothing)."""
        if self.exit_reason is not None:
            return self.exit_reason
        if self.hold_lost:
            return ActorState.CLAIM_LOST
        now, limit = time.monotonic(), float(self.config.watchdog_seconds)
        if now - self.controls.last_answer > limit:
            self.store_away = True
            return ActorState.DATABASE_GONE
        # the learner's keep-alives cross the same store: they count while it answers, and again from its return
        # (seen here, or by the control thread while this thread waited on the store itself)
        if self.store_away:
            self.store_away, self.last_keepalive = False, max(self.last_keepalive, now)
        self.last_keepalive = max(self.last_keepalive, self.controls.back_at)
        if self.controls.last_answer - self.last_keepalive > limit:
            self._read_learner()  # (keep-alives may be waiting unread after a long reset)
            if self.exit_reason is not None or self.controls.last_answer - self.last_keepalive > limit:
                return self.exit_reason or ActorState.LEARNER_GONE
        return None

    # ------------------------------------------------------------------ the loop
    def run(self) -> None:
        self.control_thread.start()
        self.outbox.put(Ready(self.action_space, self.env.observation_space))
        try:
            self._loop()
        finally:
            self.done.set()
            self.control_thread.join(timeout=1.0)
            self._secure_arm(lost=self.hold_lost)  # (held already, unless the loop ended on an error of its own)
            if self.holding:
                with contextlib.suppress(Exception):
                    self.store.release_robot(robot=self.robot, holder=self.holder)
            if self.owns_env:
                with contextlib.suppress(Exception):
                    self.env.close()
            self.store.close()

    def _loop(self) -> None:
        cfg = self.config
        while not self.started:  # the learner has read its checkpoint: the step the run is at
            self._read_learner()
            reason = self._watchdog()
            if reason is not None:
                print(f"actor of run {self.settings.run_id}: ended before its first episode: {reason}", flush=True)
                return
            time.sleep(0.01)
        if not self._take_robot():
            return
        new_episode = True
        while True:
            if new_episode:
                obs = self._begin_episode()
                if obs is None:
                    return
                # the action for each observation is worked out as soon as it is seen, so at the period's tick it is
                # sent at once: the robot's clock does not wait for a forward pass (on a busy CPU, tens of ms)
                action, length, last_step = self._action(obs), 0, None
                self.pace.restart(time.monotonic())
                new_episode = False
            held = self._hold_if_needed()
            if held == "exit":
                return
            if held == "resumed":  # a stop cut the episode: a new one begins
                new_episode = True
                continue
            delay = self.pace.tick - time.monotonic()
            if delay > 0:  # (woken early by a stop: the hold is looked at again, then the rest is waited)
                self.wake.wait(delay)
                continue
            if self.controls.demo_ended:  # the success key ended the demo: the next episode
                new_episode = True
                continue
            person = self._person_action()  # (a take-over: the person's action instead, on the same path)
            if person is None and self.controls.demo:  # a demo moves only by hand: it waits for the keys
                self._set_state(ActorState.DEMO_WAITING)
                self.wake.wait(CONTROL_POLL_SECONDS)
                self.pace.restart(time.monotonic())
                continue
            if not self._may_move():  # (the step is sent late, once the hold says so, or never)
                continue
            person = self._person_action()
            if person is None and self.controls.demo:
                continue
            sent = action if person is None else person
            self._set_state(ActorState.ACTING if person is None else ActorState.DRIVEN_BY_HAND)
            started = time.monotonic()
            try:
                raw, reward, terminated, truncated, info = self.env.step(scale_action(sent, self.action_space))
            except RobotNotArmed:  # (reached after its arming ran out, or disarmed by a Stop: asked again)
                continue
            self.pace.sent(started)
            period = None if last_step is None else started - last_step
            last_step = started
            self.step, length = self.step + 1, length + 1
            obs = model_image(raw, cfg.image_size, cfg.env_id)
            display = display_image(self.env, cfg.display_size, obs)
            self.frame = self._camera_view(display)
            self.outbox.put(Transition(
                sent, obs, float(reward), bool(terminated), bool(truncated), info, display, period,
                self.controls.evaluation_round, person is not None,
            ))  # fmt: skip
            if terminated or truncated or length >= cfg.episode_steps:
                new_episode = True
                continue
            self._read_learner()  # (a new policy is loaded here, between the steps)
            action = self._action(obs)

    def _action(self, obs: np.ndarray) -> np.ndarray:
        """The acting policy's action: its mean in an evaluation episode, else its exploring one."""
        return self.policy.act(obs, step=self.step, evaluation=self.controls.evaluation_round is not None)

    # ------------------------------------------------------------------ the robot's hold
    def _take_robot(self) -> bool:
        """Hold the robot for the run's claim before its first move; while another run's actor holds it, say so
        and wait, moving nothing. False: exit (the learner is gone, or the run was claimed again meanwhile)."""
        if self.robot is None:
            return True
        while True:
            self._read_learner()
            if self._watchdog() in EXIT_REASONS:
                return False
            asked = time.monotonic()
            try:
                answer = self.store.take_robot(
                    robot=self.robot, run_id=self.settings.run_id, claim=self.claim, holder=self.holder
                )
            except Exception:  # (the store away: asked again)
                answer = None
            if answer is not None and answer.taken:
                self.holding, self.hold_confirmed_at = True, asked
                return True
            if answer is not None and answer.stale_claim:
                self._stop_arm(ActorState.CLAIM_LOST)
                return False
            if answer is not None and answer.busy_with is not None:
                self._set_state(ActorState.robot_busy(answer.busy_with))
            self.wake.wait(TAKE_RETRY_SECONDS)

    def _may_move(self) -> bool:
        """The robot may move now, and is armed for ARM_SECONDS: this actor holds it, for the run's current claim,
        renewed lately, and no Stop is pending (always true of an env that is no robot). Asked before every move;
        while it is false the move waits a poll, and a pending Stop is the controls' at once."""
        if self.robot is None:
            return True
        asked = time.monotonic()
        answer = None
        with contextlib.suppress(Exception):
            if not self.hold_lost:
                answer = self.store.may_move_robot(robot=self.robot, holder=self.holder)
        if answer is not None and answer.held:
            self.hold_confirmed_at = max(self.hold_confirmed_at, asked)
        if answer is not None and answer.allowed and not self.controls.stop_requested:
            self.env.unwrapped.arm(seconds=ARM_SECONDS - (time.monotonic() - asked))  # type: ignore[attr-defined]
            return True
        if answer is not None and answer.stop_pending:
            self.controls.stop_requested = True
        self.wake.wait(CONTROL_POLL_SECONDS)
        return False

    def _hold_is_sure(self) -> bool:
        """The store confirmed this process's hold lately enough that nobody else can have taken it since."""
        return self.holding and not self.hold_lost and time.monotonic() - self.hold_confirmed_at < HOLD_SURE_SECONDS

    def _set_state(self, state: str) -> None:
        if state != self.state:
            self.state = state
            self.outbox.put(StateChange(state))

    def _hold_if_needed(self) -> str | None:
        """Hold the arm while the watchdog or a person says so: "exit" (the learner is gone or closed the
        actor), "resumed" (a stop ended: the episode is over), None (act now)."""
        self.wake.clear()
        reason = self._watchdog()
        if reason is None and not self.controls.stop_requested:
            return None
        self._stop_arm(ActorState.STOPPED if reason in (None, ActorState.CLOSED) else reason)
        if reason in EXIT_REASONS:
            return "exit"
        if reason == ActorState.DATABASE_GONE:  # the person must see it: stopped until they press Resume
            self._wait_for_store()
        while True:
            self.wake.clear()
            self._read_learner()
            reason = self._watchdog()
            if reason in EXIT_REASONS:
                return "exit"
            if reason is None and not self.controls.stop_requested:
                return "resumed"
            self.wake.wait(self.period)

    def _stop_arm(self, state: str) -> None:
        """Hold the arm (once the hold is lost or may be, let go of it instead: another process may drive it) and
        say so."""
        self._secure_arm(lost=state == ActorState.CLAIM_LOST)
        self._set_state(state)
        if state in (ActorState.LEARNER_GONE, ActorState.DATABASE_GONE, ActorState.CLAIM_LOST):
            print(f"actor of run {self.settings.run_id}: arm {state}", flush=True)
        with contextlib.suppress(Exception):  # the pages see it now (and the actor may exit next)
            self.store.report_actor(run_id=self.settings.run_id, state=state)

    def _secure_arm(self, *, lost: bool) -> None:
        """Hold the arm safe while this process surely holds it; else (`lost`, or not confirmed lately) let go."""
        unwrapped = self.env.unwrapped
        if self.robot is not None and (lost or not self._hold_is_sure()):
            unwrapped.let_go()  # type: ignore[attr-defined]
        elif not getattr(unwrapped, "stopped", False):
            stop = getattr(unwrapped, "stop", None)
            if stop is not None:
                stop()

    def _wait_for_store(self) -> None:
        """After an outage: once the store answers again, the run's robot is marked stopped (a person resumes);
        unless this process no longer holds the robot (another took it over meanwhile): it lets go and exits."""
        while True:
            with contextlib.suppress(Exception):
                if self.robot is not None and not self.store.renew_robot(robot=self.robot, holder=self.holder):
                    self.hold_lost = True
                    return
                self.store.request_robot_stop(run_id=self.settings.run_id)
                controls = self.controls
                controls.asked_after = controls.last_answer = time.monotonic()
                controls.stop_requested = True
                return
            self._read_learner()
            if self._watchdog() in EXIT_REASONS:
                return
            time.sleep(self.period)

    def _begin_episode(self) -> np.ndarray | None:
        """Reset the scene and send the first observation; None: exit. The arm goes to its start pose first
        (env.reset()); then, when a person must reset the scene, the card asks them and their Ready starts the
        episode, its first observation the scene as they left it. A stop (or the watchdog) that held the arm while
        they reset, once over, sends the arm to its start pose again and asks them again. While Evaluate now has
        episodes pending, this one is taken from the store: an evaluation episode (its steps carry the round)
        acting with the policy's mean action."""
        cfg, run_id = self.config, self.settings.run_id
        person = self.settings.person_reset or getattr(self.env.unwrapped, "needs_person_reset", False)
        while True:
            if self._hold_if_needed() == "exit":  # (a pending Stop holds here until Resume)
                return None
            if not self._may_move():
                continue
            try:
                raw, info = self.env.reset()  # the arm to its start pose, before anybody's hands are in the scene
            except RobotNotArmed:  # (disarmed by a Stop meanwhile: asked again)
                continue
            if not person:
                break
            waited = self._wait_for_person()
            if waited == "exit":
                return None
            if waited == "ready":
                look = getattr(self.env.unwrapped, "look", None)  # (a robot env: the scene as the person left it)
                if look is not None:
                    raw, info = look()
                break
        self.policy.episode_begins()
        controls = self.controls
        controls.evaluation_round, controls.demo, controls.demo_ended = None, False, False
        if controls.evaluation_pending > 0:  # (the store unreachable: a training episode, the arm held)
            with contextlib.suppress(Exception):
                controls.evaluation_round = self.store.take_evaluation_episode(run_id=run_id)
        if controls.evaluation_round is None and controls.demo_pending > 0:
            with contextlib.suppress(Exception):
                controls.demo = self.store.take_demo_episode(run_id=run_id)
        obs = model_image(raw, cfg.image_size, cfg.env_id)
        display = display_image(self.env, cfg.display_size, obs)
        self.frame = self._camera_view(display)
        self._set_state(ActorState.ACTING)
        self.outbox.put(EpisodeStart(obs, info, display))
        return obs

    def _wait_for_person(self) -> str:
        """Ask a person to reset the scene and wait for their Ready: "ready"; "exit" (the learner is gone or closed
        the actor); "resumed" (the arm was held meanwhile, by a stop or the watchdog, and may move again)."""
        self._set_state(ActorState.WAITING_FOR_RESET)
        asked_at: int | None = None  # the Ready count when the reset was asked for (None: not asked yet)
        while asked_at is None or self.controls.reset_count <= asked_at:
            if asked_at is None:  # (while the store is unreachable the watchdog holds the arm)
                with contextlib.suppress(Exception):
                    asked_at = self.store.request_scene_reset(run_id=self.settings.run_id).reset_count
            self._read_learner()
            held = self._hold_if_needed()
            if held is not None:
                return held
            self._refresh_frame()
            self.wake.wait(self.period)
        return "ready"

    def _refresh_frame(self) -> None:
        """While the person resets: the live view follows the camera (a robot env reads it anew; others render)."""
        unwrapped = self.env.unwrapped
        with contextlib.suppress(Exception):
            if hasattr(unwrapped, "read_camera"):
                unwrapped.last_frame = unwrapped.read_camera()
            self.frame = self._camera_view(display_image(self.env, self.config.display_size, self.frame))

    def _camera_view(self, display: np.ndarray) -> np.ndarray:
        """What the live view shows (and a goal capture takes): a robot env's whole camera frame, else `display`."""
        frame = getattr(self.env.unwrapped, "last_frame", None)
        return display if frame is None else np.asarray(frame)

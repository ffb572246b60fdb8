// Take over a run's robot by hand: hold keys (or move a gamepad's sticks) to drive, release to hand it back.
// While anything is held the page sends the action (POST /api/runs/{id}/robot/drive) every half control period;
// the robot's own process sends it to the arm instead of the policy's, at its own pace and within its limits, for
// one period from when it saw it, so a dropped connection hands the arm back within a period. Releasing everything
// sends a hand-back at once. A Stop (X, or the card's button) ends a take-over: the server refuses actions until
// Resume, and the keys must be released and pressed again. G is the success key: the episode under way (or just
// ended) is a success, and its last frames teach the classifier; it also ends a demo episode. Record demos makes the
// robot's next episodes wait for the keys, the policy idle.
import { api, el } from "/static/app.js";

/** The keys of each action dimension, in order: [dimension's name, key for -1, key for +1, what the page shows]. */
export const DRIVE_KEYS = [
  ["x", ["ArrowLeft", "a"], ["ArrowRight", "d"], "← → or A D"],
  ["y", ["ArrowDown", "s"], ["ArrowUp", "w"], "↓ ↑ or S W"],
  ["z", ["q"], ["e"], "Q E"],
  ["4th", ["z"], ["c"], "Z C"],
];
const SUCCESS_KEY = "g";
const DEADZONE = 0.15; // a gamepad axis nearer 0 than this is at rest
const SEND_MIN_MS = 20; // the fastest the page sends, whatever the robot's rate

/** The sign a key gives its dimension: [dimension, -1 or +1], or null for a key that drives nothing. */
function keyDimension(key, dims) {
  const name = key.length === 1 ? key.toLowerCase() : key;
  for (let dim = 0; dim < Math.min(dims, DRIVE_KEYS.length); dim += 1) {
    const [, minus, plus] = DRIVE_KEYS[dim];
    if (minus.includes(name)) return [dim, -1];
    if (plus.includes(name)) return [dim, 1];
  }
  return null;
}

/** The first connected gamepad's action over `dims` dimensions (left stick x, y; right stick y; triggers), or
 * null while it is at rest or there is none. */
function gamepadAction(dims) {
  const pads = typeof navigator.getGamepads === "function" ? [...navigator.getGamepads()].filter(Boolean) : [];
  if (!pads.length) return null;
  const pad = pads[0];
  const axis = (index, sign = 1) => (pad.axes.length > index ? sign * pad.axes[index] : 0);
  const trigger = (index) => (pad.buttons.length > index ? pad.buttons[index].value : 0);
  const values = [axis(0), axis(1, -1), axis(3, -1), trigger(7) - trigger(6)].slice(0, dims);
  const action = values.map((value) => (Math.abs(value) < DEADZONE ? 0 : Math.max(-1, Math.min(1, value))));
  while (action.length < dims) action.push(0);
  return action.some((value) => value !== 0) ? action : null;
}

export class TakeOver {
  /** `container`: where the take-over's panel goes; `say(kind, text)` tells the person what happened. */
  constructor(container, { say = () => {} } = {}) {
    this.container = container;
    this.say = say;
    this.robot = null; // the run's robot card as the API last gave it
    this.held = new Set(); // keys held now
    this.refused = false; // a Stop refused the take-over: nothing is sent until every key is released
    this.driving = false; // the page sent an action since the last hand-back
    this.timer = null;
    this.inFlight = false;
    this.panel = {
      root: el("div", { class: "panel takeover", id: "takeover" }),
      driver: el("strong", { class: "takeover-driver", id: "takeover-driver" }),
      keys: el("span", { class: "takeover-keys small", id: "takeover-keys" }),
      help: el("div", { class: "takeover-help robot-help", id: "takeover-help" }),
      demos: el("div", { class: "takeover-demos small", id: "takeover-demos" }),
      episodes: el("input", { type: "number", min: 1, max: 20, value: 5, required: true, id: "demo-episodes",
        "aria-label": "demo episodes to drive by hand" }),
      record: el("button", { class: "btn", type: "submit", id: "record-demos",
        title: "The next episodes wait for your keys; the policy acts again after them" }, "Record demos"),
      success: el("button", { class: "btn", type: "button", id: "mark-success",
        title: "The episode is a success: its last frames teach the classifier" }, "Success ", el("kbd", {}, "G")),
    };
    const demoForm = el("form", { class: "inline-form" }, this.panel.record,
      el("label", { class: "small" }, this.panel.episodes, " episodes by hand"));
    demoForm.addEventListener("submit", (event) => {
      event.preventDefault();
      this.post("demos", { episodes: Number(this.panel.episodes.value) }, "Record demos");
    });
    this.panel.success.addEventListener("click", () => this.post("success", undefined, "Success"));
    this.panel.root.append(this.panel.driver, " ", this.panel.keys, this.panel.help, this.panel.demos,
      el("div", { class: "robot-buttons" }, this.panel.success, demoForm));
    container.replaceChildren(this.panel.root);
    document.addEventListener("keydown", (event) => this.keydown(event));
    document.addEventListener("keyup", (event) => this.keyup(event));
    window.addEventListener("blur", () => this.releaseAll());
    document.addEventListener("visibilitychange", () => { if (document.hidden) this.releaseAll(); });
    window.addEventListener("gamepadconnected", () => this.ensureLoop());
  }

  /** The run's robot as the API gave it (null: none shown). */
  show(robot) {
    this.robot = robot;
    this.container.classList.toggle("hidden", !robot || !robot.action_dims);
    if (!robot || !robot.action_dims) {
      this.releaseAll();
      return;
    }
    const dims = robot.action_dims;
    const listed = DRIVE_KEYS.slice(0, dims).map(([name, , , keys]) => `${keys} (${name})`);
    const unkeyed = dims > DRIVE_KEYS.length ? `; dimensions past the 4th: a gamepad only` : "";
    this.panel.keys.textContent = `Take over: hold ${listed.join(", ")} or move a gamepad's sticks; ` +
      `release to hand back${unkeyed}. G: the episode is a success. X stops the robot.`;
    const demos = robot.demo_pending;
    const inDemo = (robot.actor_state || "").startsWith("demo");
    this.panel.demos.textContent = demos || inDemo
      ? `Demos: ${inDemo ? "this episode is yours (the robot moves only while you hold a key; G ends it); " : ""}` +
        `${demos} more to begin` : "";
    this.panel.record.disabled = demos > 0;
    if (robot.stop_requested) this.stopDriving();
    this.renderDriver();
  }

  renderDriver() {
    const robot = this.robot;
    let text = "The policy drives.";
    if (robot && robot.stop_requested) text = "Stopped: nobody drives until Resume.";
    else if (this.driving) text = "You drive.";
    const help = Boolean(robot && robot.asks_for_help && !robot.stop_requested && !this.driving);
    this.panel.driver.textContent = text;
    this.panel.help.textContent = help
      ? "The run asks for help: none of its recent questions was a success. Hold the keys to show it the way." : "";
    this.panel.root.classList.toggle("driving", this.driving);
    this.panel.root.classList.toggle("asks-for-help", help);
  }

  typing(event) {
    const target = event.target;
    return target && (target.isContentEditable || ["INPUT", "TEXTAREA", "SELECT"].includes(target.tagName));
  }

  keydown(event) {
    if (!this.robot || !this.robot.action_dims || this.typing(event) || event.ctrlKey || event.metaKey ||
        event.altKey) return;
    if (event.key.toLowerCase() === SUCCESS_KEY && !event.repeat) {
      event.preventDefault();
      this.post("success", undefined, "Success");
      return;
    }
    if (!keyDimension(event.key, this.robot.action_dims)) return;
    event.preventDefault(); // (arrows would scroll the page)
    this.held.add(event.key.length === 1 ? event.key.toLowerCase() : event.key);
    this.ensureLoop();
  }

  keyup(event) {
    const key = event.key.length === 1 ? event.key.toLowerCase() : event.key;
    if (!this.held.delete(key)) return;
    if (this.held.size === 0 && !gamepadAction(this.robot ? this.robot.action_dims : 0)) this.handBack();
  }

  releaseAll() {
    if (this.held.size === 0 && !this.driving) return;
    this.held.clear();
    this.handBack();
  }

  /** The action the held keys (or the gamepad) ask for, or null when nothing is held. */
  action() {
    const dims = this.robot.action_dims;
    const pad = gamepadAction(dims);
    if (pad) return pad;
    if (this.held.size === 0) return null;
    const action = new Array(dims).fill(0);
    for (const key of this.held) {
      const found = keyDimension(key, dims);
      if (found) action[found[0]] = Math.max(-1, Math.min(1, action[found[0]] + found[1]));
    }
    return action;
  }

  periodMs() {
    const hz = this.robot && this.robot.control_hz ? this.robot.control_hz : 10;
    return Math.max(SEND_MIN_MS, 500 / hz); // half a control period
  }

  ensureLoop() {
    if (this.timer === null) this.tick();
  }

  /** Every half control period while something is held (or a gamepad is out of rest): send the action. */
  async tick() {
    this.timer = null;
    if (!this.robot || !this.robot.action_dims) return;
    const action = this.action();
    if (action === null) {
      this.refused = false;
      if (this.driving) this.handBack();
      if (typeof navigator.getGamepads === "function" && [...navigator.getGamepads()].some(Boolean)) {
        this.timer = setTimeout(() => this.tick(), 100); // (watch the gamepad)
      }
      return;
    }
    this.timer = setTimeout(() => this.tick(), this.periodMs());
    if (this.refused || this.inFlight) return;
    this.inFlight = true;
    try {
      const robot = await api("POST", `/api/runs/${this.robot.run_id}/robot/drive`, { action });
      const { asks_for_help: _unjudged, ...controls } = robot; // (drive's answer skips the verdict)
      this.robot = { ...this.robot, ...controls };
      if (!this.driving) {
        this.driving = true;
        this.renderDriver();
      }
    } catch (error) {
      this.refused = true; // (a Stop, or no actor): nothing more until the keys are released and pressed again
      this.driving = false;
      this.renderDriver();
      this.say("error", `Take-over refused: ${error.message}`);
    } finally {
      this.inFlight = false;
    }
  }

  /** POST the robot's `action` (success, demos) and say how it went. */
  async post(action, body, what) {
    if (!this.robot) return;
    try {
      this.robot = { ...this.robot, ...(await api("POST", `/api/runs/${this.robot.run_id}/robot/${action}`, body)) };
      this.say("info", action === "success" ? "Marked a success: its last frames teach the classifier."
        : `${what}: the next ${body.episodes} episodes are yours to drive.`);
      this.show(this.robot);
    } catch (error) {
      this.say("error", `${what} refused: ${error.message}`);
    }
  }

  stopDriving() {
    if (this.held.size || this.driving) this.refused = true;
    this.driving = false;
  }

  async handBack() {
    const wasDriving = this.driving;
    this.driving = false;
    this.renderDriver();
    if (!wasDriving || !this.robot) return;
    try {
      await api("POST", `/api/runs/${this.robot.run_id}/robot/hand-back`);
    } catch (error) {
      this.say("error", `Hand-back failed (the robot takes over again within a period anyway): ${error.message}`);
    }
  }
}

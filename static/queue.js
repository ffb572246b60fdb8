// Answer queue: one query at a time; Y / N / S / U; the next one arrives by polling /api/queries/next. Above the
// questions, the robots at work (GET /api/robots): R presses Ready once the scene is reset, X stops every robot.
// RobotCards is shared with the run page (run.js), which shows its run's robot the same way, with Evaluate now.
// A question about an evaluation episode's last frame (strategy "evaluation") carries a tag saying so.
import { api, el, fmtNumber, fmtPercent, poll, setPendingBadge, setUpNotifyButton } from "/static/app.js";

const ROBOT_POLL_MS = 700; // while a robot is shown: its camera and a waiting reset within a second
const ROBOT_IDLE_POLL_MS = 3000; // while none is
const EVALUATION_EPISODES = { default: 5, min: 1, max: 20 }; // Evaluate now (POST /api/runs/{id}/robot/evaluate)

/** Whether a key press belongs to a field being typed in (then the page's keys do nothing). */
export function typing(event) {
  if (event.ctrlKey || event.metaKey || event.altKey) return true;
  const target = event.target;
  return Boolean(target && (target.tagName === "INPUT" || target.tagName === "TEXTAREA" || target.tagName === "SELECT"
    || target.isContentEditable));
}

/** One card per robot at work (a RobotStatusOut each) in `container`: the live camera, what the actor says,
 * Stop robot / Resume, and when the actor waits for a scene reset, Ready; while Evaluate now has episodes
 * pending, how many. With `evaluate` (the run page) also Evaluate now and its episodes. Cards are updated in
 * place. */
export class RobotCards {
  constructor(container, { say = () => {}, onChange = () => {}, evaluate = false } = {}) {
    this.container = container;
    this.say = say;
    this.onChange = onChange;
    this.evaluate = evaluate;
    this.cards = new Map(); // run id -> the card's elements
    this.robots = [];
    this.busy = new Set(); // run ids with a request in flight
  }

  render(robots) {
    this.robots = robots;
    const shown = new Set(robots.map((robot) => robot.run_id));
    for (const [runId, card] of this.cards) {
      if (!shown.has(runId)) {
        card.root.remove();
        this.cards.delete(runId);
      }
    }
    // waiting resets first (R presses the first one's Ready), then by run id
    const ordered = [...robots].sort((a, b) => Number(b.reset_needed) - Number(a.reset_needed) || a.run_id - b.run_id);
    ordered.forEach((robot, index) => {
      const card = this.cards.get(robot.run_id) || this.make(robot);
      this.update(card, robot);
      const there = this.container.children[index];
      if (there !== card.root) this.container.insertBefore(card.root, there || null);
    });
    this.onChange(robots);
  }

  make(robot) {
    const runId = robot.run_id;
    const card = {
      root: el("section", { class: "panel robot-card", "data-run-id": runId }),
      camera: el("img", { class: "thumb robot-camera hidden", alt: `live camera of run #${runId}` }),
      noCamera: el("div", { class: "robot-no-camera muted small" }, "No camera frame yet."),
      title: el("h2", { class: "robot-title" }),
      reset: el("p", { class: "robot-reset hidden" }, "Reset the scene, then press Ready ", el("kbd", {}, "R")),
      stopped: el("span", { class: "status stopped robot-stopped hidden" }, "Stopped"),
      state: el("div", { class: "robot-state small" }),
      ready: el("button", { class: "btn primary robot-ready hidden", type: "button" }, "Ready ", el("kbd", {}, "R")),
      stop: el("button", { class: "btn danger robot-stop", type: "button" }, "Stop robot ", el("kbd", {}, "X")),
      resume: el("button", { class: "btn robot-resume hidden", type: "button" }, "Resume"),
      evaluating: el("p", { class: "robot-evaluating small hidden" }),
      help: el("p", { class: "robot-help hidden" }, "Asks for help: none of its recent questions was a success. ",
        el("a", { href: `/runs/${runId}#takeover-area` }, "Take over"),
        " on the run page (hold the arrow keys) to show it the way."),
      episodes: el("input", {
        class: "robot-episodes", type: "number", min: EVALUATION_EPISODES.min, max: EVALUATION_EPISODES.max,
        value: EVALUATION_EPISODES.default, required: true, "aria-label": "episodes to evaluate",
      }),
      evaluate: el("button", { class: "btn robot-evaluate", type: "submit",
        title: "Episodes with the policy's mean action; the last frame of each is asked on the answer queue" },
        "Evaluate now"),
      cameraUrl: null,
    };
    const evaluateForm = el("form", { class: "inline-form robot-evaluate-form" }, card.evaluate,
      el("label", { class: "small" }, card.episodes, " episodes"));
    evaluateForm.addEventListener("submit", (event) => {
      event.preventDefault();
      this.act(runId, "evaluate", { episodes: Number(card.episodes.value) });
    });
    card.camera.addEventListener("load", () => {
      card.camera.classList.remove("hidden");
      card.noCamera.classList.add("hidden");
    });
    card.camera.addEventListener("error", () => {
      card.noCamera.textContent = "The camera frame could not be loaded.";
      card.noCamera.classList.remove("hidden");
    });
    card.ready.addEventListener("click", () => this.act(runId, "ready"));
    card.stop.addEventListener("click", () => this.act(runId, "stop"));
    card.resume.addEventListener("click", () => this.act(runId, "resume"));
    card.root.append(
      el("div", { class: "robot-view" }, card.camera, card.noCamera),
      el("div", { class: "robot-body" },
        el("div", { class: "robot-head" }, card.title, card.stopped),
        card.reset, card.help, card.state, card.evaluating,
        el("div", { class: "robot-buttons" }, card.ready, card.stop, card.resume,
          this.evaluate ? evaluateForm : null)),
    );
    this.cards.set(runId, card);
    return card;
  }

  update(card, robot) {
    const runId = robot.run_id;
    card.root.classList.toggle("waiting", robot.reset_needed);
    card.root.classList.toggle("stopped", robot.stop_requested);
    card.root.classList.toggle("silent", !robot.live);
    card.title.replaceChildren("Robot · ", el("a", { href: `/runs/${runId}` }, `run #${runId}`),
      robot.run_name ? ` ${robot.run_name}` : "");
    card.reset.classList.toggle("hidden", !robot.reset_needed);
    card.ready.classList.toggle("hidden", !robot.reset_needed);
    card.stopped.classList.toggle("hidden", !robot.stop_requested);
    card.stop.classList.toggle("hidden", robot.stop_requested);
    card.resume.classList.toggle("hidden", !robot.stop_requested);
    const busy = this.busy.has(runId);
    for (const button of [card.ready, card.stop, card.resume]) button.disabled = busy;
    const pending = robot.evaluation_pending;
    card.evaluating.classList.toggle("hidden", !pending);
    card.help.classList.toggle("hidden", !robot.asks_for_help || robot.stop_requested);
    card.evaluating.textContent = pending
      ? `Evaluating: ${pending} episode${pending === 1 ? "" : "s"} left (round ${robot.evaluation_round})` : "";
    card.evaluate.disabled = busy || pending > 0; // (one round at a time)
    const said = robot.actor_state ? `Actor: ${robot.actor_state}` : "Actor: –";
    const age = robot.actor_age_seconds;
    card.state.textContent = robot.live ? said
      : `${said} · not reporting for ${age === null ? "a while" : Math.max(0, Math.round(age)) + " s"}`;
    if (robot.stop_requested) card.state.textContent += " · the arm holds still until Resume";
    if (robot.camera_url !== card.cameraUrl) {
      card.cameraUrl = robot.camera_url;
      if (robot.camera_url) card.camera.src = robot.camera_url;
    }
  }

  /** The runs' Ready (R): the first card waiting for a scene reset. */
  readyFirst() {
    const waiting = this.robots.filter((robot) => robot.reset_needed).sort((a, b) => a.run_id - b.run_id)[0];
    if (!waiting) {
      this.say("info", "No robot waits for a scene reset.");
      return;
    }
    this.act(waiting.run_id, "ready");
  }

  /** Stop robot (X) for every robot shown that is not stopped yet. */
  stopAll() {
    for (const robot of this.robots) if (!robot.stop_requested) this.act(robot.run_id, "stop");
  }

  async act(runId, action, body = undefined) {
    if (this.busy.has(runId)) return;
    this.busy.add(runId);
    this.refreshCard(runId);
    let robot = null;
    try {
      robot = await api("POST", `/api/runs/${runId}/robot/${action}`, body);
      const done = {
        ready: `Run #${runId}: Ready. The robot starts its episode.`,
        stop: `Run #${runId}: robot stopped. It holds still until you press Resume.`,
        resume: `Run #${runId}: robot resumed.`,
        evaluate: `Run #${runId}: evaluating ${body && body.episodes} episodes with the policy's mean action; `
          + "the last frame of each is asked on the answer queue.",
      };
      this.say(action === "stop" ? "warn" : "ok", done[action]);
    } catch (error) {
      const refused = action === "evaluate" ? error.message : "no reset is waiting (Ready was pressed already?)";
      const text = error.status === 409 ? refused : error.message;
      this.say("error", `Run #${runId}: ${text}`);
    } finally {
      this.busy.delete(runId);
    }
    if (robot) this.render(this.robots.map((shown) => (shown.run_id === runId ? robot : shown)));
    else this.refreshCard(runId);
  }

  refreshCard(runId) {
    const card = this.cards.get(runId);
    const shown = this.robots.find((robot) => robot.run_id === runId);
    if (card && shown) this.update(card, shown);
  }

  /** Keys R (Ready) and X (Stop robot) while a robot is shown; true when the key was one of them. */
  key(event) {
    if (typing(event) || !this.robots.length) return false;
    const key = event.key.toLowerCase();
    if (key === "r" && !event.repeat) this.readyFirst();
    else if (key === "x") this.stopAll();
    else return false;
    event.preventDefault();
    return true;
  }

  /** Poll `load()` (a list of RobotStatusOut) and render it: fast while a robot is shown, slowly while none is;
   * not while the tab is hidden. */
  start(load) {
    const tick = async () => {
      if (!document.hidden) {
        try {
          this.render(await load());
        } catch (error) {
          console.warn(error);
        }
      }
      setTimeout(tick, this.robots.length ? ROBOT_POLL_MS : ROBOT_IDLE_POLL_MS);
    };
    tick();
  }
}

const queue = {
  runId: null,
  current: null,
  goalSetKey: null,
  history: [], // ids answered or skipped here, newest last (for undo)
  busy: false,
};

function nextUrl() {
  return "/api/queries/next" + (queue.runId ? `?run_id=${queue.runId}` : "");
}

function message(kind, text) {
  const box = document.getElementById("queue-message");
  if (!text) {
    box.classList.add("hidden");
    return;
  }
  box.className = "alert " + kind;
  box.textContent = text;
}

function renderGoals(item) {
  const panel = document.getElementById("goal-panel");
  const key = item.run ? `${item.run.id}:${item.goal_examples.map((e) => e.id).join(",")}` : "";
  if (key === queue.goalSetKey) return;
  queue.goalSetKey = key;
  if (!item.goal_examples.length) {
    panel.classList.add("hidden");
    return;
  }
  document.getElementById("goal-strip").replaceChildren(
    ...item.goal_examples.flatMap((e) => {
      const model = el("figure", {},
        el("img", { class: "thumb pixelated model", src: e.model_url, alt: `model view of ${e.filename}` }),
        el("figcaption", {}, "model view"));
      const photo = el("figure", {}, el("img", { class: "thumb display", src: e.display_url, alt: e.filename }),
        el("figcaption", {}, e.filename));
      // a photo already of the model's size and square (a 48×48 render) is the model's view: shown once
      model.querySelector("img").addEventListener("load", (event) => {
        const image = event.target;
        if (image.naturalWidth === e.width && image.naturalHeight === e.height) {
          photo.remove();
          model.querySelector("figcaption").textContent = `${e.filename} (the model's view)`;
        }
      });
      return [photo, model];
    })
  );
  panel.classList.remove("hidden");
}

function render(item) {
  document.getElementById("pending-count").textContent = String(item.pending);
  setPendingBadge(item.pending_all_runs);
  const undoable = queue.history.length > 0;
  document.getElementById("answer-undo").disabled = !undoable;
  document.getElementById("empty-undo").disabled = !undoable;
  const query = item.query;
  document.getElementById("queue-item").classList.toggle("hidden", !query);
  document.getElementById("queue-empty").classList.toggle("hidden", !!query);
  if (!query) {
    queue.current = null;
    document.getElementById("goal-panel").classList.add("hidden");
    queue.goalSetKey = null;
    return;
  }
  renderGoals(item);
  if (queue.current && queue.current.id === query.id) return;
  queue.current = query;
  const tag = document.getElementById("query-tag");
  const evaluation = query.strategy === "evaluation";
  tag.classList.toggle("hidden", !evaluation);
  tag.textContent = evaluation
    ? `Last frame of evaluation episode ${query.info.episode} (round ${query.info.evaluation_round})` : "";
  document.getElementById("query-display").src = query.display_image_url;
  document.getElementById("query-model").src = query.model_image_url;
  const modelImage = document.getElementById("query-model");
  modelImage.onload = () => {
    document.getElementById("query-model-caption").textContent =
      `The learner's view (${modelImage.naturalWidth}×${modelImage.naturalHeight})`;
  };
  const run = item.run;
  const facts = [
    ["Query", `#${query.id}`],
    ["Run", run ? [el("a", { href: `/runs/${run.id}` }, `#${run.id}`), " " + run.env_id] : [`#${query.run_id}`]],
    ["Env step", query.env_step.toLocaleString()],
    ["Classifier score", ["f", el("sub", {}, "ψ"), ` = ${fmtNumber(query.score, 3)} `,
      el("span", { class: "muted" }, `(p = ${fmtPercent(query.probability)})`)]],
    ["Why asked", query.strategy === "argmax" ? "highest score since the last query" : query.strategy],
  ];
  document.getElementById("query-facts").replaceChildren(
    ...facts.flatMap(([term, value]) => [el("dt", {}, term), el("dd", {}, ...[value].flat())])
  );
}

async function refresh() {
  const item = await api("GET", nextUrl());
  render(item);
}

async function act(kind) {
  if (queue.busy) return;
  if (kind === "undo") return undo();
  const query = queue.current;
  if (!query) return;
  queue.busy = true;
  try {
    if (kind === "skip") {
      await api("POST", `/api/queries/${query.id}/skip`, { labeler: "web" });
      message("info", `Skipped query #${query.id}. Press U to undo.`);
    } else {
      const success = kind === "yes";
      await api("POST", `/api/queries/${query.id}/answer`, { success, labeler: "web" });
      message("ok", `Answered ${success ? "yes" : "no"} to query #${query.id}. Press U to undo.`);
    }
    queue.history.push(query.id);
    queue.current = null;
    await refresh();
  } catch (error) {
    message("error", error.message);
    if (error.status === 404 || error.status === 409) await refresh();
  } finally {
    queue.busy = false;
  }
}

async function undo() {
  const id = queue.history[queue.history.length - 1];
  if (id === undefined) {
    message("info", "Nothing to undo.");
    return;
  }
  queue.busy = true;
  try {
    await api("POST", `/api/queries/${id}/undo`);
    queue.history.pop();
    message("info", `Query #${id} is back in the queue.`);
    queue.current = null;
    await refresh();
  } catch (error) {
    if (error.status === 409 || error.status === 404) queue.history.pop();
    message("error", "Cannot undo: " + error.message);
    await refresh();
  } finally {
    queue.busy = false;
  }
}

document.addEventListener("DOMContentLoaded", () => {
  const root = document.getElementById("queue");
  if (!root) return; // (the run page imports RobotCards from here)
  for (const id of ["query-display", "query-model"]) {
    document.getElementById(id).addEventListener("error", () => {
      if (queue.current) message("error", `The image of query #${queue.current.id} could not be loaded from the server.`);
    });
  }
  queue.runId = root.dataset.runId || null;
  setUpNotifyButton(document.getElementById("notify-toggle"));
  document.getElementById("answer-yes").addEventListener("click", () => act("yes"));
  document.getElementById("answer-no").addEventListener("click", () => act("no"));
  document.getElementById("answer-skip").addEventListener("click", () => act("skip"));
  document.getElementById("answer-undo").addEventListener("click", () => act("undo"));
  document.getElementById("empty-undo").addEventListener("click", () => act("undo"));
  const robotSection = document.getElementById("robots");
  const robots = new RobotCards(document.getElementById("robot-cards"), {
    say: message,
    onChange: (list) => robotSection.classList.toggle("hidden", list.length === 0),
  });
  robots.start(() => api("GET", "/api/robots"));
  document.addEventListener("keydown", (event) => {
    if (typing(event) || robots.key(event)) return;
    const kind = { y: "yes", n: "no", s: "skip", u: "undo" }[event.key.toLowerCase()];
    if (!kind) return;
    event.preventDefault();
    act(kind);
  });
  poll(async () => {
    if (!queue.busy) await refresh();
  }, 2000);
});

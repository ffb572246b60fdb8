// Answer queue: one query at a time; Y / N / S / U; the next one arrives by polling /api/queries/next.
import { api, el, fmtNumber, fmtPercent, poll, setPendingBadge, setUpNotifyButton } from "/static/app.js";

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
  document.addEventListener("keydown", (event) => {
    if (event.ctrlKey || event.metaKey || event.altKey) return;
    const target = event.target;
    if (target && (target.tagName === "INPUT" || target.tagName === "TEXTAREA" || target.isContentEditable)) return;
    const kind = { y: "yes", n: "no", s: "skip", u: "undo" }[event.key.toLowerCase()];
    if (!kind) return;
    event.preventDefault();
    act(kind);
  });
  poll(async () => {
    if (!queue.busy) await refresh();
  }, 2000);
});

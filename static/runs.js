// Runs page: the table, refreshed every 3 s from /api/runs.
import {
  api, el, fmtAge, fmtDuration, fmtPercent, fmtSteps, isActive, isLive, poll, setPendingBadge, statusPill,
} from "/static/app.js";

const selected = new Set();

function runRow(run) {
  const progress = run.total_steps ? Math.min(1, run.step / run.total_steps) : 0;
  const active = isActive(run);
  const status = el("td", { class: "status-cell", "data-label": "Status" }, statusPill(run));
  if (run.status === "queued" && run.waiting_reason) {
    status.append(el("div", { class: "small muted waiting-reason" }, run.waiting_reason));
  } else if (run.status === "failed" && run.status_reason) {
    status.append(el("div", { class: "reason" }, run.status_reason));
  }
  if (active && run.phase) status.append(el("div", { class: "small muted run-phase" }, run.phase));
  const eta = run.eta_seconds !== null && active ? ` · ETA ${fmtDuration(run.eta_seconds)}` : "";
  const bar = el("div");
  bar.style.width = `${(progress * 100).toFixed(1)}%`;
  const steps = `${fmtSteps(run.step)} / ${fmtSteps(run.total_steps)}`;
  const progressCell = el(
    "td",
    { class: "progress-cell", "data-label": "Progress" },
    el("div", { class: "small" }, steps, el("span", { class: "muted" }, eta)),
    el("div", { class: "progress" }, bar)
  );
  progressCell.style.minWidth = "170px";
  const queries = el("td", { class: "num", "data-label": "Queries" }, `${run.queries.answered}/${run.queries.asked}`);
  if (run.queries.pending) {
    queries.append(" · ", el("a", { href: `/queue?run=${run.id}` }, el("b", {}, `${run.queries.pending} waiting`)));
  }
  const name = el("td", { class: "name-cell" }, el("a", { href: `/runs/${run.id}` }, el("b", {}, `#${run.id}`)), " " + run.name);
  if (run.priority) name.append(" ", el("span", { class: "small muted", title: "priority" }, `p${run.priority}`));
  const check = el("input", {
    type: "checkbox", class: "compare-check", value: run.id, "aria-label": `compare run ${run.id}`,
  });
  check.defaultChecked = selected.has(run.id);
  return el(
    "tr",
    { "data-run-id": run.id },
    el("td", { class: "check" }, check),
    name,
    el("td", { class: "wide-only" }, run.env_id),
    el("td", { class: "wide-only" }, el("code", {}, run.algorithm)),
    status,
    progressCell,
    el("td", { class: "num", "data-label": "Success" }, fmtPercent(run.success_rate)),
    queries,
    // only a run a learner holds beats: a stopped or finished run's last beat only grows older
    el("td", { class: "num heartbeat-cell", "data-label": "Heartbeat" },
      active && run.heartbeat_at ? fmtAge(run.heartbeat_age_seconds) : "–")
  );
}

function renderRuns(runs) {
  const body = document.getElementById("runs-body");
  if (!runs.length) {
    const empty = el(
      "td",
      { colspan: 9, class: "empty" },
      "No runs yet. Create a ",
      el("a", { href: "/goal-sets" }, "goal set"),
      " with a few photos of success, then ",
      el("a", { href: "/runs/new" }, "start a run"),
      "."
    );
    body.replaceChildren(el("tr", {}, empty));
    return;
  }
  body.replaceChildren(...runs.map(runRow));
  setPendingBadge(runs.filter(isLive).reduce((total, run) => total + run.queries.pending, 0));
}

function updateCompareButton() {
  document.getElementById("compare-selected").disabled = selected.size < 1;
}

document.addEventListener("DOMContentLoaded", () => {
  document.getElementById("runs-body").addEventListener("change", (event) => {
    if (!event.target.classList.contains("compare-check")) return;
    const id = Number(event.target.value);
    if (event.target.checked) selected.add(id);
    else selected.delete(id);
    updateCompareButton();
  });
  document.getElementById("compare-selected").addEventListener("click", () => {
    window.location.href = "/compare?runs=" + [...selected].sort((a, b) => a - b).join(",");
  });
  renderRuns(JSON.parse(document.getElementById("runs-data").textContent));
  setTimeout(() => poll(async () => renderRuns(await api("GET", `/api/runs?archived=${document.getElementById("runs-body").dataset.archived}`)), 3000), 3000);
});

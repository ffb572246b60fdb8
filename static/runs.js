// Runs page: the table, refreshed every 3 s from /api/runs.
"use strict";

function runRow(run) {
  const progress = run.total_steps ? Math.min(1, run.step / run.total_steps) : 0;
  let reason = run.status === "failed" && run.status_reason
    ? `<div class="reason">${escapeHtml(run.status_reason)}</div>` : "";
  if (run.status === "queued" && run.waiting_reason) {
    reason = `<div class="small muted waiting-reason">${escapeHtml(run.waiting_reason)}</div>`;
  }
  const priority = run.priority ? ` <span class="small muted" title="priority">p${run.priority}</span>` : "";
  const pending = run.queries.pending
    ? ` · <a href="/queue?run=${run.id}"><b>${run.queries.pending} waiting</b></a>` : "";
  const active = run.status === "training" || run.status === "starting";
  const eta = run.eta_seconds !== null && active ? ` · ETA ${fmtDuration(run.eta_seconds)}` : "";
  if (active && run.phase) reason += `<div class="small muted run-phase">${escapeHtml(run.phase)}</div>`;
  const checked = selected.has(run.id) ? " checked" : "";
  return `<tr data-run-id="${run.id}">
    <td class="check"><input type="checkbox" class="compare-check" value="${run.id}" aria-label="compare run ${run.id}"${checked}></td>
    <td><a href="/runs/${run.id}"><b>#${run.id}</b></a> ${escapeHtml(run.name)}${priority}</td>
    <td class="wide-only">${escapeHtml(run.env_id)}</td>
    <td class="wide-only"><code>${escapeHtml(run.algorithm)}</code></td>
    <td>${statusPill(run)}${reason}</td>
    <td class="progress-cell" style="min-width:170px">
      <div class="small">${fmtSteps(run.step)} / ${fmtSteps(run.total_steps)}<span class="muted">${eta}</span></div>
      <div class="progress"><div style="width:${(progress * 100).toFixed(1)}%"></div></div>
    </td>
    <td class="num">${fmtPercent(run.success_rate)}</td>
    <td class="num">${run.queries.answered}/${run.queries.asked}${pending}</td>
    <td class="num wide-only">${run.heartbeat_at ? fmtAge(run.heartbeat_age_seconds) : "–"}</td>
  </tr>`;
}

const selected = new Set();

function renderRuns(runs) {
  const body = document.getElementById("runs-body");
  if (!runs.length) {
    body.innerHTML = `<tr><td colspan="9" class="empty">No runs yet. Create a <a href="/goal-sets">goal set</a>
      with a few photos of success, then <a href="/runs/new">start a run</a>.</td></tr>`;
    return;
  }
  body.innerHTML = runs.map(runRow).join("");
  setPendingBadge(runs.reduce((total, run) => total + run.queries.pending, 0));
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

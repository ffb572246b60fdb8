// Run page: status and stats (every 2 s), curves from /api/runs/{id}/metrics?since_step=, rollout, queries, events;
// for an active run whose actor drives a robot, the robot's card (camera, Stop robot / Resume, Ready: keys X, R;
// Evaluate now) and its take-over by hand (takeover.js).
import {
  api, el, fmtAge, fmtDuration, fmtNumber, fmtPercent, fmtSteps, fmtTime, isActive, poll, statusPill, toast,
} from "/static/app.js";
import { COLORS, LineChart } from "/static/charts.js";
import { RobotCards } from "/static/queue.js";
import { TakeOver } from "/static/takeover.js";

const ROBOT_SHOWN_SECONDS = 30; // an actor that reported within this long has its card (as GET /api/robots lists)

const CHARTS = [
  { id: "chart-success", title: "Evaluation success rate", percent: true, yMin: 0, yMax: 1,
    series: [["eval/success_rate", "success"]] },
  { id: "chart-return", title: "Return",
    series: [["eval/return", "evaluation"], ["train/episode_return", "training episodes"]] },
  { id: "chart-classifier-return", title: "Classifier return Σ fψ(s′) per evaluation episode",
    series: [["eval/classifier_return", "evaluation"]] },
  { id: "chart-reward-loss", title: "Reward classifier loss", series: [["reward/loss", "loss"]] },
  { id: "chart-reward-acc", title: "Reward classifier accuracy", percent: true, yMin: 0, yMax: 1,
    series: [["reward/acc_goal", "on goal photos"], ["reward/acc_replay", "on replay frames"],
             ["reward/agreement_with_answers", "agrees with answers"]] },
  { id: "chart-logits", title: "Mean classifier score fψ",
    series: [["reward/mean_logit_goal", "goal photos"], ["reward/mean_logit_recent", "recent frames"],
             ["reward/mean_logit_answered_yes", "answered yes"], ["reward/mean_logit_answered_no", "answered no"]] },
  { id: "chart-queries", title: "Queries", yMin: 0,
    series: [["queries/asked", "asked"], ["queries/answered", "answered"], ["queries/yes", "yes"]] },
  { id: "chart-sac", title: "SAC losses", series: [["critic/loss", "critic"], ["actor/loss", "actor"]] },
  { id: "chart-alpha", title: "Entropy temperature α", series: [["alpha/value", "α"]] },
];

const page = { run: null, charts: [], lastStep: -1, rolloutId: null, lastEventId: 0, robotShown: false };

function renderRun(run) {
  page.run = run;
  document.getElementById("run-status").replaceChildren(statusPill(run));
  const reason = document.getElementById("run-reason");
  if (run.status === "failed" && run.status_reason) {
    reason.className = "reason";
    reason.textContent = "Failed: " + run.status_reason;
  } else if (run.status === "queued") {
    reason.className = "muted small";
    reason.textContent = "Queued: " + (run.waiting_reason || "waiting for a learner (start one with `raq learn`).");
  } else if (run.status === "starting") {
    reason.className = "muted small";
    reason.textContent = "A learner took the run and is setting up (environment, networks, checkpoint).";
  } else {
    reason.textContent = "";
  }
  document.getElementById("stat-step").textContent = `${fmtSteps(run.step)} / ${fmtSteps(run.total_steps)}`;
  const progress = document.getElementById("stat-progress");
  if (run.total_steps) {
    const bar = el("div");
    bar.style.width = `${Math.min(100, (100 * run.step) / run.total_steps).toFixed(1)}%`;
    const track = el("div", { class: "progress" }, bar);
    track.style.marginTop = "0.35rem";
    progress.replaceChildren(track);
  } else {
    progress.replaceChildren();
  }
  document.getElementById("stat-success").textContent = fmtPercent(run.success_rate);
  const active = isActive(run);
  // only a run a learner holds beats: a stopped or finished run's last beat only grows older
  document.getElementById("stat-heartbeat").textContent =
    active && run.heartbeat_at ? fmtAge(run.heartbeat_age_seconds) : "–";
  document.getElementById("stat-worker").textContent = run.worker ? run.worker : "no learner yet";
  document.getElementById("stat-speed").textContent = active ? fmtNumber(run.steps_per_second, 1) : "–";
  const warmUp = active && run.phase === "warm-up";
  document.getElementById("stat-eta").textContent = run.status === "finished" ? "done"
    : active && run.eta_seconds !== null ? fmtDuration(run.eta_seconds) : "–";
  document.getElementById("stat-eta-sub").textContent = warmUp ? "known once training starts (after the warm-up)"
    : "to total steps, at the training speed";
  const phase = document.getElementById("run-phase");
  const phases = [];
  if (active && run.phase) phases.push(run.phase);
  if (run.queries.pending) phases.push(`waiting for answers (${run.queries.pending})`);
  phase.textContent = phases.join(" · ");
  const nextQuery = document.getElementById("stat-next-query");
  nextQuery.textContent = run.next_query_step === null ? ""
    : `next question at step ${run.next_query_step.toLocaleString()}`
      + (run.next_query_seconds !== null ? ` (about ${fmtDuration(run.next_query_seconds)})` : "");
  const q = run.queries;
  // the Queries chart ends at the counts the card shows (the learner records them only every log_every steps)
  const queriesChart = page.charts.find((chart) => chart.element.id === "chart-queries");
  if (queriesChart && run.step > 0) {
    queriesChart.add({ "queries/asked": [[run.step, q.asked]], "queries/answered": [[run.step, q.answered]],
                       "queries/yes": [[run.step, q.yes]] });
  }
  document.getElementById("stat-queries").textContent = `${q.answered} / ${q.asked}`;
  document.getElementById("stat-queries-sub").replaceChildren(
    `answered · ${q.yes} yes`,
    ...(q.pending ? [" · ", el("a", { href: `/queue?run=${run.id}` }, el("b", {}, `${q.pending} waiting`))] : [])
  );
  const canStop = run.status === "queued" || (active && !run.stop_requested);
  const canResume = run.status === "stopped" || run.status === "failed";
  document.getElementById("stop-run").classList.toggle("hidden", !canStop);
  document.getElementById("resume-run").classList.toggle("hidden", !canResume);
  const finished = run.status === "finished";
  const continueForm = document.getElementById("continue-form");
  if (finished && continueForm.classList.contains("hidden")) {
    document.getElementById("continue-steps").value = String(run.total_steps * 2); // a suggestion: twice as long
    document.getElementById("continue-steps").min = String(run.total_steps + 1);
  }
  continueForm.classList.toggle("hidden", !finished);
  const archive = document.getElementById("archive-run");
  archive.textContent = run.archived ? "Unarchive" : "Archive";
  archive.classList.toggle("hidden", !run.archived && (run.status === "queued" || active));
  document.getElementById("delete-run").classList.toggle("hidden", active);

  const rollout = run.latest_rollout;
  if (rollout && rollout.id !== page.rolloutId) {
    page.rolloutId = rollout.id;
    const image = document.getElementById("rollout");
    image.src = rollout.url;
    image.classList.remove("hidden");
  }
  if (rollout) {
    const parts = [`step ${fmtSteps(rollout.env_step)}`, `${rollout.frame_count} frames`];
    if (rollout.success !== null) parts.push(`success ${fmtPercent(rollout.success)}`);
    if (rollout.episode_return !== null) parts.push(`return ${fmtNumber(rollout.episode_return, 1)}`);
    document.getElementById("rollout-caption").textContent = parts.join(" · ");
  }
  renderEffort(run.effort);
  renderPace(run.learner_pace);
}

/** A real-time run's learner that cannot keep up with its robot (the run's `learner_pace`): why, in the run's own
 * figures, and the preset that fits; hidden while it keeps up. */
function renderPace(pace) {
  const box = document.getElementById("learner-pace");
  box.classList.toggle("hidden", !(pace && pace.behind));
  if (!pace || !pace.behind) return;
  document.getElementById("pace-message").textContent = pace.message;
  document.getElementById("pace-suggestion").textContent = pace.suggestion;
}

/** What the run has cost the person so far (the run's `effort`): answers and the time spent answering, resets and
 * the robot's wait for them, the time they drove the robot by hand, the person's minutes in all. */
function renderEffort(effort) {
  if (!effort) return;
  const minutes = (seconds) => `${(seconds / 60).toFixed(1)} min`;
  const parts = [
    `${effort.answers} answer${effort.answers === 1 ? "" : "s"} (${minutes(effort.answer_seconds)} answering)`,
    `${effort.resets} reset${effort.resets === 1 ? "" : "s"} (the robot waited ${minutes(effort.reset_wait_seconds)})`,
    ...(effort.takeovers ? [`${effort.takeovers} take-over${effort.takeovers === 1 ? "" : "s"} ` +
      `(${minutes(effort.takeover_seconds)} driving by hand)`] : []),
    `${effort.person_minutes.toFixed(1)} person-minutes in all`,
  ];
  const text = document.getElementById("effort-text");
  text.textContent = parts.join(" · ");
  text.classList.toggle("muted", effort.answers === 0 && effort.resets === 0 && !effort.takeovers);
}

/** The run's robot, as a list of none or one for RobotCards: while the run is active and its actor reported lately. */
async function loadRobot() {
  if (!isActive(page.run)) return [];
  const robot = await api("GET", `/api/runs/${page.run.id}/robot`);
  const recent = robot.actor_age_seconds !== null && robot.actor_age_seconds <= ROBOT_SHOWN_SECONDS;
  return recent ? [robot] : [];
}

async function refreshRun() {
  renderRun(await api("GET", `/api/runs/${page.run.id}`));
}

/** The verdict on the reward's health (GET /api/runs/{id}/reward-health), shown once there is something to say. */
async function refreshVerdict() {
  const verdict = await api("GET", `/api/runs/${page.run.id}/reward-health`);
  const panel = document.getElementById("reward-verdict");
  document.getElementById("verdict-level").textContent = verdict.level;
  document.getElementById("verdict-summary").textContent = verdict.summary;
  document.getElementById("verdict-advice").textContent = verdict.advice;
  panel.dataset.level = verdict.level;
  panel.classList.toggle("hidden", verdict.level === "too early");
}

async function refreshMetrics() {
  // Ask from the last step again: metrics written later at that same step are merged, not missed.
  const since = page.lastStep >= 0 ? page.lastStep - 1 : -1;
  const data = await api("GET", `/api/runs/${page.run.id}/metrics?since_step=${since}`);
  page.lastStep = Math.max(page.lastStep, data.last_step);
  for (const chart of page.charts) chart.add(data.series);
  if (page.robotShown) { // a robot's Evaluate now round is recorded at the step it began, when its answers come
    const rates = await api("GET", `/api/runs/${page.run.id}/metrics?names=eval/success_rate`);
    for (const chart of page.charts) chart.add(rates.series);
  }
  showReturnCharts();
}

/** An env without a reward (its return all zeros) shows the classifier's return instead of a flat line. */
function showReturnCharts() {
  const [envReturn, classifierReturn] = ["chart-return", "chart-classifier-return"].map((id) =>
    page.charts.find((chart) => chart.element.id === id));
  const values = Object.values(envReturn.data).flat();
  const flatZero = values.length > 0 && values.every((point) => point[1] === 0);
  const hasClassifier = Object.values(classifierReturn.data).some((points) => points.length > 0);
  envReturn.element.classList.toggle("hidden", flatZero && hasClassifier);
  classifierReturn.element.classList.toggle("hidden", !hasClassifier);
}

async function refreshQueries() {
  const queries = await api("GET", `/api/queries?run_id=${page.run.id}&limit=60`);
  const done = queries.filter((q) => q.status !== "pending");
  document.getElementById("answered-empty").classList.toggle("hidden", done.length > 0);
  document.getElementById("answered").replaceChildren(
    ...done.map((q) => {
      const tag = q.status === "skipped" ? "skipped" : q.answer ? "yes" : "no";
      const label = tag === "skipped" ? "skip" : tag;
      const title =
        `query #${q.id} · step ${q.env_step} · fψ ${fmtNumber(q.score, 2)}` + (q.labeler ? " · " + q.labeler : "");
      return el(
        "figure",
        { "data-query-id": q.id, title },
        el("img", { class: "thumb pixelated", loading: "lazy", src: q.model_image_url, alt: `query ${q.id}` }),
        el("span", { class: `answer-tag ${tag}` }, label),
        el("figcaption", {}, `step ${fmtSteps(q.env_step)} · fψ ${fmtNumber(q.score, 1)}`)
      );
    })
  );
}

async function refreshEvents() {
  const events = await api("GET", `/api/runs/${page.run.id}/events?limit=100`);
  const items = events.map((e) =>
    el("li", { class: e.level }, el("time", {}, fmtTime(e.created_at)), el("span", {}, e.message)));
  if (!items.length) items.push(el("li", { class: "muted" }, "No events."));
  document.getElementById("events").replaceChildren(...items);
}

async function runAction(action) {
  try {
    renderRun(await api("POST", `/api/runs/${page.run.id}/${action}`));
    toast(action === "stop" ? "Stop requested." : "Queued again: a learner resumes it from its last checkpoint.");
    refreshEvents();
  } catch (error) {
    toast(error.message, "error", 6000);
  }
}

async function continueRun(event) {
  event.preventDefault();
  const total = Number(document.getElementById("continue-steps").value);
  try {
    renderRun(await api("POST", `/api/runs/${page.run.id}/continue`, { total_steps: total }));
    toast(`Queued to train on to ${total.toLocaleString()} steps from its last checkpoint.`);
    refreshEvents();
  } catch (error) {
    toast(error.message, "error", 6000);
  }
}

async function changeRun(change) {
  try {
    renderRun(await api("PATCH", `/api/runs/${page.run.id}`, change));
    toast("archived" in change ? (page.run.archived ? "Archived." : "Back among the runs.") : "Priority changed.");
    refreshEvents();
  } catch (error) {
    toast(error.message, "error", 6000);
  }
}

async function deleteRun() {
  if (!window.confirm(`Delete run #${page.run.id} with its queries, metrics, events, rollouts and checkpoint?`)) return;
  try {
    await api("DELETE", `/api/runs/${page.run.id}`);
    window.location.href = "/";
  } catch (error) {
    toast(error.message, "error", 6000);
  }
}

document.addEventListener("DOMContentLoaded", () => {
  page.run = JSON.parse(document.getElementById("run-data").textContent);
  page.charts = CHARTS.map(
    (spec) =>
      new LineChart(document.getElementById(spec.id), {
        title: spec.title,
        percent: spec.percent,
        yMin: spec.yMin,
        yMax: spec.yMax,
        series: spec.series.map(([name, label], i) => ({ name, label, color: COLORS[i % COLORS.length] })),
      })
  );
  renderRun(page.run);
  document.getElementById("stop-run").addEventListener("click", () => runAction("stop"));
  document.getElementById("resume-run").addEventListener("click", () => runAction("resume"));
  document.getElementById("continue-form").addEventListener("submit", continueRun);
  document.getElementById("archive-run").addEventListener("click", () => changeRun({ archived: !page.run.archived }));
  document.getElementById("run-priority").addEventListener("change", (event) =>
    changeRun({ priority: Number(event.target.value) }));
  document.getElementById("delete-run").addEventListener("click", deleteRun);
  const say = (kind, text) => toast(text, kind === "error" ? "error" : "info", kind === "error" ? 6000 : 3500);
  const takeOver = new TakeOver(document.getElementById("takeover-area"), { say });
  const robots = new RobotCards(document.getElementById("robot-cards"), {
    say,
    onChange: (list) => {
      page.robotShown = list.length > 0;
      document.getElementById("robots").classList.toggle("hidden", list.length === 0);
      takeOver.show(list.length ? list[0] : null);
    },
    evaluate: true,
  });
  robots.start(loadRobot);
  document.addEventListener("keydown", (event) => {
    if (robots.key(event) && event.key.toLowerCase() === "x") takeOver.show({ ...takeOver.robot, stop_requested: true });
  });
  poll(refreshRun, 2000);
  poll(refreshMetrics, 2000);
  poll(refreshQueries, 4000);
  poll(refreshEvents, 4000);
  poll(refreshVerdict, 10000);
});

// Shared helpers for every page (an ES module; page scripts import what they use): JSON API calls with readable
// errors, formatting, toasts, the status pill, polling.

/** Values the server's Python defines, rendered into every page by base.html (not retyped here). */
let serverConstants = null;
function constants() {
  if (serverConstants === null) {
    const element = document.getElementById("page-constants");
    serverConstants = element ? JSON.parse(element.textContent) : {};
  }
  return serverConstants;
}

/** Whether a run is being worked on by a learner (app.store.RunStatus.ACTIVE). */
export function isActive(run) {
  return (constants().active_statuses || []).includes(run.status);
}

/** Queued, starting or training: a run that will still use its answers (the badge counts only its questions). */
export function isLive(run) {
  return (constants().live_statuses || []).includes(run.status);
}

/** An element: el("a", {href: "/"}, "text", child); "class" sets the class name; null attributes are left out. */
export function el(tag, attributes = {}, ...children) {
  const element = document.createElement(tag);
  for (const [name, value] of Object.entries(attributes)) {
    if (value === null || value === undefined || value === false) continue;
    if (name === "class") element.className = value;
    else element.setAttribute(name, value === true ? "" : String(value));
  }
  element.append(...children.filter((child) => child !== null && child !== undefined && child !== ""));
  return element;
}

export class ApiError extends Error {
  constructor(status, message) {
    super(message);
    this.status = status;
  }
}

export function describeDetail(detail) {
  if (detail == null) return "";
  if (typeof detail === "string") return detail;
  if (Array.isArray(detail)) {
    return detail.map((item) => (item && item.msg ? item.msg : JSON.stringify(item))).join("; ");
  }
  return JSON.stringify(detail);
}

export async function api(method, url, body) {
  const options = { method, credentials: "same-origin", headers: { Accept: "application/json" } };
  if (body instanceof FormData) {
    options.body = body;
  } else if (body !== undefined) {
    options.headers["Content-Type"] = "application/json";
    options.body = JSON.stringify(body);
  }
  let response;
  try {
    response = await fetch(url, options);
  } catch (error) {
    throw new ApiError(0, "cannot reach the server (" + error.message + ")");
  }
  if (response.status === 204) return null;
  let data = null;
  const text = await response.text();
  try {
    data = text ? JSON.parse(text) : null;
  } catch (_error) {
    data = { detail: text };
  }
  if (!response.ok) {
    let message = describeDetail(data && data.detail) || response.statusText || "request failed";
    if (response.status === 401) message += " — log in first";
    const error = new ApiError(response.status, message);
    error.detail = data && data.detail;
    throw error;
  }
  return data;
}

/** A number for people: negatives with a real minus sign (U+2212), which no line breaks after ("-" did: the
 * legend read "evaluation -" over "389.246"). */
export function fmtNumber(value, digits = 2) {
  if (value === null || value === undefined || Number.isNaN(value)) return "–";
  const abs = Math.abs(value);
  const text = abs !== 0 && (abs >= 1e5 || abs < 1e-3)
    ? abs.toExponential(1)
    : Number(abs.toFixed(digits)).toLocaleString(undefined, { maximumFractionDigits: digits });
  return (value < 0 && text !== "0" ? "\u2212" : "") + text;
}

export function fmtSteps(value) {
  if (value === null || value === undefined) return "–";
  if (value >= 1e6) return Number((value / 1e6).toFixed(value >= 1e7 ? 0 : 1)) + "M";
  if (value >= 1e3) return Number((value / 1e3).toFixed(value >= 1e4 ? 0 : 1)) + "k";
  return String(value);
}

export function fmtDuration(seconds) {
  if (seconds === null || seconds === undefined || !Number.isFinite(seconds)) return "–";
  seconds = Math.max(0, Math.round(seconds));
  if (seconds < 60) return seconds + " s";
  if (seconds < 3600) return Math.floor(seconds / 60) + " min " + (seconds % 60) + " s";
  const hours = Math.floor(seconds / 3600);
  if (hours < 48) return hours + " h " + Math.floor((seconds % 3600) / 60) + " min";
  return Math.floor(hours / 24) + " d " + (hours % 24) + " h";
}

export function fmtAge(seconds) {
  if (seconds === null || seconds === undefined) return "never";
  return fmtDuration(seconds) + " ago";
}

export function fmtPercent(value) {
  if (value === null || value === undefined) return "–";
  return Math.round(value * 100) + "%";
}

export function fmtTime(iso) {
  if (!iso) return "";
  const date = new Date(iso);
  return date.toLocaleTimeString([], { hour: "2-digit", minute: "2-digit", second: "2-digit" });
}

let toastTimer = null;
export function toast(message, kind = "info", ms = 3500) {
  let element = document.getElementById("toast");
  if (!element) {
    element = document.createElement("div");
    element.id = "toast";
    element.setAttribute("role", "status");
    document.body.appendChild(element);
  }
  element.className = "toast " + kind;
  element.textContent = message;
  element.classList.remove("hidden");
  clearTimeout(toastTimer);
  toastTimer = setTimeout(() => element.classList.add("hidden"), ms);
}

/** The run's status as a pill: <span class="status STATUS [stale]" title="REASON">LABEL</span>. */
export function statusPill(run) {
  let cls = run.status;
  let label = run.status;
  const active = isActive(run);
  const staleAfter = Number(document.body.dataset.staleAfter || 60);
  if (active && run.heartbeat_age_seconds !== null && run.heartbeat_age_seconds > staleAfter) {
    cls += " stale";
    label += " (no heartbeat)";
  }
  if (run.stop_requested && active) label += " · stopping";
  return el("span", { class: "status " + cls, title: run.status_reason || "" }, label);
}

export function setPendingBadge(count) {
  notifyQuestions(count);
  const badge = document.getElementById("nav-pending");
  if (!badge) return;
  badge.textContent = String(count);
  badge.classList.toggle("zero", count === 0);
}

// Browser notifications, when the user allowed them: one each time the number of waiting questions grows.
const notifier = { last: null };

function notificationsAllowed() {
  return "Notification" in window && Notification.permission === "granted";
}

function notifyQuestions(count) {
  const previous = notifier.last;
  notifier.last = count;
  if (previous === null || count <= previous || !notificationsAllowed()) return;
  const note = new Notification("vice-raq: a question is waiting", {
    body: `${count} question${count === 1 ? "" : "s"} waiting for your answer`, tag: "vice-raq-queue",
  });
  note.onclick = () => {
    window.focus();
    if (window.location.pathname !== "/queue") window.location.href = "/queue";
  };
}

/** The "Notify me" button: ask for permission, then say whether notifications are on. */
export function setUpNotifyButton(button) {
  if (!button) return;
  const show = () => {
    if (!("Notification" in window)) {
      button.textContent = "Notifications not supported";
      button.disabled = true;
    } else if (Notification.permission === "granted") {
      button.textContent = "Notifications on";
      button.disabled = true;
    } else if (Notification.permission === "denied") {
      button.textContent = "Notifications blocked";
      button.disabled = true;
    }
  };
  show();
  button.addEventListener("click", async () => {
    await Notification.requestPermission();
    show();
  });
}

/** Call `fn` now and then every `ms` while the tab is visible; returns a function that stops it. */
export function poll(fn, ms) {
  let stopped = false;
  let timer = null;
  let ticks = 0;
  async function tick() {
    if (stopped) return;
    ticks += 1;
    // a hidden tab keeps polling, more slowly, only when it may notify the user of a new question
    if (!document.hidden || (notificationsAllowed() && ticks % 5 === 0)) {
      try {
        await fn();
      } catch (error) {
        console.warn(error);
      }
    }
    timer = setTimeout(tick, ms);
  }
  tick();
  return () => {
    stopped = true;
    clearTimeout(timer);
  };
}

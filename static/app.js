// Shared helpers for every page: JSON API calls with readable errors, formatting, toasts.
"use strict";

class ApiError extends Error {
  constructor(status, message) {
    super(message);
    this.status = status;
  }
}

function describeDetail(detail) {
  if (detail == null) return "";
  if (typeof detail === "string") return detail;
  if (Array.isArray(detail)) {
    return detail.map((item) => (item && item.msg ? item.msg : JSON.stringify(item))).join("; ");
  }
  return JSON.stringify(detail);
}

async function api(method, url, body) {
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

function fmtNumber(value, digits = 2) {
  if (value === null || value === undefined || Number.isNaN(value)) return "–";
  const abs = Math.abs(value);
  if (abs !== 0 && (abs >= 1e5 || abs < 1e-3)) return value.toExponential(1);
  return Number(value.toFixed(digits)).toLocaleString();
}

function fmtSteps(value) {
  if (value === null || value === undefined) return "–";
  if (value >= 1e6) return Number((value / 1e6).toFixed(value >= 1e7 ? 0 : 1)) + "M";
  if (value >= 1e3) return Number((value / 1e3).toFixed(value >= 1e4 ? 0 : 1)) + "k";
  return String(value);
}

function fmtDuration(seconds) {
  if (seconds === null || seconds === undefined || !Number.isFinite(seconds)) return "–";
  seconds = Math.max(0, Math.round(seconds));
  if (seconds < 60) return seconds + " s";
  if (seconds < 3600) return Math.floor(seconds / 60) + " min " + (seconds % 60) + " s";
  const hours = Math.floor(seconds / 3600);
  if (hours < 48) return hours + " h " + Math.floor((seconds % 3600) / 60) + " min";
  return Math.floor(hours / 24) + " d " + (hours % 24) + " h";
}

function fmtAge(seconds) {
  if (seconds === null || seconds === undefined) return "never";
  return fmtDuration(seconds) + " ago";
}

function fmtPercent(value) {
  if (value === null || value === undefined) return "–";
  return Math.round(value * 100) + "%";
}

function fmtTime(iso) {
  if (!iso) return "";
  const date = new Date(iso);
  return date.toLocaleTimeString([], { hour: "2-digit", minute: "2-digit", second: "2-digit" });
}

function escapeHtml(text) {
  return String(text ?? "").replace(/[&<>"']/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;", "'": "&#39;" })[c]);
}

let toastTimer = null;
function toast(message, kind = "info", ms = 3500) {
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

function statusPill(run) {
  let cls = run.status;
  let label = run.status;
  const active = run.status === "starting" || run.status === "training";
  const staleAfter = Number(document.body.dataset.staleAfter || 60);
  if (active && run.heartbeat_age_seconds !== null && run.heartbeat_age_seconds > staleAfter) {
    cls += " stale";
    label += " (no heartbeat)";
  }
  if (run.stop_requested && active) label += " · stopping";
  return `<span class="status ${cls}" title="${escapeHtml(run.status_reason || "")}">${escapeHtml(label)}</span>`;
}

function setPendingBadge(count) {
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
function setUpNotifyButton(button) {
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
function poll(fn, ms) {
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

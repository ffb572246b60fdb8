// New run page: POST /api/runs, show 422 errors beside the fields they name.
"use strict";

const CONFIG_FIELDS = ["total_steps", "query_every", "query_budget"];

function clearErrors(form) {
  form.querySelectorAll(".field.invalid").forEach((field) => field.classList.remove("invalid"));
  form.querySelectorAll(".field .error").forEach((element) => element.remove());
  document.getElementById("form-errors").classList.add("hidden");
}

function showErrors(form, detail, fallback) {
  const box = document.getElementById("form-errors");
  const items = Array.isArray(detail) ? detail : [{ loc: [], msg: describeDetail(detail) || fallback }];
  const unplaced = [];
  for (const item of items) {
    const loc = item.loc || [];
    const name = String(loc[loc.length - 1] ?? "");
    let field = form.querySelector(`.field[data-field="${CSS.escape(name)}"]`);
    if (!field && loc.includes("config")) field = form.querySelector('.field[data-field="config"]');
    if (field) {
      field.classList.add("invalid");
      const message = document.createElement("div");
      message.className = "error";
      message.textContent = item.msg;
      field.appendChild(message);
      if (field.closest("details")) field.closest("details").open = true;
    }
    unplaced.push(item.msg);
  }
  box.innerHTML = "<b>The run was not started:</b><ul>" + unplaced.map((m) => `<li>${escapeHtml(m)}</li>`).join("") + "</ul>";
  box.classList.remove("hidden");
}

document.addEventListener("DOMContentLoaded", () => {
  const form = document.getElementById("new-run-form");
  form.addEventListener("submit", async (event) => {
    event.preventDefault();
    clearErrors(form);
    let config = {};
    const extra = document.getElementById("extra_config").value.trim();
    if (extra) {
      try {
        config = JSON.parse(extra);
        if (typeof config !== "object" || Array.isArray(config) || config === null) throw new Error("not an object");
      } catch (error) {
        showErrors(form, [{ loc: ["body", "config"], msg: "More settings must be a JSON object: " + error.message }]);
        return;
      }
    }
    for (const name of CONFIG_FIELDS) {
      const raw = form.elements[name].value.trim();
      config[name] = raw === "" ? null : Number(raw);
    }
    const goalSet = form.elements.goal_set_id.value;
    const seed = form.elements.seed.value.trim();
    const body = {
      name: form.elements.name.value,
      env_id: form.elements.env_id.value,
      algorithm: form.elements.algorithm.value,
      seed: seed === "" ? 0 : Number(seed),
      goal_set_id: goalSet ? Number(goalSet) : null,
      config,
    };
    const button = document.getElementById("start-run");
    button.disabled = true;
    try {
      const run = await api("POST", "/api/runs", body);
      window.location.href = `/runs/${run.id}`;
    } catch (error) {
      showErrors(form, error.detail, error.message);
      button.disabled = false;
    }
  });
});

// New run page: POST /api/runs, show 422 errors beside the fields they name; fill in the settings a simulated
// task starts from when it is picked, and for a robot env the robot settings the server gives for the learner's
// device (GET /api/envs/robot-settings: TrainConfig.cpu_robot() on a CPU, the paper's real_robot() on a GPU).
import { api, describeDetail } from "/static/app.js";

const CONFIG_FIELDS = ["total_steps", "query_every", "query_budget"];
const edited = new Set(); // inputs changed by hand: a task's settings never overwrite them
let robotSettings = null; // the server's answer for the env and device asked last (preset null: not a robot env)
let robotFor = null;

/** The settings the chosen env starts from: a simulated task's (served by the page, sim.PRESETS), or a robot
 * env's robot preset for the chosen device; null for any other env. */
function startingSettings(form, taskSettings) {
  const envId = form.elements.env_id.value.trim();
  const task = taskSettings[envId];
  if (task) {
    return { fields: task.fields, said: `the settings ${envId} starts from`, more: ` (how it learns with them: ${task.results_page})` };
  }
  const robot = robotSettings;
  if (!robot || !robot.preset || robot.env_id !== envId || robot.device !== form.elements.device.value) return null;
  let more = ` (TrainConfig.${robot.preset}(), ${robot.description})`;
  const goalSet = chosenGoalSet(form);
  const size = robot.fields.image_size;
  if (goalSet && size !== undefined && Number(goalSet.dataset.imageSize) !== size) {
    more += `. The goal set prepares its photos at ${goalSet.dataset.imageSize} px: pick one of ${size} px`;
  }
  return { fields: robot.fields, said: `the robot settings for a ${robot.device} learner of ${envId} at ${robot.control_hz} Hz`, more };
}

/** The chosen env's settings into the form: its fields with an input of their own there, the rest as the More
 * settings JSON unless that was edited by hand. */
function fillTaskSettings(form, taskSettings) {
  const settings = startingSettings(form, taskSettings);
  const note = document.getElementById("task-settings-note");
  const extraInput = document.getElementById("extra_config");
  if (!settings) {
    // another env: the config's defaults again (the page's values), except what was set by hand
    for (const name of CONFIG_FIELDS) {
      if (!edited.has(name)) form.elements[name].value = form.elements[name].defaultValue;
    }
    if (!edited.has("extra_config")) extraInput.value = "";
    note.classList.add("hidden");
    return;
  }
  const filled = [];
  const kept = [];
  const extra = {};
  for (const [name, value] of Object.entries(settings.fields)) {
    const input = CONFIG_FIELDS.includes(name) ? form.elements[name] : extraInput;
    if (edited.has(input.id)) {
      kept.push(name);
      continue;
    }
    if (input.id === "extra_config") extra[name] = value;
    else input.value = String(value);
    filled.push(`${name} ${value}`);
  }
  if (!edited.has("extra_config")) extraInput.value = Object.keys(extra).length ? JSON.stringify(extra) : "";
  note.textContent =
    `Filled in ${settings.said}: ${filled.join(", ")}${settings.more}.` +
    (kept.length ? ` Kept what you set for ${kept.join(", ")}.` : "");
  note.classList.remove("hidden");
}

/** Ask the server for the robot settings of the env and device chosen, then fill them in (a simulated task or
 * another env gets none). */
async function lookUpRobotSettings(form, taskSettings) {
  const envId = form.elements.env_id.value.trim();
  const device = form.elements.device.value;
  const key = `${envId}@${device}`;
  if (envId !== previewed || taskSettings[envId] || key === robotFor) return;
  robotFor = key;
  let found = null;
  try {
    found = await api("GET", "/api/envs/robot-settings?" + new URLSearchParams({ env_id: envId, device }));
  } catch {
    found = null; // the env's class could not be read: no robot settings
  }
  if (robotFor !== key) return;
  robotSettings = found;
  if (found && found.preset) fillTaskSettings(form, taskSettings);
}

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
  const title = document.createElement("b");
  title.textContent = "The run was not started:";
  const list = document.createElement("ul");
  for (const message of unplaced) {
    const item = document.createElement("li");
    item.textContent = message;
    list.appendChild(item);
  }
  box.replaceChildren(title, list);
  box.classList.remove("hidden");
}

/** "0,1,2" or "0-2" (or empty: []) -> seeds; null when it cannot be read. */
function parseSeeds(text) {
  const seeds = [];
  for (const part of text.split(",").map((p) => p.trim()).filter(Boolean)) {
    const range = part.match(/^(\d+)\s*-\s*(\d+)$/);
    if (range) {
      const [from, to] = [Number(range[1]), Number(range[2])];
      if (to < from || to - from > 50) return null;
      for (let seed = from; seed <= to; seed++) seeds.push(seed);
    } else if (/^\d+$/.test(part)) {
      seeds.push(Number(part));
    } else {
      return null;
    }
  }
  return seeds;
}

let previewTimer = null;
let previewFor = null;
let previewed = null; // the last env whose preview worked: only such an env is asked for robot settings

/** The chosen goal set's <option> (its data-env-id and data-image-size), or null. */
function chosenGoalSet(form) {
  const select = form.elements.goal_set_id;
  const option = select.options[select.selectedIndex];
  return option && option.value ? option : null;
}

/** The model's image size: the goal set's (a run takes it from its set), else the config's default. */
function imageSize(form) {
  const option = chosenGoalSet(form);
  return (option && option.dataset.imageSize) || form.dataset.defaultImageSize || "48";
}

/** The first frame of the env typed in the Task field (observation as the model sees it, display render); for an
 * env that previews, its robot settings are asked for next. */
async function showPreview(form, taskSettings) {
  const envId = form.elements.env_id.value.trim();
  const size = imageSize(form);
  const key = `${envId}@${size}`;
  if (!envId || key === previewFor) return;
  previewFor = key;
  previewed = null;
  const box = document.getElementById("env-preview");
  const text = document.getElementById("env-preview-text");
  const field = form.querySelector('.field[data-field="env_id"]');
  field.classList.remove("invalid");
  field.querySelectorAll(".error").forEach((element) => element.remove());
  text.textContent = "Making the env…";
  box.classList.remove("hidden");
  try {
    const preview = await api("GET", "/api/envs/preview?" + new URLSearchParams({ env_id: envId, size }));
    if (previewFor !== key) return;
    document.getElementById("env-preview-observation").src = preview.observation_url;
    document.getElementById("env-preview-display").src = preview.display_url;
    box.querySelectorAll("figure").forEach((figure) => figure.classList.remove("hidden"));
    text.textContent = preview.description;
    previewed = envId;
    lookUpRobotSettings(form, taskSettings);
  } catch (error) {
    if (previewFor !== key) return;
    box.querySelectorAll("figure").forEach((figure) => figure.classList.add("hidden"));
    text.textContent = "";
    field.classList.add("invalid");
    const message = document.createElement("div");
    message.className = "error";
    message.textContent = error.message;
    field.appendChild(message);
  }
}

document.addEventListener("DOMContentLoaded", () => {
  const form = document.getElementById("new-run-form");
  const envInput = form.elements.env_id;
  const taskSettings = JSON.parse(document.getElementById("task-settings").textContent);
  for (const id of [...CONFIG_FIELDS, "extra_config"]) {
    document.getElementById(id).addEventListener("input", () => edited.add(id));
  }
  const schedulePreview = () => {
    clearTimeout(previewTimer);
    previewTimer = setTimeout(() => showPreview(form, taskSettings), 500);
  };
  let envTyped = false; // the task typed by hand: picking a goal set no longer changes it
  envInput.addEventListener("input", () => {
    envTyped = true;
    fillTaskSettings(form, taskSettings);
  });
  fillTaskSettings(form, taskSettings);
  form.elements.goal_set_id.addEventListener("change", () => {
    const option = chosenGoalSet(form);
    if (option && option.dataset.envId && !envTyped && option.dataset.envId !== envInput.value.trim()) {
      envInput.value = option.dataset.envId; // a goal set shows one task: pick it too
      fillTaskSettings(form, taskSettings);
    }
    showPreview(form, taskSettings);
    fillTaskSettings(form, taskSettings); // the goal set's image size may differ from the robot settings'
  });
  form.elements.device.addEventListener("change", () => lookUpRobotSettings(form, taskSettings));
  envInput.addEventListener("input", schedulePreview);
  envInput.addEventListener("change", () => showPreview(form, taskSettings));
  showPreview(form, taskSettings);
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
    if (!("device" in config)) config.device = form.elements.device.value;
    const goalSet = form.elements.goal_set_id.value;
    const seed = form.elements.seed.value.trim();
    const body = {
      name: form.elements.name.value,
      env_id: form.elements.env_id.value.trim(),
      algorithm: form.elements.algorithm.value,
      seed: seed === "" ? 0 : Number(seed),
      goal_set_id: goalSet ? Number(goalSet) : null,
      priority: Number(form.elements.priority.value || 0),
      config,
    };
    // what was typed under More settings wins over the fields above (it used to be replaced silently)
    for (const name of ["env_id", "algorithm", "seed"]) {
      if (name in config) {
        body[name] = config[name];
        delete config[name];
      }
    }
    const button = document.getElementById("start-run");
    const sweepMethods = [...form.querySelectorAll('input[name="sweep_algorithms"]:checked')].map((box) => box.value);
    const sweepSeeds = parseSeeds(form.elements.sweep_seeds.value);
    if (sweepSeeds === null) {
      showErrors(form, [{ loc: ["body", "seeds"], msg: "seeds: write 0,1,2 or 0-2" }]);
      return;
    }
    button.disabled = true;
    const start = async (confirmed) => {
      if (sweepMethods.length || sweepSeeds.length) {
        const runs = await api("POST", "/api/runs/sweep", {
          name: body.name, env_id: body.env_id, algorithms: sweepMethods.length ? sweepMethods : [body.algorithm],
          seeds: sweepSeeds.length ? sweepSeeds : [body.seed], goal_set_id: body.goal_set_id,
          priority: body.priority, config: body.config, confirm_env_mismatch: confirmed,
        });
        window.location.href = "/compare?runs=" + runs.map((run) => run.id).join(",");
        return;
      }
      const run = await api("POST", "/api/runs", { ...body, confirm_env_mismatch: confirmed });
      window.location.href = `/runs/${run.id}`;
    };
    try {
      try {
        await start(false);
      } catch (error) {
        // the goal set was made for another task: say so, and start it only when the user confirms
        if (error.status !== 409 || !String(error.message).includes("confirm_env_mismatch")) throw error;
        const said = error.message.replace(/ \(confirm_env_mismatch: true\)/, "");
        if (!window.confirm(said + "\n\nStart it anyway?")) {
          showErrors(form, [{ loc: ["body", "goal_set_id"], msg: said }]);
          button.disabled = false;
          return;
        }
        await start(true);
      }
    } catch (error) {
      showErrors(form, error.detail, error.message);
      button.disabled = false;
    }
  });
});

// Goal set pages: create a set, upload photos (drag and drop or picker; each checked against the robot camera
// first), capture goal photos from the robot's own camera, delete photos and sets.
import { api, el, toast } from "/static/app.js";

function statusBox(kind, message) {
  const box = document.getElementById("upload-status");
  box.className = "alert " + kind;
  box.textContent = message;
}

const plural = (count, word) => `${count} ${word}${count === 1 ? "" : "s"}`;

/** POST the files as one upload; the stored examples, or null when it failed (the status box says why). */
async function sendUpload(goalSetId, files) {
  const form = new FormData();
  for (const file of files) form.append("files", file, file.name);
  statusBox("info", `Uploading ${plural(files.length, "photo")}…`);
  try {
    return await api("POST", `/api/goal-sets/${goalSetId}/examples`, form);
  } catch (error) {
    statusBox("error", "Upload failed: " + error.message);
    return null;
  }
}

/** What the status box says of stored photos: their crops, and how any differs from the set's robot camera (the
 * upload's own warnings, for a photo the check before it could not look at). */
function addedMessage(stored) {
  const cropped = stored.filter((example) => example.crop_note);
  const warned = stored.filter((example) => example.warnings && example.warnings.length);
  const notes = [
    ...cropped.map((example) => `${example.filename}: ${example.crop_note}.`),
    ...warned.map((example) => `${example.filename} differs from the robot camera's view or the set's photos: ${example.warnings.map((w) => w.message).join(" ")}`),
  ].join(" ");
  const kind = warned.length ? "warn" : cropped.length ? "info" : "ok";
  return { kind, text: `Added ${plural(stored.length, "photo")}. ${notes}`.trim() };
}

/** Upload photos: each is first compared with the robot camera's current frame (when the set's task or the Camera
 * panel names one); those that look alike are uploaded at once, the others wait for "Use anyway" or "Discard". */
async function uploadFiles(goalSetId, files) {
  if (!files.length) return;
  const envId = cameraToCompare();
  const clean = [];
  const flagged = [];
  const photosInSet = document.querySelectorAll("#examples .example").length;
  if (envId || photosInSet) {
    statusBox("info", `Comparing ${plural(files.length, "photo")} with ${envId ? "the robot camera" : "the set's photos"}…`);
    const params = new URLSearchParams(envId ? { env_id: envId } : {});
    for (const file of files) {
      const form = new FormData();
      form.append("file", file, file.name);
      try {
        const check = await api("POST", `/api/goal-sets/${goalSetId}/photo-check?${params}`, form);
        (check.warnings.length ? flagged : clean).push({ file, check });
      } catch (_error) {
        clean.push({ file, check: null }); // the check is advisory: the upload itself says what is wrong
      }
    }
  } else {
    clean.push(...files.map((file) => ({ file, check: null })));
  }
  flagged.forEach(({ file, check }) => showPhotoWarning(goalSetId, file, check));
  if (!clean.length) {
    statusBox("warn", `${plural(flagged.length, "photo")} differ${flagged.length === 1 ? "s" : ""} from ${envId ? "the robot camera's view" : "the set's photos"}: see below.`);
    return;
  }
  const stored = await sendUpload(goalSetId, clean.map(({ file }) => file));
  if (stored === null) return;
  const message = addedMessage(stored);
  if (!pendingWarnings()) {
    statusBox(message.kind, message.text);
    // keep the message readable when photos were cropped; the new photos show after the reload
    setTimeout(() => window.location.reload(), { ok: 0, info: 4000, warn: 8000 }[message.kind]);
    return;
  }
  stored.forEach(addExample);
  statusBox("warn", `${message.text} ${plural(flagged.length, "photo")} differ${flagged.length === 1 ? "s" : ""} from ${envId ? "the robot camera's view" : "the set's photos"}: see below.`);
}

function pendingWarnings() {
  return document.querySelectorAll("#photo-warnings .photo-warning").length;
}

/** A photo that differs from the camera: what differs, the photo beside the camera's frame, Use anyway / Discard. */
function showPhotoWarning(goalSetId, file, check) {
  const photoUrl = URL.createObjectURL(file);
  const camera = check.camera;
  const cameraFigure = camera
    ? el("figure", {}, el("img", { class: "camera", src: `${camera.frame_url}&t=${Date.now()}`, alt: "the robot camera's frame" }),
      el("figcaption", {}, `the camera now (${camera.width}×${camera.height}${camera.source === "camera" ? "" : `, seen through ${camera.source}'s actor`})`))
    : null;
  const use = el("button", { class: "btn primary use-anyway", type: "button" }, "Use anyway");
  const discard = el("button", { class: "btn discard", type: "button" }, "Discard");
  const card = el("div", { class: "photo-warning alert warn", "data-filename": file.name },
    el("div", {}, el("b", {}, `${file.name} does not look like ${camera ? "the robot camera's view" : "the set's other photos"}:`)),
    el("ul", {}, ...check.warnings.map((warning) => el("li", { "data-kind": warning.kind }, warning.message))),
    el("div", { class: "photo-compare" },
      el("figure", {}, el("img", { class: "photo", src: photoUrl, alt: `your photo ${file.name}` }),
        el("figcaption", {}, `your photo (${check.photo.width}×${check.photo.height})`)),
      cameraFigure),
    el("div", { class: "photo-warning-actions" }, use, discard));
  const done = (kind, text) => {
    URL.revokeObjectURL(photoUrl);
    card.remove();
    statusBox(kind, text);
  };
  use.addEventListener("click", async () => {
    use.disabled = discard.disabled = true;
    const stored = await sendUpload(goalSetId, [file]);
    if (stored === null) {
      use.disabled = discard.disabled = false;
      return;
    }
    stored.forEach(addExample);
    const message = addedMessage(stored);
    done(message.kind, message.text);
  });
  discard.addEventListener("click", () => done("info", `Discarded ${file.name}; nothing was stored.`));
  document.getElementById("photo-warnings").append(card);
}

/** A stored goal example shown as the page's template shows it, without a reload. */
function addExample(example) {
  const examples = document.getElementById("examples");
  if (!examples) return;
  const imageSize = document.getElementById("camera-panel")?.dataset.imageSize || "";
  const remove = el("button", { class: "btn small danger delete-example", "data-example-id": example.id }, "Delete");
  wireDelete(remove);
  const tag = example.source === "camera" ? el("span", { class: "source-tag" }, "camera") : null;
  examples.append(el("div", { class: "example", "data-example-id": example.id },
    el("div", { class: "pair" },
      el("figure", {},
        el("img", { class: "thumb pixelated model", src: example.model_url, alt: `model view of ${example.filename}` }),
        el("figcaption", {}, `model view (${imageSize} px)`)),
      el("figure", {},
        el("a", { href: example.original_url, target: "_blank", rel: "noopener" },
          el("img", { class: "thumb display", src: example.display_url, alt: example.filename })),
        el("figcaption", {}, `original (${example.width}×${example.height})`))),
    example.crop_note ? el("div", { class: "crop-note" }, example.crop_note) : null,
    el("div", { class: "meta" }, el("span", { class: "name", title: example.filename }, tag, tag ? " " : null, example.filename), remove)));
  document.getElementById("no-examples")?.remove();
  updateAdvice();
}

/** The photo count in the header and its advice, as the page's template words them. */
function updateAdvice() {
  const advice = document.getElementById("goal-photo-advice");
  const count = document.querySelectorAll("#examples .example").length;
  const total = document.getElementById("goal-set-photo-total");
  if (total) total.textContent = plural(count, "photo");
  if (!advice) return;
  const fewest = Number(advice.dataset.fewest || 0);
  advice.className = count < fewest ? "alert warn" : "small muted";
  const text = document.getElementById("goal-photo-count");
  if (!text) return;
  text.replaceChildren(...(count < fewest
    ? [el("b", {}, `${plural(count, "photo")}: too few.`),
      ` Give at least ${fewest}; the classifier learns what success looks like only from them.`]
    : [`${count} photos.`]));
}

function wireDelete(button) {
  button.addEventListener("click", async () => {
    try {
      await api("DELETE", `/api/goal-examples/${button.dataset.exampleId}`);
      button.closest(".example").remove();
      updateAdvice();
      toast("Photo deleted.");
    } catch (error) {
      toast(error.message, "error");
    }
  });
}

// ---------------------------------------------------------------- the Camera panel
const CAMERA_REFRESH_MS = 500;
const camera = { envIds: [], envId: "", generation: 0, timer: null, shownUrl: null, busy: false };

/** The robot camera an upload is compared with: the panel's choice, else the set's task when it has a camera. */
function cameraToCompare() {
  const panel = document.getElementById("camera-panel");
  if (camera.envId) return camera.envId;
  const setEnv = panel ? panel.dataset.envId : "";
  return camera.envIds.includes(setEnv) ? setEnv : "";
}

function cameraStatus(kind, message) {
  const box = document.getElementById("camera-status");
  box.className = kind === "error" ? "alert error" : "small muted";
  box.textContent = message;
}

function chooseCamera(envId, goalSetId) {
  camera.envId = envId;
  camera.generation += 1;
  clearTimeout(camera.timer);
  document.getElementById("camera-capture").disabled = !envId;
  document.getElementById("camera-view").classList.toggle("hidden", !envId);
  if (envId) sessionStorage.setItem(`camera-env-${goalSetId}`, envId);
  else sessionStorage.removeItem(`camera-env-${goalSetId}`);
  if (!envId) {
    cameraStatus("info", "Choose a robot to see its camera and capture goal photos from it.");
    return;
  }
  cameraStatus("info", `Opening ${envId}'s camera…`);
  refreshCamera(camera.generation);
}

/** Show the camera's newest frame, then again after CAMERA_REFRESH_MS (not while the tab is hidden). */
async function refreshCamera(generation) {
  if (generation !== camera.generation) return;
  const again = () => {
    if (generation === camera.generation) camera.timer = setTimeout(() => refreshCamera(generation), CAMERA_REFRESH_MS);
  };
  if (document.hidden) return again();
  const params = new URLSearchParams({ env_id: camera.envId, t: String(Date.now()) });
  try {
    const response = await fetch(`/api/cameras/frame?${params}`, { credentials: "same-origin", cache: "no-store" });
    if (generation !== camera.generation) return;
    if (!response.ok) {
      let detail = response.statusText;
      try {
        const body = await response.json();
        detail = typeof body.detail === "string" ? body.detail : body.detail.map((item) => item.msg).join("; ");
      } catch (_error) { /* not JSON */ }
      cameraStatus("error", `No camera view: ${detail}`);
      return again();
    }
    const source = response.headers.get("X-Camera-Source") || "robot";
    const url = URL.createObjectURL(await response.blob());
    if (generation !== camera.generation) return URL.revokeObjectURL(url);
    const image = document.getElementById("camera-live");
    const previous = camera.shownUrl;
    image.onload = () => {
      if (previous) URL.revokeObjectURL(previous);
      const seen = source.startsWith("run ") ? `live, through ${source}'s actor (it drives this robot now)` : `live, from the robot's process (${source})`;
      cameraStatus("info", `${camera.envId}: ${seen} · ${image.naturalWidth}×${image.naturalHeight} · Capture or press C to add this view`);
    };
    camera.shownUrl = url;
    image.src = url;
  } catch (error) {
    cameraStatus("error", `No camera view: ${error.message}`);
  }
  again();
}

async function capture(goalSetId) {
  if (!camera.envId || camera.busy) return;
  const button = document.getElementById("camera-capture");
  camera.busy = true;
  button.disabled = true;
  try {
    const example = await api("POST", `/api/goal-sets/${goalSetId}/capture`, { env_id: camera.envId });
    addExample(example);
    statusBox("ok", `Captured ${example.filename} from ${camera.envId}'s camera.`);
  } catch (error) {
    statusBox("error", "Capture failed: " + error.message);
  } finally {
    camera.busy = false;
    button.disabled = !camera.envId;
  }
}

/** Whether a key press belongs to a field being typed in (C there is a letter, not Capture). */
function typing(target) {
  return target instanceof HTMLElement && (target.isContentEditable || ["INPUT", "TEXTAREA", "SELECT"].includes(target.tagName));
}

async function setUpCamera(panel) {
  const goalSetId = panel.dataset.goalSetId;
  const select = document.getElementById("camera-env");
  try {
    camera.envIds = (await api("GET", "/api/cameras")).cameras.map((item) => item.env_id);
  } catch (error) {
    cameraStatus("error", "Cannot list the robot cameras: " + error.message);
    return;
  }
  if (!camera.envIds.length) {
    cameraStatus("info", "No robot camera here: a robot env (robot.base.RobotEnv) of an allowed module (RAQ_ENV_MODULES) shows up in this list.");
    return;
  }
  select.append(...camera.envIds.map((envId) => el("option", { value: envId }, envId)));
  const kept = sessionStorage.getItem(`camera-env-${goalSetId}`);
  const preselected = [kept, panel.dataset.envId].find((envId) => envId && camera.envIds.includes(envId)) || "";
  select.value = preselected;
  select.addEventListener("change", () => chooseCamera(select.value, goalSetId));
  document.getElementById("camera-capture").addEventListener("click", () => capture(goalSetId));
  document.addEventListener("keydown", (event) => {
    if (event.key !== "c" && event.key !== "C") return;
    if (event.ctrlKey || event.metaKey || event.altKey || event.repeat || typing(event.target)) return;
    if (!camera.envId) return;
    event.preventDefault();
    capture(goalSetId);
  });
  chooseCamera(preselected, goalSetId);
}

/** The goal-set page's framing panel: the run camera's first frame of the chosen task, as the model sees it. */
let framingFor = null; // the env id last asked for: an older answer arriving late is dropped

async function showFraming(input) {
  const envId = input.value.trim();
  if (envId === framingFor) return;
  framingFor = envId;
  const text = document.getElementById("framing-text");
  text.textContent = "Making the env…";
  try {
    const params = new URLSearchParams({ env_id: envId, size: input.dataset.size });
    const preview = await api("GET", "/api/envs/preview?" + params);
    if (framingFor !== envId) return;
    document.getElementById("framing-observation").src = preview.observation_url;
    document.getElementById("framing-display").src = preview.display_url;
    text.textContent = preview.description;
  } catch (error) {
    if (framingFor === envId) text.textContent = error.message;
  }
}

document.addEventListener("DOMContentLoaded", () => {
  const cameraPanel = document.getElementById("camera-panel");
  if (cameraPanel) setUpCamera(cameraPanel);

  const framing = document.getElementById("framing-env");
  if (framing) {
    // as the task is typed (after a short pause) or picked from the list, not only when the field loses focus
    let timer = null;
    framing.addEventListener("input", () => {
      clearTimeout(timer);
      timer = setTimeout(() => showFraming(framing), 400);
    });
    framing.addEventListener("change", () => {
      clearTimeout(timer);
      showFraming(framing);
    });
    showFraming(framing);
  }

  const createForm = document.getElementById("create-goal-set");
  if (createForm) {
    createForm.addEventListener("submit", async (event) => {
      event.preventDefault();
      const errorBox = document.getElementById("create-error");
      errorBox.classList.add("hidden");
      try {
        const goalSet = await api("POST", "/api/goal-sets", {
          name: createForm.elements.name.value,
          image_size: Number(createForm.elements.image_size.value || 48),
          env_id: createForm.elements.env_id.value.trim() || null,
        });
        window.location.href = `/goal-sets/${goalSet.id}`;
      } catch (error) {
        errorBox.textContent = error.message;
        errorBox.classList.remove("hidden");
      }
    });
  }

  const input = document.getElementById("goal-files");
  const dropzone = document.getElementById("dropzone");
  if (input && dropzone) {
    const goalSetId = input.dataset.goalSetId;
    input.addEventListener("change", () => {
      const files = [...input.files];
      input.value = ""; // the same file can be chosen again (after Discard, say)
      uploadFiles(goalSetId, files);
    });
    for (const name of ["dragenter", "dragover"]) {
      dropzone.addEventListener(name, (event) => {
        event.preventDefault();
        dropzone.classList.add("over");
      });
    }
    for (const name of ["dragleave", "drop"]) {
      dropzone.addEventListener(name, () => dropzone.classList.remove("over"));
    }
    dropzone.addEventListener("drop", (event) => {
      event.preventDefault();
      uploadFiles(goalSetId, [...event.dataTransfer.files]);
    });
  }

  document.querySelectorAll(".delete-example").forEach(wireDelete);

  const deleteSet = document.getElementById("delete-goal-set");
  if (deleteSet) {
    deleteSet.addEventListener("click", async () => {
      if (!window.confirm(`Delete the goal set "${deleteSet.dataset.name}" and all its photos?`)) return;
      try {
        await api("DELETE", `/api/goal-sets/${deleteSet.dataset.goalSetId}`);
        window.location.href = "/goal-sets";
      } catch (error) {
        toast(error.message, "error");
      }
    });
  }
});

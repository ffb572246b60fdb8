// Goal set pages: create a set, upload photos (drag and drop or picker), delete photos and sets.
import { api, toast } from "/static/app.js";

function statusBox(kind, message) {
  const box = document.getElementById("upload-status");
  box.className = "alert " + kind;
  box.textContent = message;
}

async function uploadFiles(goalSetId, files) {
  if (!files.length) return;
  const form = new FormData();
  for (const file of files) form.append("files", file, file.name);
  statusBox("info", `Uploading ${files.length} photo${files.length === 1 ? "" : "s"}…`);
  try {
    const stored = await api("POST", `/api/goal-sets/${goalSetId}/examples`, form);
    const cropped = stored.filter((example) => example.crop_note);
    const notes = cropped.map((example) => `${example.filename}: ${example.crop_note}.`).join(" ");
    statusBox(cropped.length ? "info" : "ok", `Added ${stored.length} photo${stored.length === 1 ? "" : "s"}. ${notes}`);
    // keep the message readable when photos were cropped; the new photos show after the reload
    setTimeout(() => window.location.reload(), cropped.length ? 4000 : 0);
  } catch (error) {
    statusBox("error", "Upload failed: " + error.message);
  }
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
    input.addEventListener("change", () => uploadFiles(goalSetId, [...input.files]));
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

  document.querySelectorAll(".delete-example").forEach((button) => {
    button.addEventListener("click", async () => {
      try {
        await api("DELETE", `/api/goal-examples/${button.dataset.exampleId}`);
        button.closest(".example").remove();
        toast("Photo deleted.");
      } catch (error) {
        toast(error.message, "error");
      }
    });
  });

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

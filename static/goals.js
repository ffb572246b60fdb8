// Goal set pages: create a set, upload photos (drag and drop or picker), delete photos and sets.
"use strict";

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
    statusBox("ok", `Added ${stored.length} photo${stored.length === 1 ? "" : "s"}.`);
    window.location.reload();
  } catch (error) {
    statusBox("error", "Upload failed: " + error.message);
  }
}

document.addEventListener("DOMContentLoaded", () => {
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

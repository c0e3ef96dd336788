// armtrack dashboard: the patient page's upload dialog. Drop vendor exports (Movella DOT,
// APDM .h5, Shimmer, MetaMotion, Sensor Logger zip) or an armtrack recording, see which
// sensor each file is (rate, duration), assign segments, check side/height, then import
// and follow the processing. Every text from a file or the server is inserted as text.
"use strict";

(function () {
  const SEGMENTS = [["", "not used"], ["trunk", "Trunk (sternum)"], ["clavicle", "Clavicle"],
    ["upper_arm", "Upper arm"], ["forearm", "Forearm"], ["hand", "Hand"]];

  function fmtSeconds(s) {
    if (s === null || s === undefined) return "";
    return s >= 120 ? `${Math.floor(s / 60)} min ${Math.round(s % 60)} s` : `${s.toFixed(1)} s`;
  }

  function send(path, form, onUpload) {
    // XMLHttpRequest, not fetch: it reports the upload's progress
    return new Promise((resolve, reject) => {
      const xhr = new XMLHttpRequest();
      xhr.open("POST", path);
      xhr.setRequestHeader("Authorization", "Bearer " + token());
      xhr.upload.onprogress = (e) => { if (e.lengthComputable && onUpload) onUpload(e.loaded / e.total); };
      xhr.onload = () => {
        let body = null;
        try { body = JSON.parse(xhr.responseText); } catch (_) { /* not JSON */ }
        if (xhr.status >= 200 && xhr.status < 300) resolve({ body, location: xhr.getResponseHeader("Location") });
        else reject(new ApiError(xhr.status, body && typeof body.detail === "string" ? body.detail : xhr.statusText));
      };
      xhr.onerror = () => reject(new ApiError(0, "the upload did not reach the server (network?)"));
      xhr.send(form);
    });
  }

  function open(patientId, onDone) {
    let chosen = [];      // File objects
    let inspection = null;
    const dialog = el("dialog", { class: "import-dialog", id: "import-dialog", "aria-labelledby": "import-title" });
    const input = el("input", { type: "file", multiple: true, id: "import-files", class: "import-input" });
    const drop = el("label", { class: "import-drop", for: "import-files", id: "import-drop" },
      el("b", {}, "Drop files here or choose them"),
      el("span", { class: "muted small" }, "Movella DOT .csv · APDM .h5 · Shimmer .csv · MetaMotion .csv · " +
        "Sensor Logger .zip · an armtrack recording"), input);
    const found = el("div", { id: "import-found" });
    const calibration = el("input", { id: "import-calibration", placeholder: "npose 0.5 3.0; tpose 5.5 8.0", maxlength: 500 });
    const calibRow = el("label", { class: "import-calibration", hidden: true },
      "Calibration poses (seconds): the still periods found are proposed; check them", calibration);
    const status = el("div", { id: "import-status", class: "import-status", role: "status" });
    const bar = el("progress", { id: "import-progress", max: 1, value: 0, hidden: true });
    const go = el("button", { id: "import-go", disabled: true }, "Import and process");
    const close = el("button", { class: "secondary", id: "import-close", onclick: () => dialog.close() }, "Close");
    dialog.append(el("div", { class: "import-head" }, el("h2", { id: "import-title" }, "Import recorded files"), close),
      drop, found, calibRow, status, bar, el("div", { class: "import-actions" }, go));
    dialog.addEventListener("close", () => dialog.remove());
    document.body.append(dialog);
    dialog.showModal();

    const take = (files) => { chosen = Array.from(files); if (chosen.length) inspect(); };
    input.addEventListener("change", () => take(input.files));
    drop.addEventListener("dragover", (e) => { e.preventDefault(); drop.classList.add("over"); });
    drop.addEventListener("dragleave", () => drop.classList.remove("over"));
    drop.addEventListener("drop", (e) => { e.preventDefault(); drop.classList.remove("over"); take(e.dataTransfer.files); });

    function say(text, kind) { clear(status, text ? el("div", { class: "import-msg " + (kind || "") }, text) : null); }

    async function inspect() {
      go.disabled = true;
      clear(found);
      say(`Looking inside ${chosen.length} file(s)…`);
      const form = new FormData();
      form.append("patient_id", patientId);
      chosen.forEach((f) => form.append("files", f, f.name));
      try {
        inspection = (await send("/api/recordings/inspect", form)).body;
      } catch (error) { say(error.message, "bad"); return; }
      show();
    }

    function rows() { return Array.from(found.querySelectorAll("tr[data-sensor-index]")); }

    function show() {
      const table = el("table", { class: "import-table" },
        el("thead", {}, el("tr", {}, el("th", {}, "File"), el("th", {}, "Sensor in it"), el("th", {}, "Format"),
          el("th", { class: "num" }, "Rate"), el("th", { class: "num" }, "Duration"), el("th", {}, "Segment"))));
      const body = el("tbody");
      const problems = [];
      let index = 0;
      for (const file of inspection.files) {
        if (file.error) { problems.push(file.error); continue; }
        for (const m of file.mismatch || []) problems.push(`${file.name}: ${m}`);
        for (const s of file.sensors) {
          const select = el("select", { "aria-label": `Segment of ${s.label}`, disabled: file.format === "armtrack" },
            SEGMENTS.map(([value, text]) => el("option", { value, selected: value === (s.suggested || "") }, text)));
          select.addEventListener("change", check);
          const row = el("tr", { dataset: { sensorIndex: String(index++) } },
            el("td", { class: "import-file" }, file.name),
            el("td", { class: "import-label" }, s.label, s.axes === 6 ? el("span", { class: "muted small" }, " (6 axes)") : null),
            el("td", { class: "import-format" }, s.format),
            el("td", { class: "num import-rate" }, `${s.rate_hz.toFixed(s.rate_hz < 10 ? 2 : 0)} Hz`),
            el("td", { class: "num import-duration" }, fmtSeconds(s.duration_s)),
            el("td", { class: "import-segment" }, select));
          row._sensor = s;
          row._file = file;
          body.append(row);
        }
      }
      table.append(body);
      const mismatch = problems.length ? el("div", { class: "import-msg warn", id: "import-warnings" },
        el("b", {}, "Before processing: "), el("ul", {}, problems.map((p) => el("li", {}, p)))) : null;
      clear(found, el("p", { class: "muted small" },
        `Patient on record: ${inspection.patient_side} arm, body height ${inspection.patient_height_m.toFixed(2)} m. ` +
        "Vendor files carry no side or height: the patient's are used."),
      el("div", { class: "import-scroll" }, table), mismatch);
      calibRow.hidden = !body.children.length || isRecording();
      if (inspection.proposal && !calibration.value) calibration.value = inspection.proposal;
      say("");
      check();
    }

    function isRecording() { return inspection.files.some((f) => f.format === "armtrack"); }

    function check() {
      const used = rows().filter((r) => r.querySelector("select").value);
      const segments = used.map((r) => r.querySelector("select").value);
      const twice = segments.find((s, i) => segments.indexOf(s) !== i);
      const blocked = inspection.files.some((f) => f.mismatch && f.mismatch.length);
      go.disabled = !used.length || Boolean(twice);
      if (twice) say(`Two sensors are assigned to ${twice.replace("_", " ")}: one sensor per segment.`, "bad");
      else if (!used.length && rows().length) say("Assign a segment to at least one sensor.");
      else if (blocked) say("The file's side or height differs from the patient's record (above): it is imported as the file says.", "warn");
      else say("");
    }

    go.addEventListener("click", async () => {
      go.disabled = true;
      const form = new FormData();
      form.append("patient_id", patientId);
      form.append("wait", "false");
      if (isRecording()) {
        form.append("file", chosen[0], chosen[0].name);
      } else {
        const map = {};
        for (const row of rows()) {
          const segment = row.querySelector("select").value;
          if (!segment) continue;
          const s = row._sensor;
          const names = s.uploads.length ? s.uploads.slice() : [row._file.name];
          if (s.label_needed) names[0] = `${names[0]}:${s.label}`;
          map[segment] = names;
        }
        const needed = new Set(Object.values(map).flat().map((n) => n.split(":")[0]));
        chosen.filter((f) => needed.has(f.name)).forEach((f) => form.append("files", f, f.name));
        form.append("sensors", JSON.stringify(map));
        if (calibration.value.trim()) form.append("calibration", calibration.value.trim());
      }
      bar.hidden = false;
      bar.value = 0;
      let answer;
      try {
        answer = await send("/api/recordings", form, (share) => {
          bar.value = share * 0.5;
          say(share < 1 ? `Uploading… ${Math.round(share * 100)} %` : "Reading and checking the files…");
        });
      } catch (error) { bar.hidden = true; say(error.message, "bad"); go.disabled = false; return; }
      const session = answer.body;
      bar.value = 0.6;
      say("Stored. Estimating the joint angles…");
      for (;;) {
        let progress;
        try { progress = await api(answer.location || `/api/recordings/${session.id}/progress`); }
        catch (error) { say(error.message, "bad"); return; }
        if (progress.state === "done") break;
        if (progress.state === "failed") {
          say(`Stored, but it could not be estimated: ${progress.error || "unknown error"}`, "bad");
          return;
        }
        bar.value = Math.min(0.95, bar.value + 0.03);
        await new Promise((r) => setTimeout(r, 700));
      }
      bar.value = 1;
      clear(status, el("div", { class: "import-msg good", id: "import-done" }, "Done: ",
        el("a", { href: "/sessions/" + session.id }, "open the session →")));
      if (onDone) onDone(session);
    });
  }

  window.armtrackImport = { open };
})();

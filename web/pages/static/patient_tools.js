// The patient page's tools: progress charts (each joint's range per session against the
// normal range, the target in force then and today's), targets, the patient's record
// (edit, export, erase) and interrupted sessions to close. User text goes in as text only.
"use strict";

const PatientTools = (() => {
  const SVG = "http://www.w3.org/2000/svg";
  let patientId = null;
  let patient = null;

  function svg(tag, attrs, ...children) {
    const node = document.createElementNS(SVG, tag);
    for (const [k, v] of Object.entries(attrs || {})) if (v !== null && v !== undefined) node.setAttribute(k, v);
    for (const c of children.flat()) if (c !== null && c !== undefined) node.append(c instanceof Node ? c : document.createTextNode(String(c)));
    return node;
  }

  function card(id, title, ...body) {
    let box = document.getElementById(id);
    if (!box) {
      box = el("div", { class: "card", id });
      document.getElementById("tools").append(box);
    }
    return clear(box, el("h2", {}, title), ...body);
  }

  // ------------------------------------------------------------ progress
  function chart(angle, rows, normal, today) {
    // drawn at the width it is shown (a phone's ~330 px too), so its 11 px text stays 11 px
    const room = (document.getElementById("tools") || {}).clientWidth || 0;
    const W = room ? Math.round(Math.min(560, Math.max(280, room - 36))) : 560;
    const H = 220, L = 46, R = 12, T = 14, B = 34;
    const dateLabels = W < 450 ? 6 : 12;
    const values = [];
    for (const r of rows) { values.push(r.rom.min, r.rom.max); if (r.rom.target_max !== null) values.push(r.rom.target_min, r.rom.target_max); }
    if (normal) values.push(normal[0], normal[1]);
    if (today) values.push(today.min_deg, today.max_deg);
    const lo = Math.floor((Math.min(...values) - 10) / 30) * 30;
    const hi = Math.ceil((Math.max(...values) + 10) / 30) * 30;
    const y = (v) => T + (hi - v) / (hi - lo) * (H - T - B);
    const n = rows.length;
    const x = (i) => L + (n === 1 ? (W - L - R) / 2 : i * (W - L - R - 30) / (n - 1) + 15);
    const g = svg("svg", { viewBox: `0 0 ${W} ${H}`, class: "progress-chart", role: "img",
      "aria-label": `${ANGLE_LABELS[angle] || angle}: range per session` });
    for (let v = lo; v <= hi; v += 30) {
      g.append(svg("line", { x1: L, x2: W - R, y1: y(v), y2: y(v), stroke: v === 0 ? "#9aa5b1" : "#e6eaef" }),
        svg("text", { x: L - 6, y: y(v) + 4, "text-anchor": "end", class: "tick" }, `${v}°`));
    }
    if (normal) g.append(svg("rect", { x: L, width: W - L - R, y: y(normal[1]), height: y(normal[0]) - y(normal[1]),
      fill: "#d6dde5", opacity: 0.55 }), svg("text", { x: W - R - 4, y: y(normal[1]) + 13, "text-anchor": "end", class: "tick" }, "normal (AAOS)"));
    if (today) {
      for (const v of [today.min_deg, today.max_deg]) g.append(svg("line", { x1: L, x2: W - R, y1: y(v), y2: y(v),
        stroke: "#e8590c", "stroke-dasharray": "6 4", "stroke-width": 1.5 }));
      g.append(svg("text", { x: L + 4, y: y(today.max_deg) - 4, class: "tick today" }, `today's target ${today.min_deg}…${today.max_deg}°`));
    }
    rows.forEach((r, i) => {
      const cx = x(i);
      if (r.rom.target_max !== null && r.rom.target_max !== undefined) {
        for (const v of [r.rom.target_min, r.rom.target_max]) g.append(svg("line", { x1: cx - 9, x2: cx + 9, y1: y(v), y2: y(v), stroke: "#1d2733", "stroke-width": 2 }));
      }
      g.append(svg("rect", { x: cx - 5, width: 10, y: y(r.rom.max), height: Math.max(2, y(r.rom.min) - y(r.rom.max)), rx: 3,
        fill: "var(--accent)", class: "session-bar" }, svg("title", {}, `${fmtDate(r.started_at)}: ${deg(r.rom.min)} to ${deg(r.rom.max)}`
          + (r.rom.percent_of_normal !== null ? `, ${Math.round(r.rom.percent_of_normal)} % of normal` : ""))));
      if (n <= dateLabels || i % Math.ceil(n / dateLabels) === 0) g.append(svg("text", { x: cx, y: H - 12, "text-anchor": "middle", class: "tick" },
        fmtDate(r.started_at, { dateOnly: true }).replace(/,? \d{4}$/, "")));
    });
    return g;
  }

  async function progress() {
    const p = await api(`/api/patients/${patientId}/progress`);
    // the AAOS normal ranges come with any report's rows (normal_min/normal_max)
    const normals = {};
    for (const s of p.sessions) for (const [a, r] of Object.entries(s.rom))
      if (r.normal_min !== null && r.normal_max !== null) normals[a] = [r.normal_min, r.normal_max];
    const today = Object.fromEntries(p.targets.map((t) => [t.angle, t]));
    const angles = ANGLES.filter((a) => p.sessions.some((s) => s.rom[a]));
    const body = angles.length ? angles.map((a) => {
      const rows = p.sessions.filter((s) => s.rom[a]).map((s) => ({ started_at: s.started_at, rom: s.rom[a] }));
      const trend = p.trend[a];
      return el("div", { class: "progress-angle", dataset: { angle: a } },
        el("h3", {}, ANGLE_LABELS[a] || a,
          el("span", { class: "muted small" }, trend ? ` · ${trend.sessions} session${trend.sessions === 1 ? "" : "s"}, change ${trend.change_deg >= 0 ? "+" : ""}${Math.round(trend.change_deg)}°`
            + (trend.slope_deg_per_week !== null ? `, ${trend.slope_deg_per_week.toFixed(1)}°/week` : "") : "")),
        chart(a, rows, normals[a], today[a]));
    }) : el("p", { class: "muted" }, "No estimated session yet.");
    // the same figures as a file (docs/therapist.md, "Reviewing sessions")
    const csv = `/api/patients/${patientId}/progress.csv`;
    const exportCsv = angles.length ? el("p", { class: "progress-export" },
      el("button", { class: "secondary", dataset: { export: csv }, onclick: async (event) => {
        const button = event.currentTarget;
        button.disabled = true;
        await saveFile(csv, `patient-${patientId}-progress.csv`, document.getElementById("progress-card"));
        button.disabled = false;
      } }, "⬇ progress.csv"),
      el("span", { class: "muted small" }, " each session's range per joint, % of normal, target and repetitions")) : null;
    card("progress-card", "Progress", el("div", { class: "legend" },
      el("span", {}, el("i", { style: "background:var(--accent)" }), "range of each session"),
      el("span", {}, el("i", { style: "background:#d6dde5" }), "normal range"),
      el("span", {}, el("i", { style: "background:#1d2733;height:3px" }), "target then"),
      el("span", {}, el("i", { style: "background:#e8590c;height:3px" }), "today's target")), body, exportCsv);
  }

  // ------------------------------------------------------------ targets
  async function targets() {
    const list = await api(`/api/patients/${patientId}/targets`);
    const form = el("form", { class: "inline", id: "target-form" },
      el("label", {}, "Joint", el("select", { name: "angle", id: "target-angle" },
        ANGLES.map((a) => el("option", { value: a }, ANGLE_LABELS[a])))),
      el("label", {}, "From (°)", el("input", { name: "min_deg", id: "target-min", type: "number", step: "1", min: "-180", max: "180", required: true, style: "width:90px" })),
      el("label", {}, "To (°)", el("input", { name: "max_deg", id: "target-max", type: "number", step: "1", min: "-180", max: "180", required: true, style: "width:90px" })),
      el("label", {}, "Note", el("input", { name: "note", id: "target-note", maxlength: "500", style: "width:220px" })),
      el("button", { type: "submit" }, "Set target"));
    form.addEventListener("submit", async (event) => {
      event.preventDefault();
      const f = new FormData(form);
      try {
        await api(`/api/patients/${patientId}/targets/${f.get("angle")}`, { method: "PUT", body: {
          min_deg: Number(f.get("min_deg")), max_deg: Number(f.get("max_deg")), note: f.get("note").trim() || null } });
        form.reset();
        targets(); progress().catch(() => {});
      } catch (error) { showError(form, error); }
    });
    card("targets-card", "Targets",
      el("p", { class: "muted small" }, "A session is judged against the target in force when it was recorded; a new target applies from now on."),
      el("table", { id: "targets-table" }, el("thead", {}, el("tr", {}, el("th", {}, "Joint"), el("th", {}, "Range"), el("th", {}, "Note"), el("th", {}, "Set"), el("th", {}))),
        el("tbody", {}, list.length ? list.map((t) => el("tr", { dataset: { angle: t.angle } },
          el("td", {}, ANGLE_LABELS[t.angle]), el("td", {}, `${t.min_deg}° to ${t.max_deg}°`),
          el("td", {}, t.note || ""), el("td", { class: "muted" }, fmtDate(t.updated_at)),
          el("td", { class: "num" }, el("button", { class: "danger", onclick: async () => {
            if (!confirm(`Remove the target for ${ANGLE_LABELS[t.angle]}? Past reports keep it.`)) return;
            await api(`/api/patients/${patientId}/targets/${t.angle}`, { method: "DELETE" });
            targets(); progress().catch(() => {});
          } }, "Remove"))))
          : el("tr", {}, el("td", { colspan: 5, class: "muted" }, "No target set.")))),
      form);
  }

  // ------------------------------------------------------------ the record
  function record() {
    const field = (label, name, attrs) => el("label", {}, label, el("input", Object.assign({ name, id: "edit-" + name }, attrs)));
    const form = el("form", { class: "inline", id: "edit-patient" },
      field("Name", "name", { value: patient.name, required: true, maxlength: "200", style: "width:220px" }),
      el("label", {}, "Arm followed", el("select", { name: "side", id: "edit-side" },
        ["right", "left"].map((s) => el("option", { value: s, selected: s === patient.side }, s)))),
      field("Body height (m)", "height_m", { type: "number", step: "0.01", min: "1.0", max: "2.3", value: patient.height_m, required: true, style: "width:100px" }),
      field("Clinic number", "clinic_number", { value: patient.clinic_number || "", maxlength: "64", style: "width:130px" }),
      field("Date of birth", "date_of_birth", { type: "date", min: "1900-01-01", max: todayIso(), value: patient.date_of_birth || "", style: "width:160px" }),
      el("button", { type: "submit" }, "Save"));
    form.addEventListener("submit", async (event) => {
      event.preventDefault();
      const f = new FormData(form);
      try {
        patient = await api(`/api/patients/${patientId}`, { method: "PATCH", body: {
          name: f.get("name").trim(), side: f.get("side"), height_m: Number(f.get("height_m")),
          clinic_number: f.get("clinic_number").trim() || null, date_of_birth: f.get("date_of_birth") || null } });
        document.dispatchEvent(new CustomEvent("armtrack:patient", { detail: patient }));
        showSaved(form);
      } catch (error) { showError(form, error); }
    });
    const exportButton = el("button", { class: "secondary", id: "export-patient", onclick: async () => {
      exportButton.disabled = true;
      await saveFile(`/api/patients/${patientId}/export`, `patient-${patientId}.zip`, form);
      exportButton.disabled = false;
    } }, "⬇ Export all the patient's data (zip)");
    const erase = el("button", { class: "danger", id: "erase-patient", onclick: async () => {
      const typed = prompt(`Erase ${patient.name} with every session, kit and target, for good? Type the patient's name to confirm.`);
      if (typed === null) return;
      if (typed.trim() !== patient.name) { showError(form, "The name did not match: nothing was erased."); return; }
      try { await api(`/api/patients/${patientId}`, { method: "DELETE" }); location.href = "/patients"; }
      catch (error) { showError(form, error); }
    } }, "Erase the patient…");
    // docs/extensions/discharge.md: the records stay, the kits start no new session; the
    // page's notice (patient.html) says so and readmits
    const discharge = el("button", { class: "secondary", id: "discharge-patient", hidden: !!patient.discharged_at, onclick: async () => {
      if (!confirm(`Discharge ${patient.name}? Their sessions, reports and kits stay; their kits start no new session until you readmit them, and the patient list shows them only under “Show discharged”.`)) return;
      try {
        patient = await api(`/api/patients/${patientId}/discharge`, { method: "POST" });
        document.dispatchEvent(new CustomEvent("armtrack:patient", { detail: patient }));
      } catch (error) { showError(form, error); }
    } }, "Discharge…");
    document.addEventListener("armtrack:patient", (event) => {
      patient = event.detail;
      discharge.hidden = !!patient.discharged_at;
    });
    card("record-card", "Patient record", form,
      el("div", { class: "row", style: "margin-top:12px;align-items:center" }, exportButton,
        el("span", { class: "grow" }), discharge, erase));
  }

  function showSaved(where) {
    const note = el("span", { class: "saved", id: "saved-note" }, "Saved ✓");
    where.append(note);
    setTimeout(() => note.remove(), 3000);
  }

  // ------------------------------------------------------------ interrupted sessions
  async function interrupted() {
    const sessions = await api(`/api/patients/${patientId}/sessions?limit=50`);
    const open = sessions.filter((s) => s.status === "interrupted");
    const box = document.getElementById("interrupted-card");
    if (!open.length) { if (box) box.remove(); return; }
    const times = fmtSessionTimes(open.map((s) => s.started_at));
    card("interrupted-card", "Interrupted sessions",
      el("p", { class: "muted small" }, "The kit lost its connection and has not resumed. Close a session to estimate what was recorded."),
      open.map((s, k) => el("div", { class: "row", style: "align-items:center", dataset: { session: s.id } },
        el("a", { href: "/sessions/" + s.id }, `Session ${s.id} · ${times[k]}`),
        s.stopped_by_server ? el("span", { class: "badge s-interrupted", title: s.stopped_by_server.message },
          `stopped by the server ${fmtDate(s.stopped_by_server.at)}`) : null,
        el("button", { class: "secondary close-session", onclick: async (event) => {
          event.currentTarget.disabled = true;
          try {
            await api(`/api/sessions/${s.id}/close?wait=false`, { method: "POST" });  // estimated in the background: polled below
            interrupted();
            whenEstimated(s.id).then(() => progress()).catch(() => {});
          }
          catch (error) { showError(document.getElementById("interrupted-card"), error); }
        } }, "Close and estimate"))));
    document.getElementById("tools").prepend(document.getElementById("interrupted-card"));
  }

  // a closed session is estimated in the background: resolves once it is (or failed)
  async function whenEstimated(sessionId, waitedS = 0) {
    const s = await api(`/api/sessions/${sessionId}`);
    if (s.processed || s.processing_error || waitedS > 600) return s;
    await new Promise((resolve) => setTimeout(resolve, 2000));
    return whenEstimated(sessionId, waitedS + 2);
  }

  async function start(id) {
    patientId = id;
    // what the page changes while the tools load (Readmit clicked on the notice) is what
    // the record card is built from, not this first read
    let changed = false;
    document.addEventListener("armtrack:patient", (event) => { patient = event.detail; changed = true; });
    const first = await api(`/api/patients/${patientId}`);
    if (!changed) patient = first;
    if (!document.getElementById("tools")) document.querySelector("main").append(el("div", { id: "tools" }));
    await Promise.all([interrupted(), progress(), targets()].map((p) => p.catch((e) => showError(document.querySelector("main"), e))));
    record();
    setInterval(() => interrupted().catch(() => {}), 10000);
  }

  return { start, progress, targets };
})();

// Exercise programs on the dashboard (docs/programs.md): the editor and adherence on the
// patient page (mountPrograms), the flags on the patients list (showPatientFlags).
// Every text from the server or a user goes in as text (el() makes text nodes).
"use strict";

const FLAG_LABELS = { no_session: "No session", range_falling: "Range falling", pain_rising: "Pain rising" };

function flagChip(flag) {
  return el("span", { class: "chip flag flag-" + flag.kind, title: flag.message },
    "⚑ " + (FLAG_LABELS[flag.kind] || flag.kind));
}

// The patients list: a "needs a look" chip per flag, in the row's last-but-one cell (none
// for a discharged patient: docs/extensions/discharge.md).
async function showPatientFlags(tbody) {
  let flagged;
  try { flagged = await api("/api/flags"); } catch (_) { return; }
  for (const entry of flagged) {
    const row = tbody.querySelector(`tr[data-patient="${entry.patient_id}"]`);
    if (!row || "discharged" in row.dataset) continue;  // in care no more: nothing to look at
    const cell = row.querySelector(".now-cell");
    cell.append(...entry.flags.map((f) => el("div", { class: "flag-line" }, flagChip(f),
      el("span", { class: "small muted" }, " " + f.message))));
  }
}

// --- the patient page ---------------------------------------------------------------

let catalogue = [];
let cataloguePatient = null;

async function mountPrograms(patientId, box) {
  // with the patient: whether their kits measure each exercise (measurable, why_not)
  if (!catalogue.length || cataloguePatient !== patientId) {
    catalogue = await api(`/api/programs/catalogue?patient_id=${encodeURIComponent(patientId)}`);
    cataloguePatient = patientId;
  }
  const [programs, patient] = await Promise.all([
    api(`/api/patients/${patientId}/programs`), api(`/api/patients/${patientId}`)]);
  // discharged (docs/extensions/discharge.md): the kits guide no program, as the phone
  // says; readmitting takes it up again. The card is built again on either.
  const discharged = patient.discharged_at;
  if (!box.dataset.followsDischarge) {
    box.dataset.followsDischarge = "1";
    document.addEventListener("armtrack:patient", (event) => {
      if (!!event.detail.discharged_at !== !!box.dataset.discharged) mountPrograms(patientId, box);
    });
  }
  if (discharged) box.dataset.discharged = "1"; else delete box.dataset.discharged;
  const cards = [];
  for (const p of programs) cards.push(await programCard(patientId, p, box, discharged));
  clear(box, el("div", { class: "card", id: "programs-card" },
    el("div", { class: "row", style: "justify-content:space-between;align-items:center" },
      el("h2", { style: "margin:0" }, "Exercise programs"),
      discharged ? null : el("button", { id: "new-program", onclick: () => openEditor(patientId, box, null) },
        "New program")),
    programs.length ? cards : el("p", { class: "muted" },
      "No program yet. Prescribe one: the patient's kit then guides it, and you see here "
      + "whether it is done and whether it works.")));
}

async function programCard(patientId, p, box, discharged) {
  const v = p.version;
  const adherence = await api(`/api/programs/${p.id}/adherence`);
  const dates = `from ${fmtDay(v.start_date)}` + (v.end_date ? ` to ${fmtDay(v.end_date)}` : "");
  const stopped = discharged && p.active;  // in force but for the discharge
  const force = stopped ? "not in force: discharged" : p.active ? "in force" : "not in force";
  return el("div", { class: "program", dataset: { program: p.id } },
    el("div", { class: "row", style: "justify-content:space-between;align-items:baseline;flex-wrap:wrap" },
      el("h3", { style: "margin:8px 0" }, p.name, " ",
        el("span", { class: "badge " + (p.active && !stopped ? "in-force" : "not-in-force") }, force),
        " ", el("span", { class: "muted small" }, `version ${v.number}, ${dates}`)),
      el("div", { class: "row" },
        discharged ? null : el("button", { class: "secondary", onclick: () => openEditor(patientId, box, p) }, "Change"),
        el("button", { class: "secondary", title: "The program as FHIR R4 (CarePlan, Goals, ServiceRequests, Observations)",
          onclick: () => download(`/api/programs/${p.id}/careplan.fhir.json`, `program-${p.id}.fhir.json`) }, "FHIR"),
        el("button", { class: "secondary", title: "Progress report (PDF)",
          onclick: () => download(`/api/patients/${patientId}/progress.pdf`, `patient-${patientId}-progress.pdf`) }, "PDF"),
        p.ended_at ? null : el("button", { class: "danger", onclick: async () => {
          if (!confirm(`End “${p.name}”? It stays with its history; no more prescriptions or flags after today.`)) return;
          await api(`/api/programs/${p.id}/end`, { method: "POST" });
          mountPrograms(patientId, box);
        } }, "End"))),
    stopped ? el("p", { class: "notice discharge-stopped" },
      `The discharge on ${fmtDate(discharged, { dateOnly: true })} stopped this program: the patient's kit `
      + "guides it no more and starts no session (their phone says they were discharged). "
      + "Readmit the patient (at the top of the page) to take it up again or to change it.") : null,
    adherence.flags.length ? el("div", { class: "flags" }, adherence.flags.map((f) =>
      el("div", { class: "flag-line" }, flagChip(f), " ", f.message))) : null,
    v.note ? el("p", { class: "muted" }, v.note) : null,
    el("div", { class: "scroll" }, el("table", { class: "program-exercises" },
      el("thead", {}, el("tr", {}, ["Exercise", "Dose", "Days a week", "Target", "Last range", "Note"]
        .map((h) => el("th", {}, h)))),
      el("tbody", {}, v.exercises.map((e) => {
        const points = (adherence.exercises.find((x) => x.exercise === e.exercise) || { points: [] }).points;
        const last = points[points.length - 1];
        return el("tr", { dataset: { exercise: e.exercise } },
          el("td", {}, e.title, el("div", { class: "small muted" }, "measured on " + (ANGLE_LABELS[e.angle] || e.angle))),
          el("td", {}, `${e.sets} × ${e.repetitions}` + (e.hold_s ? `, hold ${e.hold_s} s` : "") + (e.sets > 1 ? `, rest ${e.rest_s} s` : "")),
          el("td", { class: "num" }, String(e.days_per_week)),
          el("td", {}, `${deg(e.target[0])} to ${deg(e.target[1])}`,
            el("div", { class: "small muted" }, TARGET_SOURCE_WORDS[e.target_source] || e.target_source)),
          el("td", {}, last ? [deg(last.range_deg), " ", rangeChart(points)] : el("span", { class: "muted" }, "not done yet")),
          el("td", { class: "small" }, e.note || ""));
      })))),
    uncountedNote(adherence.uncounted_sessions),
    weeksTable(adherence.weeks),
    painLine(adherence.pain));
}

/** Sessions of the patient this program does not count (their kit did not follow it):
 * said, so that "not done yet" beside a list of sessions is not a puzzle. */
function uncountedNote(n) {
  if (!n) return null;
  return el("p", { class: "small muted uncounted" },
    `${n} session${n === 1 ? "" : "s"} of this patient during this program ${n === 1 ? "is" : "are"} not counted here: `
    + "the kit did not follow this program (it neither named it nor marked its exercises). "
    + "The phone kit follows it; for a sensor kit, see docs/programs.md.");
}

/** Saves the server's answer as `filename` only when it is the file: a refusal (the
 * patient handed to a colleague or erased meanwhile, too many reports at once) is said in
 * the programs card in the server's words, and a sign-in that ended goes to the sign-in
 * page, as `api` does; before, the refusal's JSON was saved under the PDF's name. */
function download(path, filename) {
  return saveFile(path, filename, document.getElementById("programs-card") || document.querySelector("main"));
}

// The range of each session (dots and line) against the target band, oldest left.
function rangeChart(points) {
  const w = 120, h = 32, ns = "http://www.w3.org/2000/svg";
  const svg = document.createElementNS(ns, "svg");
  svg.setAttribute("viewBox", `0 0 ${w} ${h}`); svg.setAttribute("class", "rangechart");
  svg.setAttribute("role", "img");
  svg.setAttribute("aria-label", "range per session: " + points.map((p) => deg(p.range_deg)).join(", "));
  const target = points[points.length - 1].target_max_deg - points[points.length - 1].target_min_deg;
  const values = points.map((p) => p.range_deg ?? 0);
  const top = Math.max(target, ...values) * 1.1 || 1;
  const y = (v) => h - 2 - (v / top) * (h - 4);
  const x = (i) => points.length === 1 ? w / 2 : 4 + (i * (w - 8)) / (points.length - 1);
  const band = document.createElementNS(ns, "line");
  Object.entries({ x1: 0, x2: w, y1: y(target), y2: y(target), class: "target" }).forEach(([k, v]) => band.setAttribute(k, v));
  svg.append(band);
  const line = document.createElementNS(ns, "polyline");
  line.setAttribute("points", values.map((v, i) => `${x(i)},${y(v)}`).join(" "));
  svg.append(line);
  return svg;
}

function weeksTable(weeks) {
  if (!weeks.length) return null;
  const cell = (done, prescribed) => el("td", { class: "num" }, `${done} / ${prescribed}`);
  return el("details", { class: "weeks", open: true },
    el("summary", {}, "Adherence by week (done / prescribed)"),
    el("div", { class: "scroll" }, el("table", { class: "adherence" },
      el("thead", {}, el("tr", {}, ["Week", "Days", "Sessions", "Exercises", "Repetitions", "Adherence"]
        .map((h, i) => el("th", { class: i ? "num" : "" }, h)))),
      el("tbody", {}, weeks.slice().reverse().map((w) => el("tr", { dataset: { week: w.week } },
        el("td", { title: `ISO week ${w.week}` }, `week of ${fmtDay(w.monday)}`,
          el("span", { class: "small muted" }, ` v${w.version}`), weekWhy(w)),
        // days: the figure the patient's phone says ("This week: 2 of 5 days done")
        cell(w.done.days, w.prescribed.days),
        cell(w.done.sessions, w.prescribed.sessions), cell(w.done.exercises, w.prescribed.exercises),
        cell(w.done.repetitions, w.prescribed.repetitions),
        el("td", { class: "num " + percentClass(w.adherence_percent) },
          w.adherence_percent === null ? "—" : w.adherence_percent.toFixed(0) + " %")))))));
}

// Why a week asks other days than the program's "N days a week" (the adherence's
// shortened and changed_on), under the week's name, as the patient's phone says it:
// "began 2 Dec 2026 · changed 3 Dec 2026: counts from the next week"; null when neither.
function weekWhy(w) {
  const s = w.shortened || {};
  const parts = [s.starts_on ? `began ${fmtDay(s.starts_on)}` : null,
    s.ends_on ? `ends ${fmtDay(s.ends_on)}` : null,
    w.changed_on ? `changed ${fmtDay(w.changed_on)}: counts from the next week` : null].filter(Boolean);
  return parts.length ? el("span", { class: "small muted week-why", style: "display:block" }, parts.join(" · ")) : null;
}

function painLine(pain) {
  if (!pain.length) return null;
  return el("p", { class: "small" }, el("b", {}, "Pain (0–10) and effort (Borg CR10) by session: "),
    pain.map((p, i) => [i ? " · " : "", `${fmtDay(p.day)}: pain ${p.pain ?? "—"}, effort ${p.effort ?? "—"}`]));
}

// Where an exercise's target comes from, in the therapist's words (the API's
// ``target_source``): the program's own, else the patient's target for the angle, else
// the exercise's usual range (the catalogue's).
const TARGET_SOURCE_WORDS = {
  program: "set in this program", patient: "the patient's target", catalogue: "the exercise's usual range",
};

// --- the editor -----------------------------------------------------------------------

function exerciseRow(value) {
  const offered = catalogue.filter((c) => c.measurable !== false);
  const v = value || { exercise: (offered[0] || catalogue[0]).name, sets: 2, repetitions: 10, days_per_week: 5,
    hold_s: 0, rest_s: 30, target_min_deg: null, target_max_deg: null, note: "" };
  // only what the patient's kits measure is offered; an exercise already prescribed stays
  const select = el("select", { name: "exercise", "aria-label": "Exercise" },
    catalogue.filter((c) => c.measurable !== false || c.name === v.exercise).map((c) =>
      el("option", { value: c.name, selected: c.name === v.exercise },
        `${c.title} (${ANGLE_LABELS[c.angle] || c.angle})`
        + (c.measurable === false ? " — not measured by this patient's kits" : ""))));
  const num = (name, val, attrs) => el("input", Object.assign({ name, type: "number", value: val ?? "",
    "aria-label": name.replace(/_/g, " ") }, attrs));
  const row = el("div", { class: "exercise-row" },
    el("label", { class: "wide" }, "Exercise", select),
    el("label", { class: "dose" }, "Sets", num("sets", v.sets, { min: 1, max: 20, required: true })),
    el("label", { class: "dose" }, "Repetitions", num("repetitions", v.repetitions, { min: 1, max: 100, required: true })),
    el("label", { class: "dose" }, "Days a week", num("days_per_week", v.days_per_week, { min: 1, max: 7, required: true })),
    el("label", { class: "pair" }, "Hold (s)", num("hold_s", v.hold_s, { min: 0, max: 60, step: "any" })),
    el("label", { class: "pair" }, "Rest (s)", num("rest_s", v.rest_s, { min: 0, max: 600, step: "any" })),
    el("label", { class: "pair" }, "Target from (°)", num("target_min_deg", v.target_min_deg, { step: "any" })),
    el("label", { class: "pair" }, "to (°)", num("target_max_deg", v.target_max_deg, { step: "any" })),
    el("label", { class: "wide" }, "Note for the patient", el("input", { name: "note", value: v.note || "", maxlength: 500 })),
    el("div", { class: "row wide actions" },
      el("button", { type: "button", class: "secondary", title: "Move up", "aria-label": "Move up",
        onclick: () => row.previousElementSibling && row.parentNode.insertBefore(row, row.previousElementSibling) }, "↑"),
      el("button", { type: "button", class: "secondary", title: "Move down", "aria-label": "Move down",
        onclick: () => row.nextElementSibling && row.parentNode.insertBefore(row.nextElementSibling, row) }, "↓"),
      el("button", { type: "button", class: "danger", onclick: () => row.remove() }, "Remove")));
  return row;
}

function readRow(row) {
  const value = (name) => row.querySelector(`[name="${name}"]`).value;
  const number = (name) => value(name) === "" ? null : Number(value(name));
  return { exercise: value("exercise"), sets: number("sets"), repetitions: number("repetitions"),
    days_per_week: number("days_per_week"), hold_s: number("hold_s") ?? 0, rest_s: number("rest_s") ?? 30,
    target_min_deg: number("target_min_deg"), target_max_deg: number("target_max_deg"),
    note: value("note") || null };
}

/** What is wrong with the exercises' targets, in the form's words (the API would refuse the
 * same with its field names: "target_min_deg must be below target_max_deg"), or null. */
function targetProblem(exercises) {
  for (const e of exercises) {
    const title = (catalogue.find((c) => c.name === e.exercise) || { title: e.exercise }).title;
    const a = e.target_min_deg, b = e.target_max_deg;
    if ((a === null) !== (b === null))
      return `${title}: give both ends of the target, or neither (then the patient's own target applies).`;
    if (a !== null && !(a < b))
      return `${title}: the target's “from” (${a}°) must be below its “to” (${b}°).`;
  }
  return null;
}

/** The exercises left out of the editor's choice, each with why (the server's words). */
function notOffered() {
  if (catalogue.every((c) => c.measurable == null)) {
    return el("p", { class: "small muted", id: "not-offered" },
      "No kit of this patient has sent a session yet, so every exercise is offered: a phone "
      + "on the forearm measures the elbow and the forearm's turn, on the upper arm the shoulder.");
  }
  const left = catalogue.filter((c) => c.measurable === false);
  if (!left.length) return null;
  return el("div", { class: "small not-offered", id: "not-offered" },
    el("b", {}, "Not offered for this patient's kits:"),
    el("ul", {}, left.map((c) => el("li", {}, c.why_not))));
}

function openEditor(patientId, box, program) {
  const v = program ? program.version : null;
  const today = new Date().toISOString().slice(0, 10);
  const rows = el("div", { class: "exercise-rows" },
    (v ? v.exercises : [null]).map((e) => exerciseRow(e)));
  const form = el("form", { class: "card program-editor", id: "program-editor" },
    el("h2", {}, program ? `Change “${program.name}” (saved as version ${v.number + 1})` : "New program"),
    program ? el("p", { class: "muted small" },
      "Sessions already done keep the version they followed.") : null,
    el("div", { class: "row wrap" },
      program ? null : el("label", { class: "name-field" }, "Name", el("input", { name: "name", required: true, maxlength: 120, placeholder: "e.g. Elbow after the fracture" })),
      el("label", {}, "Start", el("input", { name: "start_date", type: "date", required: true, value: v ? v.start_date : today })),
      el("label", {}, "End (optional)", el("input", { name: "end_date", type: "date", value: v && v.end_date ? v.end_date : "" }))),
    el("label", { class: "wide" }, "Note", el("textarea", { name: "note", maxlength: 2000, rows: 2 }, v && v.note ? v.note : "")),
    el("h3", {}, "Exercises, in order"),
    el("p", { class: "small muted", id: "target-hint" },
      "A target left blank is the patient's own target for the exercise's angle, or else the "
      + "exercise's usual range."),
    notOffered(), rows,
    el("div", { class: "row", style: "margin-top:10px" },
      el("button", { type: "button", class: "secondary", id: "add-exercise", onclick: () => rows.append(exerciseRow(null)) }, "Add exercise"),
      el("span", { class: "grow" }),
      el("button", { type: "button", class: "secondary", onclick: () => mountPrograms(patientId, box) }, "Cancel"),
      el("button", { type: "submit", id: "save-program" }, program ? "Save as a new version" : "Prescribe")));
  form.addEventListener("submit", async (event) => {
    event.preventDefault();
    const data = new FormData(form);
    const body = { start_date: data.get("start_date"), end_date: data.get("end_date") || null,
      note: data.get("note") || null, exercises: [...rows.children].map(readRow) };
    const problem = targetProblem(body.exercises);
    if (problem) { showError(form, problem); return; }
    try {
      if (program) await api(`/api/programs/${program.id}`, { method: "PUT", body });
      else await api(`/api/patients/${patientId}/programs`, { method: "POST", body: { name: data.get("name"), ...body } });
      await mountPrograms(patientId, box);
    } catch (error) { showError(form, error); }
  });
  clear(box, form);
  form.scrollIntoView({ block: "start" });
}

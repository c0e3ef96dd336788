// The audit log page (/audit): GET /api/audit with filters and pages of 50, newest first.
// A therapist sees their patients' trail and their own actions; a clinic admin every entry
// (and may filter by who acted). Every name and route is inserted as text.
"use strict";

const AUDIT_PAGE = 50;
const AUDIT_ACTIONS = {
  viewed: "Viewed", listed: "Listed patients", exported: "Exported", uploaded: "Uploaded",
  erased: "Erased", erased_retention: "Erased (retention)",
  closed_silence: "Closed (kit silent)", viewed_3d: "Opened the 3D view",
  reassigned: "Reassigned", issued_device: "Issued a kit", revoked_device: "Revoked a kit",
  discharged: "Discharged", readmitted: "Readmitted",
  changed: "Changed", viewed_live: "Watched live", issued_reset: "Issued a password reset",
  reset_password: "Reset the password", created_account: "Created an account",
  disabled_account: "Disabled an account", enabled_account: "Enabled an account",
  changed_password: "Changed their password",
};

frame([{ text: "Audit log" }]);

const auditState = { offset: 0, patients: new Map() };
const auditBody = document.querySelector("#audit-table tbody");

for (const [value, text] of Object.entries(AUDIT_ACTIONS)) {
  document.getElementById("f-action").append(el("option", { value }, text));
}

function auditFilters() {
  const params = new URLSearchParams();
  const pairs = [["patient_id", "f-patient"], ["therapist_id", "f-actor"], ["action", "f-action"],
    ["from_date", "f-from"], ["to_date", "f-to"]];
  for (const [name, id] of pairs) {
    const value = document.getElementById(id).value;
    if (value) params.set(name, value);
  }
  return params;
}

function patientCell(id) {
  if (id === null || id === undefined) return el("span", { class: "muted" }, "—");
  const name = auditState.patients.get(id);
  if (name && !(window.ME && window.ME.is_admin)) return el("a", { href: "/patients/" + id }, name);
  return name ? el("span", {}, name) : el("span", { class: "muted" }, "patient #" + id);
}

async function loadAudit() {
  const params = auditFilters();
  params.set("limit", String(AUDIT_PAGE + 1));
  params.set("offset", String(auditState.offset));
  let rows;
  try {
    rows = await api("/api/audit?" + params.toString());
  } catch (error) { showError(document.querySelector("main"), error); return; }
  const more = rows.length > AUDIT_PAGE;
  rows = rows.slice(0, AUDIT_PAGE);
  clear(auditBody, rows.map((e) => el("tr", { dataset: { entry: e.id } },
    el("td", { class: "nowrap" }, fmtDate(e.at)),
    el("td", {}, e.actor || (e.therapist_id ? "therapist #" + e.therapist_id : "kit #" + e.device_id)),
    el("td", { class: "nowrap" }, AUDIT_ACTIONS[e.action] || e.action),
    el("td", {}, patientCell(e.patient_id)),
    el("td", {}, e.session_id ? el("span", {}, "#" + e.session_id) : el("span", { class: "muted" }, "—")),
    el("td", { class: "muted small" }, e.client || "—"),
    el("td", { class: "route small" }, e.route))));
  document.getElementById("audit-empty").hidden = rows.length > 0;
  document.getElementById("audit-newer").disabled = auditState.offset === 0;
  document.getElementById("audit-older").disabled = !more;
  document.getElementById("audit-range").textContent = rows.length
    ? `entries ${auditState.offset + 1}–${auditState.offset + rows.length}` : "";
}

async function loadAuditChoices(me) {
  const patientSelect = document.getElementById("f-patient");
  const asked = new URLSearchParams(location.search);
  let patients = [];
  try {
    patients = me.is_admin ? await api("/api/admin/patients?limit=1000") : await api("/api/patients?limit=1000");
  } catch (_) { patients = []; }
  for (const p of patients) {
    auditState.patients.set(p.id, p.name);
    patientSelect.append(el("option", { value: p.id }, p.name));
  }
  if (me.is_admin) {
    document.getElementById("audit-scope").textContent = "Every entry of the clinic: who viewed, "
      + "exported, uploaded, erased or reassigned patients' data, when, and from which address.";
    document.getElementById("f-actor-label").hidden = false;
    try {
      const actorSelect = document.getElementById("f-actor");
      for (const t of await api("/api/admin/therapists?limit=1000")) {
        actorSelect.append(el("option", { value: t.id }, t.full_name ? `${t.full_name} (${t.username})` : t.username));
      }
    } catch (_) { /* the filter stays "Anyone" */ }
  } else {
    document.getElementById("audit-scope").textContent = "The trail of your patients (whoever acted: "
      + "you, their kit, an admin, a former therapist) and your own actions: who viewed, exported, "
      + "uploaded or erased data, when, and from which address.";
  }
  const wanted = asked.get("patient_id");
  if (wanted && !auditState.patients.has(Number(wanted))) {
    patientSelect.append(el("option", { value: wanted }, "patient #" + wanted));
  }
  if (wanted) patientSelect.value = wanted;
}

document.getElementById("audit-filters").addEventListener("submit", (event) => {
  event.preventDefault();
  auditState.offset = 0;
  loadAudit();
});
document.getElementById("f-clear").addEventListener("click", () => {
  document.getElementById("audit-filters").reset();
  auditState.offset = 0;
  loadAudit();
});
document.getElementById("audit-older").addEventListener("click", () => {
  auditState.offset += AUDIT_PAGE;
  loadAudit();
});
document.getElementById("audit-newer").addEventListener("click", () => {
  auditState.offset = Math.max(0, auditState.offset - AUDIT_PAGE);
  loadAudit();
});

api("/api/me").then(loadAuditChoices).then(loadAudit)
  .catch((error) => showError(document.querySelector("main"), error));

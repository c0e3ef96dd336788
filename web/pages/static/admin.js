// The clinic admin's screens (/admin) over /api/admin/*: therapists (list, add, disable,
// enable, a one-time password reset code shown once) and patients' reassignment. A
// non-admin gets 403 from the API and sees only a notice. Names are inserted as text.
"use strict";

const ADMIN_PATIENT_PAGE = 50;
const adminState = { therapists: [], patientOffset: 0 };

frame([{ text: "Clinic accounts" }]);

function therapistLabel(t) {
  return t.full_name ? `${t.full_name} (${t.username})` : t.username;
}

// in care, the load a hand-over shares out; the discharged ones (records kept) beside it
function patientCounts(t) {
  return [el("span", { class: "nowrap" }, `${t.patients} in care`),
    el("br"), el("span", { class: "muted small nowrap" }, `${t.discharged_patients} discharged`)];
}

function therapistRow(t) {
  const me = window.ME && window.ME.id === t.id;
  const status = t.disabled_at
    ? el("span", { class: "status-disabled" }, "Disabled " + fmtDate(t.disabled_at, { dateOnly: true }))
    : el("span", {}, "Active");
  const actions = el("div", { class: "actions" });
  if (!me) {
    actions.append(t.disabled_at
      ? el("button", { type: "button", class: "secondary", dataset: { act: "enable" }, onclick: () => enableTherapist(t) }, "Enable")
      : el("button", { type: "button", class: "danger", dataset: { act: "disable" }, onclick: () => disableTherapist(t) }, "Disable"));
  }
  // no reset code for an admin, oneself included (its holder would act in their name)
  if (!t.is_admin) {
    actions.append(el("button", { type: "button", class: "secondary", dataset: { act: "reset" }, onclick: () => resetPassword(t) },
      "Reset password"));
  } else if (me) {
    actions.append(el("a", { href: "/account", dataset: { act: "own-password" } }, "Change your password"));
  }
  return el("tr", { dataset: { therapist: t.id, username: t.username } },
    el("td", { class: "nowrap" }, t.username, me ? el("span", { class: "muted small" }, " (you)") : null),
    el("td", {}, t.full_name || el("span", { class: "muted" }, "—")),
    el("td", {}, t.is_admin ? "Clinic admin" : "Therapist"),
    el("td", { class: "num" }, t.is_admin ? el("span", { class: "muted" }, "—") : patientCounts(t)),
    el("td", { class: "status" }, status),
    el("td", {}, actions));
}

async function loadTherapists() {
  adminState.therapists = await api("/api/admin/therapists?limit=1000");
  clear(document.querySelector("#therapists tbody"), adminState.therapists.map(therapistRow));
}

async function disableTherapist(t) {
  if (!confirm(`Disable ${therapistLabel(t)}? They are signed out at once and cannot sign in `
    + "until enabled again. Their patients stay theirs: hand them to a colleague below.")) return;
  try {
    await api(`/api/admin/therapists/${t.id}/disable`, { method: "POST" });
    await refreshAll();
  } catch (error) { showError(document.querySelector("#therapists").closest(".card"), error); }
}

async function enableTherapist(t) {
  try {
    await api(`/api/admin/therapists/${t.id}/enable`, { method: "POST" });
    await refreshAll();
  } catch (error) { showError(document.querySelector("#therapists").closest(".card"), error); }
}

async function resetPassword(t) {
  if (!confirm(`Make a one-time reset code for ${therapistLabel(t)}? Their password keeps working `
    + "until they set a new one with the code.")) return;
  try {
    const reset = await api(`/api/admin/therapists/${t.id}/reset`, { method: "POST" });
    document.getElementById("reset-who").textContent = therapistLabel(t);
    document.getElementById("reset-code").textContent = reset.reset_token;
    const hours = reset.expires_in / 3600;
    document.getElementById("reset-hours").textContent = hours >= 1
      ? `${Math.round(hours * 10) / 10} hours` : `${Math.round(reset.expires_in / 60)} minutes`;
    const box = document.getElementById("reset-box");
    box.hidden = false;
    box.scrollIntoView({ block: "nearest" });
  } catch (error) { showError(document.querySelector("#therapists").closest(".card"), error); }
}

document.getElementById("reset-done").addEventListener("click", () => {
  document.getElementById("reset-code").textContent = "";  // shown once: gone from the page
  document.getElementById("reset-box").hidden = true;
});

document.getElementById("add-therapist").addEventListener("submit", async (event) => {
  event.preventDefault();
  const form = event.target;
  try {
    const made = await api("/api/admin/therapists", { method: "POST", body: {
      username: document.getElementById("new-username").value.trim(),
      password: document.getElementById("new-password").value,
      full_name: document.getElementById("new-full-name").value.trim() || null,
      is_admin: document.getElementById("new-admin").checked } });
    form.reset();
    await refreshAll();
    const saved = el("span", { class: "saved", id: "therapist-added" }, `Added ${therapistLabel(made)}.`);
    form.append(saved);
    setTimeout(() => saved.remove(), 6000);
  } catch (error) { showError(form, error); }
});

function patientRow(p) {
  const holders = adminState.therapists.filter((t) => !t.is_admin && !t.disabled_at && t.id !== p.therapist_id);
  const current = adminState.therapists.find((t) => t.id === p.therapist_id);
  const select = el("select", { "aria-label": "Hand " + p.name + " to" },
    el("option", { value: "" }, "choose a therapist…"),
    holders.map((t) => el("option", { value: t.id }, therapistLabel(t))));
  const button = el("button", { type: "button", class: "secondary", dataset: { act: "reassign" } }, "Hand over");
  button.addEventListener("click", async () => {
    if (!select.value) { select.focus(); return; }
    const target = adminState.therapists.find((t) => t.id === Number(select.value));
    if (!confirm(`Hand ${p.name} to ${therapistLabel(target)}? `
      + `${current ? therapistLabel(current) : "The former therapist"} no longer sees them.`)) return;
    try {
      await api(`/api/admin/patients/${p.id}/reassign`, { method: "POST", body: { therapist_id: Number(select.value) } });
      await refreshAll();
    } catch (error) { showError(document.querySelector("#admin-patients").closest(".card"), error); }
  });
  return el("tr", { dataset: p.discharged_at ? { patient: p.id, discharged: "" } : { patient: p.id } },
    el("td", {}, p.name, p.discharged_at ? [" ", el("span", { class: "badge s-discharged",
      title: "Discharged on " + fmtDate(p.discharged_at, { dateOnly: true }) }, "Discharged")] : null),
    el("td", { class: "holder" }, current ? therapistLabel(current) : "#" + p.therapist_id,
      current && current.disabled_at ? el("span", { class: "status-disabled small" }, " (disabled)") : null),
    el("td", {}, el("div", { class: "reassign" }, select, button)));
}

async function loadPatients() {
  // as the therapist's list: the patients in care; "Show discharged" adds the rest, marked
  const all = document.getElementById("admin-show-discharged").checked;
  const rows = await api(`/api/admin/patients?limit=${ADMIN_PATIENT_PAGE + 1}&offset=${adminState.patientOffset}`
    + (all ? "" : "&discharged=false"));
  const more = rows.length > ADMIN_PATIENT_PAGE;
  const shown = rows.slice(0, ADMIN_PATIENT_PAGE);
  clear(document.querySelector("#admin-patients tbody"), shown.map(patientRow));
  const empty = document.getElementById("admin-patients-empty");
  empty.textContent = all ? "No patient yet." : "No patient in care. “Show discharged” lists the discharged ones.";
  empty.hidden = shown.length > 0;
  document.getElementById("patients-prev").disabled = adminState.patientOffset === 0;
  document.getElementById("patients-next").disabled = !more;
  document.getElementById("patients-range").textContent = shown.length
    ? `patients ${adminState.patientOffset + 1}–${adminState.patientOffset + shown.length}` : "";
}

async function refreshAll() {
  await loadTherapists();
  await loadPatients();
}

document.getElementById("admin-show-discharged").addEventListener("change", () => {
  adminState.patientOffset = 0;
  loadPatients().catch((error) => showError(document.querySelector("#admin-patients").closest(".card"), error));
});
document.getElementById("patients-next").addEventListener("click", () => {
  adminState.patientOffset += ADMIN_PATIENT_PAGE;
  loadPatients();
});
document.getElementById("patients-prev").addEventListener("click", () => {
  adminState.patientOffset = Math.max(0, adminState.patientOffset - ADMIN_PATIENT_PAGE);
  loadPatients();
});

api("/api/me").then(async (me) => {
  window.ME = me;
  if (!me.is_admin) {
    document.getElementById("admin-refused").hidden = false;
    return;
  }
  document.getElementById("admin-body").hidden = false;
  await refreshAll();
}).catch((error) => {
  if (error.status === 403) document.getElementById("admin-refused").hidden = false;
  else showError(document.querySelector("main"), error);
});

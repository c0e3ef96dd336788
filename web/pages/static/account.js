// The signed-in therapist's account (/account): full name (PATCH /api/me) and password
// (POST /api/auth/password).
"use strict";

frame([{ text: "Your account" }]);

function saved(form, text) {
  const note = el("span", { class: "saved" }, text);
  form.append(note);
  setTimeout(() => note.remove(), 6000);
}

api("/api/me").then((me) => {
  document.getElementById("full-name").value = me.full_name || "";
  document.getElementById("account-facts").textContent = `User name ${me.username} · `
    + (me.is_admin ? "clinic admin" : "therapist");
}).catch((error) => showError(document.querySelector("main"), error));

document.getElementById("name-form").addEventListener("submit", async (event) => {
  event.preventDefault();
  try {
    const me = await api("/api/me", { method: "PATCH",
      body: { full_name: document.getElementById("full-name").value.trim() || null } });
    document.getElementById("who-name").textContent = me.full_name || me.username;
    saved(event.target, "Saved ✓");
  } catch (error) { showError(event.target, error); }
});

document.getElementById("password-form").addEventListener("submit", async (event) => {
  event.preventDefault();
  const form = event.target;
  const fresh = document.getElementById("new-password").value;
  if (fresh !== document.getElementById("new-again").value) {
    showError(form, "the two new passwords differ: type the same one twice");
    return;
  }
  try {
    await api("/api/auth/password", { method: "POST",
      body: { old_password: document.getElementById("old-password").value, new_password: fresh } });
    form.reset();
    saved(form, "Password changed ✓");
  } catch (error) { showError(form, error); }
});

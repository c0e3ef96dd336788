// The sign-in page's "I have a reset code" form: POST /api/auth/reset with the one-time
// code a clinic admin gave (as the bearer token) and the new password.
"use strict";
document.getElementById("reset-form").addEventListener("submit", async (event) => {
  event.preventDefault();
  const message = document.getElementById("reset-message");
  const say = (kind, text) => {
    const box = document.createElement("div");
    box.className = kind; box.textContent = text;
    message.replaceChildren(box);
  };
  const password = document.getElementById("reset-password").value;
  if (password !== document.getElementById("reset-again").value) {
    say("error", "the two new passwords differ: type the same one twice");
    return;
  }
  const code = document.getElementById("reset-code").value.trim();
  const answer = await fetch("/api/auth/reset", { method: "POST",
    headers: { Authorization: "Bearer " + code, "Content-Type": "application/json" },
    body: JSON.stringify({ new_password: password }) });
  if (!answer.ok) {
    let detail = "the password could not be set";
    try {
      const data = await answer.json();
      detail = typeof data.detail === "string" ? data.detail
        : (data.detail || []).map((d) => d.msg).join("; ");
    } catch (_) { /* keep */ }
    say("error", detail);
    return;
  }
  event.target.reset();
  say("notice", "Your new password is set: sign in with it above.");
  document.getElementById("password").value = "";
  document.getElementById("password").focus();
});

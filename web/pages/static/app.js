// armtrack dashboard: shared helpers. No build step, no framework.
// The bearer token lives in sessionStorage (gone when the tab closes).
"use strict";

const TOKEN_KEY = "armtrack.token";
const USER_KEY = "armtrack.user";

const ANGLE_LABELS = {
  clavicle_protraction: "Clavicle protraction",
  clavicle_elevation: "Clavicle elevation",
  shoulder_flexion: "Shoulder flexion",
  shoulder_abduction: "Shoulder abduction",
  shoulder_rotation: "Shoulder rotation",
  elbow_flexion: "Elbow flexion",
  forearm_pronation: "Forearm pronation",
  wrist_flexion: "Wrist flexion",
  wrist_deviation: "Wrist deviation",
  shoulder_elevation: "Shoulder elevation",
};
const ANGLES = Object.keys(ANGLE_LABELS);

function token() { return sessionStorage.getItem(TOKEN_KEY); }

function signOut() {
  sessionStorage.removeItem(TOKEN_KEY);
  sessionStorage.removeItem(USER_KEY);
  location.href = "/signin";
}

function requireSignIn() {
  if (!token()) {
    location.href = "/signin?next=" + encodeURIComponent(location.pathname);
    throw new Error("not signed in");
  }
}

class ApiError extends Error {
  constructor(status, detail) { super(detail); this.status = status; }
}

async function api(path, options = {}) {
  const headers = Object.assign({ Authorization: "Bearer " + token() }, options.headers || {});
  let body = options.body;
  if (body !== undefined && !(body instanceof FormData) && typeof body !== "string") {
    body = JSON.stringify(body);
    headers["Content-Type"] = "application/json";
  }
  const answer = await fetch(path, { method: options.method || "GET", headers, body });
  if (answer.status === 401) {
    sessionStorage.removeItem(TOKEN_KEY);
    location.href = "/signin?next=" + encodeURIComponent(location.pathname);
    throw new ApiError(401, "signed out");
  }
  if (!answer.ok) {
    let detail = answer.statusText;
    try {
      const data = await answer.json();
      detail = typeof data.detail === "string" ? data.detail
        : (data.detail || []).map((d) => (d.loc || []).slice(1).join(".") + ": " + d.msg).join("; ");
    } catch (_) { /* not JSON */ }
    throw new ApiError(answer.status, detail);
  }
  if (answer.status === 204) return null;
  return answer.json();
}

// el("div", {class: "x", onclick: fn}, "text", child, ...)
function el(tag, attrs, ...children) {
  const node = document.createElement(tag);
  for (const [key, value] of Object.entries(attrs || {})) {
    if (value === null || value === undefined || value === false) continue;
    if (key.startsWith("on")) node.addEventListener(key.slice(2), value);
    else if (key === "dataset") Object.assign(node.dataset, value);
    else node.setAttribute(key, value === true ? "" : value);
  }
  for (const child of children.flat(Infinity)) {
    if (child === null || child === undefined || child === false) continue;
    node.append(child instanceof Node ? child : document.createTextNode(String(child)));
  }
  return node;
}

function clear(node, ...children) { node.replaceChildren(...children.flat(Infinity).filter((c) => c != null)); return node; }

function fmtDate(iso) {
  if (!iso) return "—";
  const d = new Date(iso.endsWith("Z") || iso.includes("+") ? iso : iso + "Z");
  return d.toLocaleString(undefined, { weekday: "short", day: "numeric", month: "short",
    year: "numeric", hour: "2-digit", minute: "2-digit" });
}

function fmtDuration(seconds) {
  if (seconds === null || seconds === undefined) return "—";
  const s = Math.round(seconds);
  const m = Math.floor(s / 60);
  return m ? `${m} min ${String(s % 60).padStart(2, "0")} s` : `${s} s`;
}

function fmtAgo(seconds) {
  if (seconds === null || seconds === undefined) return "never";
  if (seconds < 1.5) return "now";
  if (seconds < 90) return `${Math.round(seconds)} s ago`;
  if (seconds < 5400) return `${Math.round(seconds / 60)} min ago`;
  return `${Math.round(seconds / 3600)} h ago`;
}

function fmtPercent(fraction, digits = 1) {
  return fraction === null || fraction === undefined ? "—" : (fraction * 100).toFixed(digits) + " %";
}

function exerciseLabel(name) {
  return name.replace(/_/g, " ").replace(/^./, (c) => c.toUpperCase());
}

function qualityBadge(quality) {
  const text = { good: "Good data", fair: "Fair data", poor: "Poor data" }[quality.grade] || quality.grade;
  const why = [];
  if (quality.worst_lost_fraction !== null && quality.worst_lost_fraction !== undefined)
    why.push(`${fmtPercent(quality.worst_lost_fraction)} samples lost (worst sensor)`);
  if (quality.missing_sensors && quality.missing_sensors.length)
    why.push("no data from " + quality.missing_sensors.join(", "));
  if (quality.calibration_warnings && quality.calibration_warnings.length)
    why.push(`${quality.calibration_warnings.length} calibration warning(s)`);
  return el("span", { class: "badge q-" + quality.grade, title: why.join("; ") }, text);
}

function statusBadge(status) {
  const labels = { live: "● Live", interrupted: "Interrupted", closed: "Finished" };
  return el("span", { class: "badge s-" + status }, labels[status] || status);
}

// An angle [deg] for people: whole degrees, never "-0°"; "—" when unknown.
function deg(value) {
  if (value === null || value === undefined || !Number.isFinite(value)) return "—";
  return String(Math.round(value) + 0) + "°";  // + 0 turns -0 into 0
}

// Text from the server with "-0" (a rounded small negative number) written as "0".
function noNegativeZero(text) {
  return String(text).replace(/(^|[^\d.])-0(?![\d.])/g, (_, before) => before + "0");
}

// A bar: the normal range as a grey band, the measured range as a coloured bar.
function romBar(min, max, normalMin, normalMax) {
  const lo = Math.min(normalMin ?? min, min) - 10;
  const hi = Math.max(normalMax ?? max, max) + 10;
  const x = (v) => ((v - lo) / (hi - lo)) * 100;
  const bar = el("div", { class: "rombar", title: `measured ${deg(min)} to ${deg(max)}`
    + (normalMin !== null && normalMin !== undefined ? `; normal ${normalMin}° to ${normalMax}°` : "") });
  if (normalMin !== null && normalMin !== undefined)
    bar.append(el("div", { class: "normal", style: `left:${x(normalMin)}%;width:${x(normalMax) - x(normalMin)}%` }));
  bar.append(el("div", { class: "measured", style: `left:${x(min)}%;width:${Math.max(x(max) - x(min), 0.8)}%` }));
  if (lo < 0 && hi > 0) bar.append(el("div", { class: "zero", style: `left:${x(0)}%` }));
  return bar;
}

function percentClass(p) {
  if (p === null || p === undefined) return "";
  return p >= 80 ? "pct-good" : p >= 50 ? "pct-mid" : "pct-low";
}

const DISCLAIMER = "armtrack supports therapy: it helps you follow a patient's exercises and "
  + "range of motion. It is not a diagnostic device; do not use its numbers to diagnose.";

// The page frame: top bar with breadcrumbs and sign-out, and the disclaimer footer.
function frame(crumbs) {
  requireSignIn();
  const bar = el("header", { class: "topbar" },
    el("a", { class: "brand", href: "/patients" }, el("span", { class: "logo" }, "◠"), "armtrack"),
    el("nav", { class: "crumbs" }, crumbs.map((c, i) => [
      i ? el("span", { class: "sep" }, "›") : null,
      c.href ? el("a", { href: c.href }, c.text) : el("span", { id: c.id || null }, c.text)])),
    el("div", { class: "who" }, el("span", {}, sessionStorage.getItem(USER_KEY) || ""),
      el("button", { class: "link", onclick: signOut }, "Sign out")));
  document.body.prepend(bar);
  document.body.append(el("footer", { class: "disclaimer", id: "disclaimer" }, DISCLAIMER));
}

function showError(where, error) {
  const box = el("div", { class: "error" }, String(error.message || error));
  where.prepend(box);
  setTimeout(() => box.remove(), 8000);
}

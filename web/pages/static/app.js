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

// Signing out ends the sign-in on the server (its token stops working, its live feeds
// close) and in the tabs it was handed to, not only in this tab.
// The request outlives the page (keepalive): the sign-in page opens at once.
function signOut() {
  const ended = token();
  sessionStorage.removeItem(TOKEN_KEY);
  sessionStorage.removeItem(USER_KEY);
  if (ended) {
    if (authChannel) authChannel.postMessage({ kind: "signed-out", token: ended });
    fetch("/api/auth/signout", { method: "POST", keepalive: true,
      headers: { Authorization: "Bearer " + ended } }).catch(() => { /* offline */ });
  }
  location.href = "/signin";
}

// A tab opened from a signed-in tab (Ctrl-click, middle click) has no token of its own:
// it asks the other tabs of this origin on a BroadcastChannel (same-origin only, nothing
// written to cookies or localStorage), and a signed-in tab answers with its token.
const AUTH_CHANNEL = "armtrack.auth";
let authChannel = null;
try { authChannel = new BroadcastChannel(AUTH_CHANNEL); } catch (_) { authChannel = null; }
// A tab answers only just after the therapist opened a link in a new tab from it
// (Ctrl/⌘/Shift-click or middle click), once: not to any page that asks at any time.
const HANDOFF_WINDOW_MS = 10000;
let openedNewTabAt = -Infinity;
function noteNewTab(event) {
  if (event.target.closest && event.target.closest("a[href], tr.clickable")
      && (event.ctrlKey || event.metaKey || event.shiftKey || event.button === 1)) {
    openedNewTabAt = Date.now();
  }
}
document.addEventListener("click", noteNewTab, true);
document.addEventListener("auxclick", noteNewTab, true);
if (authChannel) {
  authChannel.onmessage = (event) => {
    if (event.data && event.data.kind === "signed-out" && event.data.token && event.data.token === token()) {
      sessionStorage.removeItem(TOKEN_KEY);
      sessionStorage.removeItem(USER_KEY);
      location.href = "/signin";
      return;
    }
    if (event.data && event.data.kind === "need-token" && token()
        && Date.now() - openedNewTabAt < HANDOFF_WINDOW_MS) {
      openedNewTabAt = -Infinity;
      authChannel.postMessage({ kind: "token", to: event.data.from, token: token(),
        user: sessionStorage.getItem(USER_KEY) || "" });
    }
  };
}
const TAB_ID = Math.random().toString(36).slice(2);
const HANDOFF_WAIT_MS = 1500;

let signedIn = null;
function requireSignIn() {
  if (signedIn) return signedIn;
  if (token()) return (signedIn = Promise.resolve());
  signedIn = new Promise((resolve) => {
    const giveUp = () => {
      location.href = "/signin?next=" + encodeURIComponent(location.pathname + location.search);
    };
    if (!authChannel) { giveUp(); return; }
    const timer = setTimeout(giveUp, HANDOFF_WAIT_MS);
    const listen = (event) => {
      if (event.data && event.data.kind === "token" && event.data.to === TAB_ID && event.data.token) {
        clearTimeout(timer);
        authChannel.removeEventListener("message", listen);
        sessionStorage.setItem(TOKEN_KEY, event.data.token);
        if (event.data.user) sessionStorage.setItem(USER_KEY, event.data.user);
        const who = document.getElementById("who-name");
        if (who && !who.textContent) who.textContent = event.data.user;
        resolve();
      }
    };
    authChannel.addEventListener("message", listen);
    authChannel.postMessage({ kind: "need-token", from: TAB_ID });
  });
  return signedIn;
}

class ApiError extends Error {
  constructor(status, detail) { super(detail); this.status = status; }
}

// The clinic (name, address, IANA time zone): pages show times in its zone. Loaded once
// per page, before any other API answer is drawn.
let CLINIC = null;
let clinicPromise = null;
function clinic() {
  if (!clinicPromise) {
    clinicPromise = requireSignIn().then(() => fetch("/api/clinic", { headers: { Authorization: "Bearer " + token() } })
      .then((r) => (r.ok ? r.json() : null)).catch(() => null)
      .then((c) => { CLINIC = c; return c; }));
  }
  return clinicPromise;
}

// The answer to `path` once it is ok: a GET the server is too busy for asked again when
// it says, a 401 to the sign-in page, any other refusal an ApiError in the server's words.
async function fetchOk(path, options = {}) {
  await requireSignIn();
  if (path !== "/api/clinic") await clinic();
  const headers = Object.assign({ Authorization: "Bearer " + token() }, options.headers || {});
  let body = options.body;
  if (body !== undefined && !(body instanceof FormData) && typeof body !== "string") {
    body = JSON.stringify(body);
    headers["Content-Type"] = "application/json";
  }
  const method = options.method || "GET";
  let answer = await fetch(path, { method, headers, body });
  // A read the server is too busy for (429/503 with Retry-After: e.g. the account's other
  // tabs have 4 reports being made, server/builds.py) is asked again when it says, up to
  // 3 times, so the card fills instead of showing 'ask again in 5 s' nobody can act on.
  for (let again = 0; again < 3 && method === "GET" && (answer.status === 429 || answer.status === 503); again += 1) {
    const wait = Number(answer.headers.get("Retry-After"));
    if (!(wait > 0 && wait <= 30)) break;
    await new Promise((done) => setTimeout(done, wait * 1000));
    answer = await fetch(path, { method, headers, body });
  }
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
  return answer;
}

async function api(path, options = {}) {
  const answer = await fetchOk(path, options);
  if (answer.status === 204) return null;
  return answer.json();
}

// Save what `path` answers as `filename` (a report, a CSV: fetched with the therapist's
// token); a refusal shown in `where` in the server's words, nothing saved; an ended
// sign-in goes to the sign-in page as any request does. The pages' one download.
async function saveFile(path, filename, where) {
  try {
    const answer = await fetchOk(path);
    const url = URL.createObjectURL(await answer.blob());
    const a = el("a", { href: url, download: filename });
    document.body.append(a); a.click(); a.remove();
    setTimeout(() => URL.revokeObjectURL(url), 10000);
  } catch (error) {
    if (error.status !== 401) showError(where, new Error(`${filename} was not made: ${error.message}`));
  }
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

// A table row that opens ``url``: a click on its own link is the link's (a Ctrl-click
// opens a new tab, signed in by the token hand-off above); elsewhere in the row, Ctrl/⌘
// opens a new tab too.
function rowLink(url) {
  return (event) => {
    if (event.target.closest("a, button, input, select")) return;
    if (event.ctrlKey || event.metaKey) { openedNewTabAt = Date.now(); window.open(url, "_blank"); }
    else location.href = url;
  };
}

function clear(node, ...children) { node.replaceChildren(...children.flat(Infinity).filter((c) => c != null)); return node; }

// The clinic's time zone, and whether this browser is elsewhere (then times say their zone).
function clinicZone() {
  const zone = CLINIC && CLINIC.time_zone;
  if (!zone) return { timeZone: undefined, elsewhere: false };
  let here;
  try { here = Intl.DateTimeFormat().resolvedOptions().timeZone; } catch (_) { here = null; }
  return { timeZone: zone, elsewhere: here !== zone };
}

// A moment from the API (always with its zone; UTC if a text lacks one) as a Date.
function parseMoment(iso) {
  return new Date(/[zZ]|[+-]\d\d:?\d\d$/.test(iso) ? iso : iso + "Z");
}

// A moment from the API in the clinic's local time and clock; ``seconds``: with its seconds.
function fmtDate(iso, options = {}) {
  if (!iso) return "—";
  const d = parseMoment(iso);
  const { timeZone, elsewhere } = clinicZone();
  const parts = options.dateOnly ? { day: "numeric", month: "short", year: "numeric" }
    : { weekday: "short", day: "numeric", month: "short", year: "numeric", hour: "2-digit", minute: "2-digit" };
  if (options.seconds && !options.dateOnly) parts.second = "2-digit";
  // the clinic's clock (ARMTRACK_CLINIC_CLOCK), as its reports write times: not the browser's
  if (!options.dateOnly && CLINIC && CLINIC.clock) parts.hourCycle = CLINIC.clock === "12h" ? "h12" : "h23";
  if (timeZone) parts.timeZone = timeZone;
  if (elsewhere && !options.dateOnly) parts.timeZoneName = "short";
  return d.toLocaleString(undefined, parts);
}

// Sessions' start times (``starts``: ISO moments) as a list writes them: to the minute,
// and with the seconds where two or more share a minute, so that sessions started 35 s
// apart (a kit restarted, a stream beside an upload) read apart; seconds on every row
// would be noise a therapist reads past. (Zones are whole minutes: a minute is the same
// in UTC and in the clinic's time.)
function fmtSessionTimes(starts) {
  const minute = (iso) => Math.floor(parseMoment(iso).getTime() / 60000);
  const count = new Map();
  for (const iso of starts) if (iso) count.set(minute(iso), (count.get(minute(iso)) || 0) + 1);
  return starts.map((iso) => fmtDate(iso, { seconds: !!iso && count.get(minute(iso)) > 1 }));
}

// A calendar date ("2026-11-16": a birth date, a program's start) as the pages write dates
// ("Nov 16, 2026"); read at noon UTC so that no clinic's time zone moves it a day.
function fmtDay(date) {
  return date ? fmtDate(date + "T12:00:00Z", { dateOnly: true }) : "—";
}

// Today's date on this computer, as a date field takes it ("2026-12-03"): the latest date
// of birth the forms take (the server's bound: server/api/schemas.py EARLIEST_BIRTH, today).
function todayIso() {
  const d = new Date();
  return `${d.getFullYear()}-${String(d.getMonth() + 1).padStart(2, "0")}-${String(d.getDate()).padStart(2, "0")}`;
}

// A duration [s]: "35 s", "2 min 05 s", and from an hour on "1 h 05 min" (to the minute:
// "65 min 17 s" had the reader divide). server/reports/words.py duration_words says it alike.
function fmtDuration(seconds) {
  if (seconds === null || seconds === undefined) return "—";
  const s = Math.round(seconds);
  const m = Math.floor(s / 60);
  if (m >= 60) return `${Math.floor(m / 60)} h ${String(m % 60).padStart(2, "0")} min`;
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

// A session's exercises' names in words, in their order; where the kit marked the same
// exercise more than once, each set says which it is ("Elbow flexion — set 1", "— set 2"),
// as the PDF does (server/reports/words.py set_words). The report's names stay the kit's.
function exerciseNames(exercises) {
  const total = new Map();
  for (const e of exercises) total.set(e.name, (total.get(e.name) || 0) + 1);
  const seen = new Map();
  return exercises.map((e) => {
    const name = e.name.split(" + ").map(exerciseLabel).join(" + ");
    if (total.get(e.name) < 2) return name;
    seen.set(e.name, (seen.get(e.name) || 0) + 1);
    return `${name} — set ${seen.get(e.name)}`;
  });
}

// A set the kit began and never ended in a closed session (summary's `unfinished`): the
// patient left it part way, "stopped after 4 of 10" (of the set's asked repetitions).
function stoppedWords(e) {
  if (typeof e.repetitions !== "number") return "stopped part way";
  return typeof e.asked === "number" ? `stopped after ${e.repetitions} of ${e.asked}`
    : `stopped after ${e.repetitions}`;
}

// A set the kit marked in which the report counted no repetition (started and ended at
// once, or nothing done): shown, as empty, not as an exercise "× 0".
function emptySet(e) {
  return e.source === "marks" && e.repetitions === 0;
}

// A session's exercises as chips say them: each one's name (its set where there are
// several), with the repetitions the report found; an empty set says so.
function exerciseChipTexts(exercises) {
  const names = exerciseNames(exercises);
  return exercises.map((e, k) => e.unfinished ? `${names[k]}: ${stoppedWords(e)}`
    : emptySet(e) ? `${names[k]}: empty (no repetition)`
    : typeof e.repetitions === "number" && (e.source !== "detected" || e.repetitions)
      ? `${names[k]} × ${e.repetitions}` : names[k]);
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
  if (quality.short) why.push("cut short: too little data to judge the exercise");
  return el("span", { class: "badge q-" + quality.grade, title: why.join("; ") }, text);
}

// The server stopped a kit's stream (a session's stopped_by_server, docs/extensions/
// stream-stopped.md): when, and the server's words for the therapist. Text only.
// The last refused message's reason quotes the kit's own values: shown apart, as the kit's.
function stoppedNote(stop, heading = "h2") {
  return [el(heading, {}, `The server stopped the kit's stream · ${fmtDate(stop.at)}`),
    el("p", {}, stop.message),
    el("p", { class: "small muted" }, "The server's answer to the kit's last refused message (quoting what the kit sent): ",
      el("code", { class: "kit-text" }, stop.last_refused))];
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

// api.md's percent of normal: how far the range reached on the side it moved most, as a
// share of the normal range on that side of zero (flexion to 150° of −60…180° → 83 %).
function percentOfNormal(min, max, normalMin, normalMax) {
  if (normalMin === null || normalMin === undefined || normalMax === null || normalMax === undefined) return null;
  const shares = [];
  if (normalMax > 0) shares.push(max / normalMax);
  if (normalMin < 0) shares.push(min / normalMin);
  return shares.length ? Math.max(0, ...shares) * 100 : null;
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
    el("div", { class: "who" }, el("a", { id: "who-name", href: "/account", title: "Your account: name and password" },
      sessionStorage.getItem(USER_KEY) || ""),
      el("button", { class: "link", onclick: signOut }, "Sign out")));
  document.body.prepend(bar);
  clinic().then((c) => {
    if (c && c.name) bar.querySelector(".brand").append(el("span", { class: "clinic-name", id: "clinic-name" }, c.name));
  });
  api("/api/me").then((me) => {
    document.getElementById("who-name").textContent = me.full_name || me.username;
    bar.querySelector(".who").prepend(el("nav", { class: "nav-links" },
      el("a", { href: "/audit", id: "nav-audit" }, "Audit log"),
      me.is_admin ? el("a", { href: "/admin", id: "nav-admin" }, "Clinic accounts") : null));
    window.ME = me;
    document.dispatchEvent(new CustomEvent("armtrack:me", { detail: me }));
  }).catch(() => {});
  document.body.append(el("footer", { class: "disclaimer", id: "disclaimer" }, DISCLAIMER));
}

function showError(where, error) {
  const box = el("div", { class: "error" }, String(error.message || error));
  where.prepend(box);
  setTimeout(() => box.remove(), 8000);
}

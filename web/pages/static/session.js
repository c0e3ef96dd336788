// The session page: the 3D view (live or replay) beside the session's numbers.
// Live: angles from /ws/live, sensors and calibration from GET /api/patients/{id}/live.
// Finished: the range of motion, calibration, quality and exports from the summary.
"use strict";

const sessionId = Number(location.pathname.split("/")[2]);
const POSE_NAMES = { npose: "N-pose", tpose: "T-pose" };
frame([{ text: "Patients", href: "/patients" }, { text: "…", id: "crumb-patient" },
  { text: "Session " + sessionId }]);

let session = null;
let patient = null;
let normals = {};

// ---------------------------------------------------------------- the 3D view
// A viewer grant works once, so a view whose connection closed (the server restarted,
// the network dropped) cannot come back by itself. Every VIEWER_CHECK_MS the page asks the
// grant's state; once it is closed or unknown, the view reloads with a new grant, and
// "3D view reconnecting…" shows over it meanwhile (also while the server is unreachable).
const VIEWER_CHECK_MS = 2000;
const VIEWER_RETRY_MAX_MS = 30000;
let viewerMode = null;
let viewerGrant = null;
let viewerTimer = null;
let viewerRetries = 0;
let viewerScale = 1;  // how much the page scales the view down (viewer_fit.js)
const VIEWER_RESCALE = 1.25;  // a view scaled by this much more or less is asked for anew

function viewerNote(text) {
  const note = document.getElementById("viewer-note");
  note.textContent = text || "";
  note.hidden = !text;
}

function viewerCheckLater(ms) {
  clearTimeout(viewerTimer);
  viewerTimer = setTimeout(checkViewer, ms);
}

function retryDelay() {
  return Math.min(VIEWER_CHECK_MS * 2 ** Math.max(viewerRetries - 1, 0), VIEWER_RETRY_MAX_MS);
}

async function openViewer(mode, reconnecting = false) {
  viewerMode = mode;
  clearTimeout(viewerTimer);
  const box = document.getElementById("viewer");
  document.getElementById("viewer-title").textContent =
    mode === "live" ? "Live 3D arm" : "Replay";
  if (!reconnecting) {
    viewerRetries = 0;
    viewerNote(null);
    clear(box, el("div", { class: "placeholder" }, "Opening the 3D view…"));
  }
  let grant;
  try {
    viewerScale = Math.max(viewerFitScale(box), 0.2);  // its labels grow to read as large
    grant = await api("/api/viewer", { method: "POST", body: {
      patient_id: session.patient_id, session_id: mode === "live" ? null : session.id,
      display_scale: viewerScale } });
  } catch (error) {
    if (reconnecting) {  // the server may be restarting: try again later
      viewerRetries += 1;
      viewerTimer = setTimeout(() => openViewer(mode, true), retryDelay());
      return;
    }
    viewerGrant = null;
    clear(box, el("div", { class: "placeholder", id: "viewer-error" },
      "The 3D view is not available: " + error.message));
    return;
  }
  viewerGrant = grant;
  clear(box, el("iframe", { src: grant.url, id: "viewer-frame", title: "3D view of the arm",
    allow: "fullscreen" }));
  viewerCheckLater(VIEWER_CHECK_MS);
}

async function checkViewer() {
  const grant = viewerGrant;
  if (!grant) return;
  let state;
  try {
    state = (await api(grant.state_url)).state;
  } catch (error) {
    state = error.status === 404 ? "closed" : "unknown";  // unknown: no answer
  }
  if (grant !== viewerGrant) return;  // replaced meanwhile
  if (state === "closed") {  // over, or unknown to the server: a new grant
    viewerNote("3D view reconnecting…");
    viewerRetries += 1;
    viewerTimer = setTimeout(() => openViewer(viewerMode, true),
      viewerRetries > 1 ? retryDelay() : 0);
    return;
  }
  if (state === "open") {
    viewerRetries = 0;
    viewerNote(null);
  } else if (state === "unknown") {
    viewerNote("3D view reconnecting…");
  }
  viewerCheckLater(VIEWER_CHECK_MS);
}
document.getElementById("reload-viewer").addEventListener("click", () => openViewer(viewerMode));
// the view's box changed size a lot (a phone turned): a view with labels sized anew
let rescaleTimer = null;
document.getElementById("viewer").addEventListener("viewer-scale", (event) => {
  clearTimeout(rescaleTimer);
  if (!viewerGrant || Math.abs(Math.log(event.detail / viewerScale)) < Math.log(VIEWER_RESCALE)) return;
  rescaleTimer = setTimeout(() => viewerGrant && openViewer(viewerMode), 1000);
});

// ---------------------------------------------------------------- live
let lastPose = null;
let poseDirty = false;
let liveStatus = null;
let socket = null;
let ended = false;

function liveAnglesCard() {
  const card = document.getElementById("angles-card");
  clear(card,
    el("div", { class: "row", style: "justify-content:space-between;align-items:center" },
      el("h2", { style: "margin:0" }, "Joint angles now"),
      el("span", { class: "muted small", id: "pose-age" }, "waiting for the first estimate…")),
    el("table", { id: "angles-table", style: "margin-top:6px" },
      el("thead", {}, el("tr", {}, el("th", {}, "Angle"), el("th", { class: "num" }, "Now"),
        el("th", {}, "Range so far vs normal"), el("th", { class: "num" }, "% normal"))),
      el("tbody", {}, measuredAngles().map((name) => el("tr", { dataset: { angle: name } },
        el("td", { class: "name" }, ANGLE_LABELS[name]),
        el("td", { class: "now" }, "—"), el("td", { class: "bar" }), el("td", { class: "num pct" }, "")))),
    ),
    el("div", { class: "legend" }, el("span", {}, el("i", { style: "background:#d6dde5" }), "normal range (AAOS)"),
      el("span", {}, el("i", { style: "background:var(--accent)" }), "range so far"),
      el("span", {}, el("i", { style: "background:#e8590c;width:4px" }), "now"),
      el("span", {}, "calibration poses are not counted")),
    assumptionsNote());
}

// the angles this session's kit measures, and what they assume (docs/extensions/measured-angles.md)
function measuredAngles() {
  const measured = session && session.measured_angles;
  return measured ? ANGLES.filter((name) => measured.includes(name)) : ANGLES;
}
function assumptionsNote() {
  const assumed = Object.values((session && session.assumptions) || {});
  return assumed.length ? el("p", { class: "muted small", id: "assumptions" }, "Assumes " + assumed.join("; ") + ".") : null;
}

function renderPose() {
  if (!poseDirty || !lastPose) return;
  poseDirty = false;
  const pose = lastPose;
  for (const name of ANGLES) {
    const row = document.querySelector(`#angles-table tr[data-angle="${name}"]`);
    if (!row) continue;
    const now = pose.angles_deg[name];
    row.querySelector(".now").textContent = deg(now);
    const rom = (pose.rom_deg || {})[name];
    const normal = normals[name];
    const bar = row.querySelector(".bar");
    const pct = row.querySelector(".pct");
    if (rom) {
      const b = romBar(rom.min, rom.max, normal ? normal[0] : null, normal ? normal[1] : null);
      if (now !== null && now !== undefined) {
        const lo = Math.min(normal ? normal[0] : rom.min, rom.min) - 10;
        const hi = Math.max(normal ? normal[1] : rom.max, rom.max) + 10;
        b.append(el("div", { class: "now", style: `left:${Math.min(100, Math.max(0, (now - lo) / (hi - lo) * 100))}%` }));
      }
      clear(bar, b);
      const p = normal ? percentOfNormal(rom.min, rom.max, normal[0], normal[1]) : null;
      pct.textContent = p === null ? "" : Math.round(p) + " %";
      pct.className = "num pct " + percentClass(p);
      row.classList.toggle("moving", rom.range >= 10);
      row.classList.toggle("faint", rom.range < 10);
    }
  }
  document.getElementById("pose-age").textContent =
    `stream time ${pose.t.toFixed(1)} s · delay ${Math.round((pose.latency_s || 0) * 1000)} ms`;
}
setInterval(renderPose, 100);

function connectLive() {
  const scheme = location.protocol === "https:" ? "wss:" : "ws:";
  socket = new WebSocket(`${scheme}//${location.host}/ws/live?patient=${session.patient_id}&token=${encodeURIComponent(token())}`);
  socket.onmessage = (event) => {
    const update = JSON.parse(event.data);
    if (update.kind === "pose" && update.session_id === session.id) {
      lastPose = update;
      poseDirty = true;
    } else if (update.kind === "session" && update.session_id === session.id) {
      statusChanged(update.status);
      if (update.status === "closed") finishLive();
    } else if (update.kind === "error") {
      showError(document.getElementById("angles-card"), update.reason);
    }
  };
  // 4429: the account holds all its live feeds (the error update above said so): later
  socket.onclose = (event) => { if (!ended) setTimeout(connectLive, event.code === 4429 ? 10000 : 1000); };
}

// One poll at a time, and never an answer older (by the stream's own clock) than the one
// shown: a busy browser whose polls bunch up must not show "relax" in the middle of a pose.
let pollInFlight = false;
let shownStreamT = -Infinity;

async function pollLive() {
  if (pollInFlight) return;
  pollInFlight = true;
  let status;
  try {
    status = await api(`/api/patients/${session.patient_id}/live`);
  } catch (_) { return; } finally { pollInFlight = false; }
  const streamT = status.calibration ? status.calibration.stream_time_s : null;
  if (status.session && status.session.id === session.id && streamT !== null && streamT !== undefined) {
    if (streamT < shownStreamT) return;  // older than what is shown
    shownStreamT = streamT;
  }
  liveStatus = status;
  normals = liveStatus.normal_ranges || normals;
  if (liveStatus.session && liveStatus.session.id === session.id) {
    if (notTheLatest) {  // its kit came back to it: the live view again
      notTheLatest = false;
      document.getElementById("reload-viewer").hidden = false;
      openViewer("live");
    }
    if (liveStatus.session.status !== session.status) statusChanged(liveStatus.session.status);
    showStopped(liveStatus.session.stopped_by_server);
    document.getElementById("sensors-card").hidden = false;
    clear(document.getElementById("sensors"), storageNote(liveStatus), sensorTable(liveStatus));
    renderCalibration(liveStatus);
    LiveFollow.live(liveStatus);
  } else if (!liveStatus.session || liveStatus.session.id !== session.id) {
    // a newer session, or this one was closed
    LiveFollow.newer(liveStatus);
    const fresh = await api(`/api/sessions/${session.id}`);
    if (fresh.status === "closed") finishLive();
    else if (fresh.status !== "live") interruptedBehindALaterOne(fresh);
  }
}

/** This session is interrupted (or stopped) and the patient's live status names a later
 * one of theirs: the live feed has nothing of this session, and the live 3D view shows the
 * patient's latest session, not this one. The page says it is interrupted and offers to
 * close it (as when it is the latest), and shows no other session's arm. */
let notTheLatest = false;
function interruptedBehindALaterOne(fresh) {
  if (session.status !== fresh.status) statusChanged(fresh.status);
  showStopped(fresh.stopped_by_server);
  renderCalibration({ calibration: null, posesUnknown: true });
  document.getElementById("pose-age").textContent = "no kit streams into this session";
  if (notTheLatest) return;
  notTheLatest = true;
  clearTimeout(viewerTimer);
  viewerGrant = null;
  document.getElementById("viewer-title").textContent = "3D arm";
  document.getElementById("reload-viewer").hidden = true;  // it would open the latest session's
  clear(document.getElementById("viewer"), el("div", { class: "placeholder", id: "viewer-not-live" },
    "This session's kit is not connected, and a later session of the patient came after it. "
    + "Close this session to estimate what was recorded: its replay opens then."));
}

// Why a finished session has no calibration pose: the kit skipped them, or (carried-on/1,
// docs/extensions/carried-on.md) the session carries on the kit's earlier one, full or
// closed while it streamed, where the patient held them.
function noPosesWhy() {
  const earlier = session && session.carries_on;
  if (earlier == null) {
    return el("p", { style: "margin:4px 0", id: "no-poses" }, "No calibration pose: the default sensor mounting was used.");
  }
  return el("p", { style: "margin:4px 0", id: "no-poses" },
    "No calibration pose: this session carries on ",
    el("a", { href: `/sessions/${earlier}` }, `session ${earlier}`),
    " of the same kit, where the patient held the poses (that one was full, or closed while the kit sent). "
    + "They are not carried over: each session's orientation filters start anew, and only the poses tell how the sensor sits on the arm and which way the arm faces.");
}

// ---------------------------------------------------------------- calibration guidance
let spokenPhase = null;
let speak = false;

function calibrationState(live) {
  const cal = live.calibration || { poses: [], holding: null, instructions: {} };
  const estimating = live.estimating || (lastPose && lastPose.session_id === session.id);
  const warnings = [];
  for (const p of cal.poses) for (const w of p.warnings || []) warnings.push(w);
  for (const w of (lastPose && lastPose.warnings) || []) warnings.push(w);
  // the session's state first: a pose whose hold began before the kit was cut off
  // (its end mark never came) is not being held; the box said "Hold the N-pose ·
  // Still ✓" on and on and hid that the stream had stopped
  if (session.status !== "live" && session.stopped_by_server) {
    return { phase: "stopped", kind: "warn", icon: "■", title: "The server stopped the kit's stream",
      how: "The kit will not reconnect by itself: see why above; the data so far are stored. "
        + "Close the session to estimate what was recorded.", closable: true, poses: cal.poses, warnings };
  }
  if (session.status !== "live") {
    // a phone records on offline and sends it all when back: closing at once would end
    // the patient's session mid-set (found by a new user after a 12-s outage)
    const how = session.metadata.device === "phone kit"
      ? "The patient's phone keeps recording while offline and sends it all when its "
        + "connection is back, so the patient may still be exercising: wait a few minutes "
        + "before closing. The data so far are stored. If the patient has stopped, close "
        + "the session to estimate what was recorded."
      : "The kit may reconnect and resume; the data so far are stored. If the patient has "
        + "stopped, close the session to estimate what was recorded.";
    return { phase: "interrupted", kind: "warn", icon: "‖", title: "The stream is interrupted",
      how, closable: true, poses: cal.poses, warnings };
  }
  if (cal.holding) {
    const p = cal.holding;
    const name = POSE_NAMES[p.name];
    let still;
    if (p.still === undefined) still = null;
    else still = p.still;
    // a kit with a trunk sensor: the server's guide says whether the hold has pinned the
    // trunk's lean through a sway yet (live_status.trunk_guide), in words for the therapist
    const trunk = p.trunk || null;
    let stillText = still === null ? "Checking…" : still ? `Still ✓ — keep holding (${p.held_s.toFixed(0)} s)`
      : "Moving — please hold still";
    if (trunk && still !== false) {
      stillText = trunk.pinned ? `Still ✓ — ${trunk.message} (${p.held_s.toFixed(0)} s)`
        : `${trunk.message} (${p.held_s.toFixed(0)} s)`;
    }
    return { phase: "hold:" + p.name, kind: "holding", icon: p.name === "npose" ? "N" : "T",
      title: `Hold the ${name}`, how: cal.instructions[p.name], still, stillText,
      keepHolding: Boolean(trunk && trunk.keep_holding), trunkSteady: Boolean(trunk && trunk.pinned),
      poses: cal.poses, warnings };
  }
  if (estimating) {
    // a sensor that stopped sending mid-session (docs/extensions/sensor-stopped.md): its
    // angles are not shown, which is what the title says (not "less accurate")
    const stopped = Object.keys((lastPose && lastPose.session_id === session.id
      && lastPose.stopped_sensors) || {}).map((n) => (SENSOR_LABELS[n] || n).toLowerCase());
    return { phase: "done", kind: warnings.length ? "warn" : "done", icon: warnings.length ? "!" : "✓",
      title: stopped.length ? `Live angles without the ${stopped.join(" and ")} sensor`
          + `${stopped.length > 1 ? "s: they" : ": it"} stopped sending`
        : warnings.length ? "Calibrated, with warnings — the angles may be less accurate"
        : "Calibrated — live angles are running",
      how: cal.poses.length ? null : session && session.carries_on != null
        ? `No calibration pose in this session: it carries on session ${session.carries_on}, where the patient held the poses; the default sensor mounting is used here.`
        : "No calibration pose was made: the default sensor mounting is used.",
      poses: cal.poses, warnings, patientTitle: "Well done", patientHow: "You can start the exercise." };
  }
  if (cal.poses.length) {
    const last = cal.poses[cal.poses.length - 1];
    const next = last.name === "npose" ? "T-pose" : null;
    return { phase: "between:" + last.name, kind: "waiting", icon: "…",
      title: `${POSE_NAMES[last.name]} done${last.still ? " ✓" : " — it was not still"}`
        + (next ? `. Next: the ${next}` : ". Calibrating…"),
      how: next ? "Relax the arm and wait for the kit's signal for the T-pose." : "The live angles start in a moment.",
      patientTitle: last.still ? "Good — relax" : "Relax", poses: cal.poses, warnings };
  }
  return { phase: "waiting", kind: "waiting", icon: "…", title: "Waiting for calibration",
    how: "The kit starts with the N-pose: stand tall, arm hanging by the side, palm facing the thigh.",
    poses: cal.poses, warnings };
}

let calibrationParts = null;

/** An interrupted (or stopped) session closed from its own page, as from the patient page's
 * "Interrupted sessions" card: estimated in the background; the page follows the close. */
async function closeSession(event) {
  const button = event.currentTarget;
  button.disabled = true;
  try {
    await api(`/api/sessions/${session.id}/close?wait=false`, { method: "POST" });
    finishLive();
  } catch (error) {
    button.disabled = false;
    showError(document.getElementById("calibration"), error);
  }
}

function calibrationShell() {
  const parts = {
    icon: el("div", { class: "icon" }), title: el("div", { class: "title" }),
    how: el("div", { class: "how" }), still: el("div", { class: "still" }),
    steps: el("div", { class: "steps" }), warnings: el("ul", { class: "warnings", id: "calibration-warnings" }),
    close: el("button", { class: "secondary", id: "close-session", hidden: "", onclick: closeSession },
      "Close and estimate"),
  };
  parts.box = el("div", { class: "calib", id: "calibration-box" }, parts.icon,
    el("div", { class: "what" }, parts.title, parts.how, parts.still, parts.steps, parts.warnings,
      el("div", {}, parts.close)),
    el("div", { style: "display:flex;flex-direction:column;gap:6px" },
      el("button", { class: "secondary", id: "show-patient", onclick: () => openPatientView() }, "Show to patient"),
      el("label", { style: "flex-direction:row;align-items:center;gap:6px;font-size:13px" },
        el("input", { type: "checkbox", id: "speak", onchange: (e) => { speak = e.target.checked; } }),
        "Read aloud")));
  clear(document.getElementById("calibration"), parts.box);
  return parts;
}

function renderCalibration(live) {
  const s = calibrationState(live);
  const parts = calibrationParts || (calibrationParts = calibrationShell());
  parts.box.className = `calib ${s.kind}${s.still === false ? " moving" : ""}`;
  parts.box.dataset.phase = s.phase;
  parts.icon.textContent = s.icon;
  parts.title.textContent = s.title;
  parts.how.textContent = s.how || "";
  parts.how.hidden = !s.how;
  parts.still.textContent = s.stillText || "";
  parts.still.hidden = !s.stillText;
  parts.still.style.color = s.still === false || s.keepHolding ? "var(--warn)" : "var(--good)";
  parts.still.dataset.trunk = s.keepHolding ? "keep-holding" : s.trunkSteady ? "steady" : "";
  parts.steps.style.display = live.posesUnknown ? "none" : "";  // the live status names another session
  clear(parts.steps, ["npose", "tpose"].map((name) => {
    const p = [...s.poses].reverse().find((q) => q.name === name);
    if (!p) return el("span", { class: "step" }, POSE_NAMES[name] + ": not yet");
    if (p.end === null) {
      return s.closable ? el("span", { class: "step bad" }, POSE_NAMES[name] + ": cut off when the stream stopped")
        : el("span", { class: "step now" }, POSE_NAMES[name] + ": holding now");
    }
    return el("span", { class: "step " + (p.still ? "ok" : "bad") },
      POSE_NAMES[name] + (p.still ? ": still ✓" : ": moved ✗"));
  }));
  clear(parts.warnings, s.warnings.map((w) => el("li", {}, w)));
  parts.warnings.hidden = !s.warnings.length;
  parts.close.hidden = !s.closable;
  // the patient's large view
  document.getElementById("pv-title").textContent = s.patientTitle || s.title;
  document.getElementById("pv-how").textContent = s.patientHow || s.how || "";
  const pvStill = document.getElementById("pv-still");
  pvStill.textContent = s.kind === "holding" ? (s.still === false ? "Hold still…"
    : s.keepHolding ? "Keep holding — sit tall and still…" : s.still ? "Still ✓" : "") : "";
  pvStill.dataset.trunk = s.keepHolding ? "keep-holding" : s.trunkSteady ? "steady" : "";
  pvStill.className = "still " + (s.still === false ? "no" : "ok");
  if (s.phase !== spokenPhase) {
    spokenPhase = s.phase;
    if (speak && window.speechSynthesis) {
      speechSynthesis.cancel();
      speechSynthesis.speak(new SpeechSynthesisUtterance(
        (s.patientTitle || s.title) + ". " + (s.patientHow || s.how || "")));
    }
  }
}

function openPatientView() { document.getElementById("patient-view").classList.add("open"); }
function closePatientView() { document.getElementById("patient-view").classList.remove("open"); }
document.getElementById("close-patient-view").addEventListener("click", closePatientView);
document.addEventListener("keydown", (e) => { if (e.key === "Escape") closePatientView(); });

async function finishLive() {
  if (ended) return;
  ended = true;
  calibrationParts = null;
  if (socket) socket.close();
  document.getElementById("exercise-now")?.remove();
  document.getElementById("sensors-card").hidden = true;  // no kit streams any more
  LiveFollow.watch();
  LiveFollow.history().catch(() => {});
  clear(document.getElementById("calibration"), el("div", { class: "calib done", id: "calibration-box" },
    el("div", { class: "icon" }, "✓"), el("div", { class: "what" },
      el("div", { class: "title" }, "The session has ended"),
      el("div", { class: "how" }, "Estimating the whole session; the replay opens when it is ready."))));
  for (let i = 0; i < 600; i++) {
    const fresh = await api(`/api/sessions/${session.id}`);
    showClosedAfterSilence(fresh.closed_after_silence);
    if (fresh.processed || fresh.processing_error) { location.reload(); return; }
    await new Promise((r) => setTimeout(r, 1000));
  }
}

// ---------------------------------------------------------------- replay / details
function download(path, filename) {
  return el("button", { class: "secondary", onclick: async (event) => {
    const button = event.currentTarget;
    button.disabled = true;
    await saveFile(path, filename, document.getElementById("details-card"));
    button.disabled = false;
  }, dataset: { export: path } }, "⬇ " + filename);
}

function romTable(summary) {
  const names = ANGLES.filter((n) => summary.rom[n]);
  if (!names.length) {
    return el("p", { class: "muted" }, summary.processed ? "No joint moved more than 10° outside the calibration poses."
      : summary.processing_error ? "Not estimated: " + summary.processing_error : "Estimating the session…");
  }
  return [el("table", { id: "rom-table" },
    el("thead", {}, el("tr", {}, el("th", {}, "Angle"), el("th", { class: "num" }, "Min"),
      el("th", { class: "num" }, "Max"), el("th", { class: "num" }, "Range"), el("th", {}, "vs normal"),
      el("th", { class: "num" }, "Normal"), el("th", { class: "num" }, "% normal"))),
    el("tbody", {}, names.map((n) => {
      const r = summary.rom[n];
      return el("tr", { dataset: { angle: n } }, el("td", { class: "name" }, ANGLE_LABELS[n]),
        el("td", { class: "num" }, deg(r.min)), el("td", { class: "num" }, deg(r.max)),
        el("td", { class: "num" }, el("b", {}, deg(r.range))),
        el("td", { style: "width:28%" }, romBar(r.min, r.max, r.normal_min, r.normal_max)),
        el("td", { class: "num muted nowrap" }, r.normal_min === null ? "—" : `${r.normal_min}…${r.normal_max}°`),
        el("td", { class: "num " + percentClass(r.percent_of_normal) },
          r.percent_of_normal === null ? "—" : Math.round(r.percent_of_normal) + " %"));
    }))),
  el("div", { class: "legend" }, el("span", {}, el("i", { style: "background:#d6dde5" }), "normal range (AAOS)"),
    el("span", {}, el("i", { style: "background:var(--accent)" }), "this session"),
    el("span", {}, "calibration poses are not counted"))];
}

/** The kit as the therapist named it; else the phone kit's or another kit's own word. */
function streamedBy(session) {
  if (session.device_name) return session.device_name;
  if (session.metadata.device === "phone kit") return "the patient's phone";
  return session.metadata.device || "a kit";
}

/** A signed number with a true minus sign ("−3.5"). */
function signed(value, digits) {
  return value === null || value === undefined ? "—" : value.toFixed(digits).replace("-", "−");
}

/** The report's figures per exercise and angle: repetitions, mean movement time [s],
 * peak angular velocity [deg/s] and median smoothness (SPARC), as the PDF gives them. */
function exerciseFigures(report) {
  const rows = report.exercises.flatMap((e) => e.angles.map((a) => [e, a]));
  if (!rows.length) return null;
  const several = report.exercises.length > 1;
  const names = new Map(report.exercises.map((e, k) => [e, exerciseNames(report.exercises)[k]]));
  return [el("table", { id: "exercise-figures" },
    el("thead", {}, el("tr", {}, el("th", {}, "Angle"), el("th", { class: "num" }, "Reps"),
      el("th", { class: "num" }, "Move time"), el("th", { class: "num" }, "Peak speed"),
      el("th", { class: "num" }, "Smoothness"))),
    el("tbody", {}, rows.map(([e, a]) => el("tr", { dataset: { angle: a.angle, exercise: e.name } },
      el("td", { class: "name" }, (several ? names.get(e) + ": " : "") + (ANGLE_LABELS[a.angle] || a.angle)),
      el("td", { class: "num", dataset: { unit: a.repetitions === 1 ? " repetition" : " repetitions" } }, String(a.repetitions)),
      el("td", { class: "num" }, a.mean_movement_time_s === null ? "—" : a.mean_movement_time_s.toFixed(1) + " s"),
      el("td", { class: "num" }, a.peak_velocity_deg_s === null ? "—" : Math.round(a.peak_velocity_deg_s) + "°/s"),
      el("td", { class: "num" }, signed(a.median_sparc, 1)))))),
    el("p", { class: "muted small", style: "margin:4px 0" },
      "Means over the repetitions; peak speed: the joint's fastest turn; smoothness: SPARC, closer to 0 is smoother.")];
}

/** What the patient said after each exercise on the phone (effort-pain/1): "The patient
 * said: Elbow flexion: effort 4.5 of 10, pain 3 of 10"; nothing when they gave none. */
function ratingsNote(ratings) {
  if (!ratings || !ratings.length) return null;
  const score = (v, what) => v === null || v === undefined ? `${what} not given` : `${what} ${v} of 10`;
  return el("div", { id: "ratings", style: "margin-top:8px" },
    el("p", { style: "margin:4px 0" }, el("b", {}, "The patient said"),
      " (effort: 0 nothing at all to 10 maximal; pain: 0 none to 10 the worst imaginable):"),
    el("ul", { style: "margin:2px 0;padding-left:20px" }, ratings.map((r) => el("li", {},
      `${r.exercise.split(" + ").map(exerciseLabel).join(" + ")}: ${score(r.effort, "effort")}, ${score(r.pain, "pain")}`))));
}

/** Which poses calibrated the angles, in words (the estimator's method: two-pose,
 * n-pose or default; the PDF says it alike, reports/words.py calibration_words). */
function calibrationWords(method, held) {
  if (method === "two-pose") {
    return "Calibrated from the two poses the patient held in this session: the arm hanging "
      + "(N-pose), then out sideways, palm down (T-pose).";
  }
  if (method === "n-pose") {
    return "Calibrated from the one pose the patient held in this session, the arm hanging "
      + "(N-pose); without the T-pose the rest is taken as the strapping guide places the sensors.";
  }
  const poses = `${held} calibration pose${held === 1 ? "" : "s"}`;
  if (method === "default") {
    return `${poses} held, but not used: each sensor is taken as the strapping guide places it `
      + "(the warning below says why).";
  }
  return `${poses} held; the angles are not estimated yet.`;
}

/** The targets in force when the session was recorded, and how far each was reached. */
function targetLines(report) {
  const names = ANGLES.filter((n) => report.rom[n] && report.rom[n].target_max !== null
    && report.rom[n].target_max !== undefined);
  if (!names.length) return null;
  return el("div", { id: "rom-targets", style: "margin-top:8px" }, names.map((n) => {
    const r = report.rom[n];
    return el("p", { dataset: { angle: n }, style: "margin:2px 0" },
      el("b", {}, "Target then: "), `${ANGLE_LABELS[n]} ${deg(r.target_min)} to ${deg(r.target_max)}`,
      r.percent_of_target === null ? "" : ` · ${Math.round(r.percent_of_target)}\u00a0% of it reached`,
      r.target_reached ? " ✓" : "");
  }));
}

async function showReplay() {
  const summary = await api(`/api/sessions/${session.id}/summary`);
  // to the second: the page of one session names it as its row does among others of the minute
  const started = fmtDate(summary.started_at, { seconds: true });
  document.getElementById("facts").replaceChildren(
    session.dated === "uploaded" ? "uploaded " + started + " (recording time unknown)"
      : (session.dated === "recorded" ? "recorded " : "") + started,
    " · ", fmtDuration(summary.duration_s), " · ",
    session.source === "upload" ? "uploaded recording" : "streamed by " + streamedBy(session),
    " · ", qualityBadge(summary.quality));
  clear(document.getElementById("angles-card"),
    el("h2", {}, "Range of motion"),
    summary.headline ? el("p", { style: "margin:0 0 10px;font-size:16px" }, "Largest: ", el("b", { id: "headline" }, noNegativeZero(summary.headline))) : null,
    romTable(summary), assumptionsNote());
  const q = summary.quality;
  const card = document.getElementById("details-card");
  card.hidden = false;
  clear(card,
    el("h2", {}, "Exercises"),
    summary.exercises.length ? el("div", { id: "exercises" }, exerciseChipTexts(summary.exercises).map((text, k) => el("span", { class: summary.exercises[k].unfinished ? "chip unfinished" : emptySet(summary.exercises[k]) ? "chip empty" : "chip" },
      text + ` · ${summary.exercises[k].start.toFixed(0)}–${summary.exercises[k].end === null ? "…" : summary.exercises[k].end.toFixed(0)} s`)))
      : el("p", { class: "muted" }, "No exercise was marked or found in this session."),
    summary.exercises.some((e) => e.unfinished) ? el("p", { class: "note", id: "stopped-part-way" },
      "The patient stopped part way: the session ended with a set begun and never finished "
      + "on the kit (“stopped after …” above).") : null,
    ratingsNote(summary.ratings),
    el("h3", {}, "Calibration"),
    summary.calibration_poses.length
      ? el("p", { style: "margin:4px 0", id: "calibration-words" }, calibrationWords(q.calibration_method, summary.calibration_poses.length))
      : noPosesWhy(),
    q.calibration_warnings.length ? el("ul", { class: "warnings", id: "calibration-warnings" },
      q.calibration_warnings.map((w) => el("li", {}, w))) : el("p", { class: "muted", style: "margin:4px 0" }, "No calibration warning."),
    el("h3", {}, "Data quality"),
    el("table", {}, el("tbody", {}, Object.entries(q.sensors).map(([name, s]) => el("tr", {},
      el("td", {}, SENSOR_LABELS[name] || name), el("td", { class: "num" }, s.samples.toLocaleString() + " samples"),
      el("td", { class: "num" }, fmtPercent(s.lost_fraction) + " lost"))))),
    el("h3", {}, "Exports"),
    el("div", { class: "row", id: "exports" },
      download(`/api/sessions/${session.id}/recording.csv`, "recording.csv"),
      summary.processed ? download(`/api/sessions/${session.id}/angles.csv`, "angles.csv") : null),
    el("div", { class: "row", style: "margin-top:18px" }, eraseSessionButton(card)));
  if (summary.processed) {
    try {
      const report = await api(`/api/sessions/${session.id}/report`);
      const targets = targetLines(report);
      if (targets) document.getElementById("angles-card").append(targets);
      const figures = exerciseFigures(report);
      if (figures) document.getElementById("exercises").after(...figures);
    } catch (_) { /* the summary above stands without the report's figures */ }
  }
  // report exports, where this server has them
  if (summary.processed) {
    try {
      const paths = (await (await fetch("/openapi.json")).json()).paths || {};
      for (const kind of ["report.pdf", "report.csv", "report.mot", "report.sto", "report.fhir.json"]) {
        if (paths["/api/sessions/{session_id}/" + kind])
          document.getElementById("exports").append(download(`/api/sessions/${session.id}/${kind}`, kind));
      }
    } catch (_) { /* no OpenAPI document: the raw exports are enough */ }
  }
}

/** "Erase this session…": a recording imported to the wrong patient, a session streamed by
 * the wrong kit, is corrected without erasing the patient. Asks first, naming the session;
 * then back to the patient's page, where it is gone. */
function eraseSessionButton(card) {
  return el("button", { class: "danger", id: "erase-session", onclick: async () => {
    const what = `session ${session.id} of ${patient.name} (${fmtDate(session.started_at)})`;
    if (!confirm(`Erase ${what} with its recording, angles and reports, for good? `
      + "The patient's other sessions stay.")) return;
    try {
      await api(`/api/sessions/${session.id}`, { method: "DELETE" });
      location.href = "/patients/" + patient.id;
    } catch (e) { showError(card, e); }
  } }, "Erase this session…");
}

// ---------------------------------------------------------------- stopped by the server
function showStopped(stop) {
  const box = document.getElementById("stopped-by-server");
  if (!stop) return;
  session.stopped_by_server = stop;
  clear(box, ...stoppedNote(stop));
  box.hidden = false;
}

// The server closed this interrupted session after its kit's long silence
// (closed_after_silence, docs/extensions/closed-after-silence.md): when, and its words.
function showClosedAfterSilence(record) {
  const box = document.getElementById("closed-after-silence");
  if (!record) return;
  clear(box, el("h2", {}, `The server closed this session · ${fmtDate(record.at)}`),
    el("p", {}, record.message),
    el("p", { class: "small muted" }, `The kit last sent data ${fmtDate(record.last_data_at)}.`));
  box.hidden = false;
}

// ---------------------------------------------------------------- start
/** The session turned live, interrupted or closed while the page is open: its badge, and
 * the day's strip, which names each session's state ("live now", "interrupted"). */
function statusChanged(status) {
  session.status = status;
  setStatus();
  LiveFollow.history().catch(() => {});
}

function setStatus() {
  const actions = document.getElementById("actions");
  clear(actions, statusBadge(session.status));
}

async function start() {
  session = await api(`/api/sessions/${sessionId}`);
  patient = await api(`/api/patients/${session.patient_id}`);
  const crumb = document.getElementById("crumb-patient");
  clear(crumb, el("a", { href: "/patients/" + patient.id }, patient.name));
  document.getElementById("title").textContent = `${patient.name} — ${session.status === "closed" ? "session" : "live session"} ${session.id}`;
  document.title = `${patient.name} · session ${session.id} · armtrack`;
  setStatus();
  showStopped(session.stopped_by_server);
  showClosedAfterSilence(session.closed_after_silence);
  LiveFollow.start(session);
  if (session.status === "closed") {
    openViewer("replay");
    await showReplay();
    LiveFollow.watch();
  } else {
    document.getElementById("facts").textContent =
      `started ${fmtDate(session.started_at, { seconds: true })} · ${session.sensors.length} sensors · ${patient.side} arm`;
    liveAnglesCard();
    openViewer("live");
    connectLive();
    await pollLive();
    setInterval(() => { if (!ended) pollLive(); }, 500);
  }
}
start().catch((e) => showError(document.querySelector("main"), e));

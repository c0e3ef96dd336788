// armtrack phone kit: the guided home session (/kit). The phone is the sensor: strap it,
// hold the two calibration poses, then do the day's exercises with the live angle, the
// target band and the repetitions from the server (docs/phone-kit.md). With a program in
// force (docs/programs.md) the list, the dose (sets × repetitions, hold, rest) and the
// version come from it, the session names it in hello (programs/1), and after each
// exercise the patient says how hard it was and the pain (kit-program.js). Every text the
// server or the page shows is set as text (textContent), never as HTML.
"use strict";

const TOKEN_KEY = "armtrack.kit.token";
const TODAY_KEY = "armtrack.kit.today";
const STEP_KEY = "armtrack.kit.step";
const SEGMENT_KEY = "armtrack.kit.segment";
/** What this session did per exercise (the finished screen's list; kept over a reload). */
const DID_KEY = "armtrack.kit.did";
/** The last finished session's list of what was done, with when (the welcome shows it); forgotten
 * when another kit's link is opened (main). */
const LAST_KEY = "armtrack.kit.last";
/** Set (sessionStorage) when the patient chose to carry on a session cut short long ago
 * that could not be sent (offline): the reload resumes it (endTheStaleSession). */
const CARRY_ON_KEY = "armtrack.kit.carry-on";
/** A kit token as the server makes it (server/auth.py new_token("dev_"): 256 random bits,
 * URL-safe base64): anything else in a link is the link cut short. */
const TOKEN_SHAPE = /^dev_[A-Za-z0-9_-]{43}$/;
/** hello's device: what the kit is (the session page names it by the therapist's name for
 * it); not the browser's platform string, which named no one's phone. */
const PHONE_KIT = "phone kit";
const G = 9.81;
/** Stillness: over the last STILL_S, gyroscope under STILL_GYRO [rad/s] and |a| within
 * STILL_ACC [m/s²] of g. A calibration pose is held HOLD_S once still. */
const STILL_S = 0.5, STILL_GYRO = 0.25, STILL_ACC = 0.8, HOLD_S = 2.5;
/** How long "I'm ready" waits for a first motion reading before saying there is none [ms]. */
const MOTION_WAIT_MS = 8000;
/** After a set's last repetition the set ends once the angle is back within
 * RETURN_FRACTION of the band from its start (a both-ways exercise's start is its neutral,
 * 0°) and SETTLE_MS has passed (the report counts a repetition from rest and back to rest,
 * so the marked set must hold the return), or after RETURN_WAIT_MS at most. A both-ways
 * exercise (palm down, then up: docs/programs.md) is counted on its first turn: the set
 * waits first for the last turn the other way (feedback's unpaired_turns back to 0), at
 * most RETURN_WAIT_MS. */
const RETURN_FRACTION = 0.15, SETTLE_MS = 1200, RETURN_WAIT_MS = 7000;
// A forearm phone's elbow movement the server found made about the shoulder (the straight
// arm raised: feedback's not_elbow_movements, docs/extensions/kit-feedback.md) is not
// counted; the patient is told why, for NOT_ELBOW_MS.
const NOT_ELBOW_MS = 8000;
const NOT_ELBOW_WORDS = "That moved your whole arm from the shoulder, so it did not count. "
  + "Keep your upper arm still against your side and bend only at the elbow.";
/** A session kept on the phone whose last reading is older than this [s] when the page
 * opens is not carried on: the page was closed or the battery died, and after so long the
 * phone has most likely been off the arm (charged, put away), so the poses it was
 * calibrated with no longer hold, and the day may have changed. It is sent as it is and
 * ended, and the page starts afresh. A reload or a tab closed by mistake comes back well
 * within it; the longest rest between sets (10 min) keeps the page open and recording. */
const CARRY_ON_WITHIN_S = 30 * 60;

/** Used when the server cannot be asked (offline, first start) — the catalogue's defaults. */
const FALLBACK_EXERCISES = [
  { name: "elbow_flexion", title: "Bend the elbow", angle: "elbow_flexion", sensor: "forearm", repetitions: 10,
    instruction: "Arm along your side, thumb forward: bend the elbow to bring the hand up toward the shoulder, then straighten it fully.",
    picture: "elbow_flexion", target: { min_deg: 0, max_deg: 120, from: "default" } },
  { name: "pronation", title: "Turn the palm", angle: "forearm_pronation", sensor: "forearm", repetitions: 10, both_ways: true,
    instruction: "Elbow bent at a right angle by your side: turn the palm down, then up, as far as is comfortable.",
    picture: "pronation", target: { min_deg: -70, max_deg: 70, from: "default" } },
  { name: "shoulder_flexion", title: "Raise the arm forward", angle: "shoulder_elevation", sensor: "upper_arm", repetitions: 10,
    instruction: "Arm straight, thumb up: raise it forward and up as high as is comfortable, then lower it slowly.",
    picture: "shoulder_flexion", target: { min_deg: 0, max_deg: 150, from: "default" } },
  { name: "shoulder_abduction", title: "Raise the arm to the side", angle: "shoulder_elevation", sensor: "upper_arm", repetitions: 10,
    instruction: "Arm straight, palm down: raise it out to the side up to shoulder height, then lower it slowly.",
    picture: "shoulder_abduction", target: { min_deg: 0, max_deg: 90, from: "default" } },
];
const SEGMENT_WORDS = { forearm: "forearm", upper_arm: "upper arm" };
const TOP_TOWARD = { forearm: "your elbow", upper_arm: "your shoulder" };

function el(tag, attrs, ...children) {
  const node = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs || {})) {
    if (k === "onclick") node.addEventListener("click", v);
    else if (k === "class") node.className = v;
    else node.setAttribute(k, v);
  }
  for (const c of children.flat()) if (c != null) node.append(c instanceof Node ? c : String(c));
  return node;
}

const kit = {
  token: null, today: null, sensor: null, side: "right", stream: null,
  recent: [],            // [t, |gyro|, |acc|, ay] of the last readings (stillness, strap check)
  lastReading: null, motionSeen: false, listening: false,
  feedback: null, feedbackAt: 0, phase: null, exerciseIndex: 0, timers: [],
  wakeLock: null, hiddenAt: null, gaps: [],
  did: JSON.parse(localStorage.getItem(DID_KEY) || "{}"),  // see noteDone
};

// -- speech, vibration, wake lock ----------------------------------------------------------
function say(text) {
  try {
    if (!("speechSynthesis" in window)) return;
    speechSynthesis.cancel();
    speechSynthesis.speak(new SpeechSynthesisUtterance(text));
  } catch (_) { /* no voice on this phone: the screen says it */ }
}
function buzz(pattern) { try { if (navigator.vibrate) navigator.vibrate(pattern); } catch (_) { /* none */ } }
/** A session runs: from "I'm ready" (or its resume) until it has ended and all is sent. */
function sessionRuns() {
  return Boolean(kit.stream && kit.stream.state && !kit.stream.state.finished
                 && !kit.stream.stopped);
}
/** The screen kept on (Wake Lock) while a session runs only; taken again on a return to
 * the page (the browser lets it go when the page is hidden), released at the end. */
async function keepAwake() {
  try {
    if ("wakeLock" in navigator && !kit.wakeLock && document.visibilityState === "visible"
        && sessionRuns()) {
      kit.wakeLock = await navigator.wakeLock.request("screen");
      kit.wakeLock.addEventListener("release", () => { kit.wakeLock = null; });
    }
  } catch (_) { /* refused (battery saver): the page says to keep the screen on */ }
}
function letSleep() {
  if (kit.wakeLock && !sessionRuns()) { kit.wakeLock.release().catch(() => {}); kit.wakeLock = null; }
}

// -- sensors -------------------------------------------------------------------------------
/** Whether the page may read the motion sensors: asks where the phone asks first (iOS,
 * only from a tap); false when refused (iOS keeps a "Don't allow" for the site) or when
 * asking failed. */
async function motionAllowed() {
  const D = window.DeviceMotionEvent;
  if (!D || typeof D.requestPermission !== "function") return true;
  try { return await D.requestPermission() === "granted"; } catch (_) { return false; }
}

function onMotion(event) {
  const values = KitAxes.row(event);
  if (!values) return;
  kit.motionSeen = true;
  if (kit.stream && kit.stream.state && !kit.stream.ended) kit.stream.reading(event);
  const t = event.timeStamp / 1000;  // this page load's clock: the stillness check's
  const [ax, ay, az, gx, gy, gz] = values;
  kit.lastReading = values;
  kit.recent.push([t, Math.hypot(gx, gy, gz), Math.hypot(ax, ay, az), ay]);
  while (kit.recent.length && kit.recent[0][0] < t - 2) kit.recent.shift();
}

function listen() {
  if (kit.listening) return;
  kit.listening = true;
  window.addEventListener("devicemotion", onMotion);
}

/** Whether the phone has been still for the last STILL_S (and the readings cover it). */
function still(condition = () => true) {
  const r = kit.recent;
  if (r.length < 5) return false;
  const end = r[r.length - 1][0];
  if (end - r[0][0] < STILL_S) return false;
  for (let i = r.length - 1; i >= 0 && r[i][0] >= end - STILL_S; i--) {
    const [, g, a, ay] = r[i];
    if (g > STILL_GYRO || Math.abs(a - G) > STILL_ACC || !condition(ay)) return false;
  }
  return true;
}
const hanging = (ay) => ay > 8.3;          // long axis vertical, top up (arm down)
const horizontal = (ay) => Math.abs(ay) < 3; // long axis level (arm out to the side)
const upsideDown = (ay) => ay < -6;         // long axis vertical, top down (as the strap check)

// -- layout -------------------------------------------------------------------------------
function screen(...children) {
  for (const id of kit.timers.splice(0)) clearInterval(id);
  const main = document.getElementById("screen");
  main.replaceChildren(...children.flat().filter((c) => c != null));
  document.getElementById("gap").hidden = true;  // a screen-off notice lasts until the next step
  main.scrollTop = 0;
  window.scrollTo(0, 0);
}
function every(ms, fn) { const id = setInterval(fn, ms); kit.timers.push(id); fn(); return id; }
function picture(name) { return el("div", { class: "picture" }, KitPictures.named(name, kit.sensor, kit.side)); }
function big(text, attrs = {}) { return el("button", { class: "big", ...attrs }, text); }

function status() {
  const bar = document.getElementById("status");
  const s = kit.stream;
  let text, kind;
  if (!s || !s.state) { text = navigator.onLine ? "Ready" : "Offline"; kind = "idle"; }
  else if (s.error) { text = s.error; kind = "bad"; }
  else if (s.state.finished) { text = "All sent ✓"; kind = "good"; }
  else if (s.connected) {
    text = s.unsent > 30 ? `Sending… ${s.unsent} to go` : "Connected · sending live";
    kind = "good";
  } else {
    text = "Offline · saved on this phone, will send when online";
    kind = "warn";
  }
  bar.textContent = text;
  bar.className = "status " + kind;
  bar.dataset.connected = s && s.connected ? "yes" : "no";
  letSleep();  // the session's end (all sent, or erased) lets the screen sleep
}

// -- the steps ----------------------------------------------------------------------------
/** One tab of this phone holds the kit (Web Locks): a second tab (the link opened again)
 * would resume the same stream, take its connection from the first and number messages
 * into the same outbox. It waits, saying so, and goes on by itself once the other tab is
 * closed. Without Web Locks (a page not served over https), as before. */
function holdTheKit() {
  if (!(navigator.locks && navigator.locks.request)) return Promise.resolve();
  return new Promise((resolve) => {
    let held = false;
    navigator.locks.request("armtrack-kit", () => {
      held = true;
      resolve();
      return new Promise(() => {});  // held while this page lives
    });
    setTimeout(() => {
      if (!held) {
        screen(el("h1", {}, "Open in another tab"),
          el("p", { class: "lead" }, "Your exercise kit is already open in another tab or window on this phone. Go back to that one, or close it: this page then goes on by itself."));
      }
    }, 1000);
  });
}

/** Without a working link the status bar's "Ready" would say all is well: it goes. */
function noStatus() { document.getElementById("status").hidden = true; }

function noLink() {
  noStatus();
  screen(el("h1", {}, "Open your link"),
    el("p", { class: "lead" }, "This page is your arm exercise kit. Open it from the link or QR code your therapist gave you."));
}

/** The link opened is not whole (a message app broke it, part of it was copied): the
 * server would refuse it as it refuses a revoked one, but the therapist did nothing. */
function cutLink() {
  noStatus();
  screen(el("h1", {}, "This link is incomplete"),
    el("p", { class: "lead", id: "cut-link" }, "Part of the link is missing, so it cannot open your exercises."),
    el("p", {}, "Open the whole link again from your therapist's message (tap it, do not copy part of it), "
      + "or scan the QR code again. If it still does not work, ask your therapist for a new link."));
}

function welcome() {
  kit.phase = "welcome";
  const count = kit.today.exercises.length;
  const intro = kit.today.program
    ? KitProgram.summary(kit.today, kit.today.exercises)
    : [el("h1", {}, "Your arm exercises"),
      el("p", { class: "lead" }, `Today: ${count ? [...new Set(kit.today.exercises.map((e) => e.title))].join(", ") : "your exercises"}.`)];
  const notice = kit.notice ? el("p", { class: "note", id: "notice" }, kit.notice) : null;
  kit.notice = null;
  screen(...intro, notice, lastTime(),
    el("p", {}, "Your phone measures your arm. You need a strap or a sports armband for the phone."),
    kit.today.offline ? el("p", { class: "note" }, "Offline: using the exercises saved on this phone.") : null,
    big("Start", { id: "start", onclick: chooseSegment }));
}

/** A day in the patient's words: "today", "yesterday", else `before` + "Tuesday, Dec 1". */
function dayWords(at, before = "") {
  const days = Math.round((new Date().setHours(0, 0, 0, 0) - new Date(at).setHours(0, 0, 0, 0)) / 86400000);
  return days === 0 ? "today" : days === 1 ? "yesterday"
    : before + at.toLocaleDateString(undefined, { weekday: "long", month: "short", day: "numeric" });
}

/** What the patient did in their recent sessions ("Last time, today" and its list, then
 * the ones before): the server's (device-today's `recent`, any phone of theirs) with the
 * last one kept on this phone; null when there is none. */
function lastTime() {
  const last = JSON.parse(localStorage.getItem(LAST_KEY) || "null");
  const sessions = KitProgram.recent(kit.today.recent, last);
  if (!sessions.length) return null;
  return el("div", { id: "recent" }, sessions.map((r, i) => {
    const when = dayWords(r.at);
    return el("div", i === 0 ? { class: "last", id: "last-session" } : { class: "last" },
      el("p", { class: "kicker" }, i === 0 ? `Last time, ${when}` : when[0].toUpperCase() + when.slice(1)),
      el("ul", { class: "did" }, r.lines.map((line) => el("li", {}, line))));
  }));
}

function chooseSegment() {
  kit.phase = "segment";
  const choose = (segment) => async () => {
    if (!await motionAllowed()) return motionRefused();
    listen();
    kit.sensor = segment;
    localStorage.setItem(SEGMENT_KEY, segment);
    strap();
  };
  const usable = (segment) => kit.today.exercises.some((e) => KitProgram.measuredOn(e, segment));
  screen(el("h1", {}, "Where will you wear the phone?"),
    el("div", { class: "choices" },
      ["forearm", "upper_arm"].filter(usable).map((segment) => el("button", {
        class: "choice", id: "segment-" + segment, onclick: choose(segment) },
        el("div", { class: "picture small" }, KitPictures.named("segment:" + segment, null, kit.side)),
        el("span", {}, "On my " + SEGMENT_WORDS[segment],
          // which of today's exercises the phone measures there: the welcome lists all
          el("span", { class: "measures" }, "For: " + [...new Set(kit.today.exercises
            .filter((e) => KitProgram.measuredOn(e, segment)).map((e) => e.title))].join(", ")))))));
}

function sensorProblem(reason, advice = el("p", {}, "Open this page in Chrome or Safari, from the https link, and allow motion sensors when asked.")) {
  screen(el("h1", {}, "The phone's motion sensors"),
    el("p", { class: "lead" }, reason),
    advice,
    big("Try again", { onclick: chooseSegment }));
}

/** The phone refused the motion sensors: what to tap, and what to do when it does not
 * ask again. */
function motionRefused() {
  sensorProblem("The phone did not let this page use its motion sensors: they are what "
      + "measures your arm, so the exercises cannot start.",
    el("ol", { class: "steps", id: "allow-motion" },
      el("li", {}, "Tap Try again, then Allow when the phone asks."),
      el("li", {}, "If it does not ask: close the browser (swipe it away), open your link again, and tap Allow.")));
}

function strap() {
  kit.phase = "strap";
  const check = el("p", { class: "check", id: "strap-check" }, "Waiting for the phone's motion sensors…");
  screen(el("h1", {}, `Strap the phone on your ${SEGMENT_WORDS[kit.sensor]}`),
    picture("segment:" + kit.sensor),
    el("ol", { class: "steps" },
      el("li", {}, `On the outside of your ${kit.side} ${SEGMENT_WORDS[kit.sensor]}.`),
      el("li", {}, "Screen facing out, away from your skin."),
      el("li", {}, `The top of the phone toward ${TOP_TOWARD[kit.sensor]}.`),
      el("li", {}, "Firm, so it does not slide.")),
    check,
    kit.today.program ? KitProgram.skipped(kit.today.exercises, kit.sensor) : null,
    big("I'm ready", { id: "ready", onclick: beginSession }));
  say(`Strap the phone on the outside of your ${SEGMENT_WORDS[kit.sensor]}, screen out, top toward ${TOP_TOWARD[kit.sensor]}.`);
  const started = Date.now();
  every(250, () => {
    if (!kit.motionSeen) {
      if (Date.now() - started > 4000) check.textContent = "No motion readings yet. Is this a phone, in Chrome or Safari, over https?";
      return;
    }
    const ay = kit.lastReading[1];
    if (ay > 8.3) { check.textContent = "✓ The phone is the right way up."; check.className = "check good"; }
    else if (ay < -6) { check.textContent = `Turn the phone round: its top toward ${TOP_TOWARD[kit.sensor]}.`; check.className = "check warn"; }
    else { check.textContent = "Let your arm hang by your side to check the phone."; check.className = "check"; }
  });
}

/** `ready` of each connection: the program version the session follows is the one that
 * counts (programs-hello.md: a change since today's list was read gives the newer one). */
function onReady(message) {
  if (message.program_error) kit.programError = message.program_error;
  const followed = message.program;
  if (followed && kit.today.program && followed.version !== kit.today.program.version) {
    kit.today = { ...kit.today, exercises: followed.exercises,
      program: { id: followed.id, name: followed.name, version: followed.version, note: followed.note } };
    localStorage.setItem(TODAY_KEY, JSON.stringify(kit.today));
  }
}

function newStream(program) {
  return new KitStream({
    token: kit.token, sensor: kit.sensor, side: kit.side, device: PHONE_KIT,
    program, onChange: status, onReady, onEndedByTherapist: () => finished(), onStopped: stopped, onFeedback: (f) => { kit.feedback = f; kit.feedbackAt = Date.now(); },
  });
}

/** Whether a motion reading comes within ``ms`` [ms] (at once when one came already). */
function motionWithin(ms) {
  return new Promise((resolve) => {
    const started = Date.now();
    const id = setInterval(() => {
      if (kit.motionSeen || Date.now() - started > ms) { clearInterval(id); resolve(kit.motionSeen); }
    }, 100);
    if (kit.motionSeen) { clearInterval(id); resolve(true); }
  });
}

async function beginSession() {
  // no session without readings: one would stay empty ("interrupted", 0 samples) on the
  // therapist's page while this page waited for ever
  const ready = document.getElementById("ready");
  if (ready) { ready.disabled = true; ready.textContent = "Waiting for the phone's motion sensors…"; }
  kit.stream = newStream(kit.today.program ? kit.today.program.id : null);  // not started yet
  if (!await motionWithin(MOTION_WAIT_MS)) {
    kit.stream = null;
    return sensorProblem("No motion readings came from this device, so no session was started. "
      + "armtrack needs a phone's motion sensors: this page on a computer cannot measure the arm.");
  }
  await kit.stream.start();
  kit.did = {};
  localStorage.removeItem(DID_KEY);
  await keepAwake();
  saveStep("npose", 0);
  calibrationPose("npose");
}

function saveStep(phase, index, extra = {}) {
  kit.phase = phase;
  kit.exerciseIndex = index;
  localStorage.setItem(STEP_KEY, JSON.stringify({ phase, index, sensor: kit.sensor, ...extra }));
}

/** N-pose, then T-pose: both held HOLD_S once still. Their marks go out together when
 * the T-pose is done (the N-pose's in the past): until then the server has no pose and
 * waits (kinematics.md: with no pose, calibration waits 60 s), so it never calibrates
 * from the N-pose alone while the T-pose is being held. The T-pose must begin within
 * 5 s of the N-pose's end (the spec's grace), else both are held again. */
const POSES = {
  npose: { title: "Arm down, hold still", condition: hanging,
    text: "Stand tall, arm hanging by your side, thumb forward." },
  tpose: { title: "Arm out to the side, hold still", condition: horizontal,
    text: "Raise your arm straight out to the side, palm down, at shoulder height." },
};
const TPOSE_WITHIN_S = 4.8;

function calibrationPose(name) {
  const pose = POSES[name];
  saveStep(name, 0);
  const count = el("div", { class: "count", id: "count" }, "");
  const hint = el("p", { class: "check", id: "hold" }, "Get into position…");
  screen(el("h1", {}, pose.title), picture(name), el("p", { class: "lead" }, pose.text), count, hint);
  say(pose.text + " Then hold still.");
  let holdStart = null;
  let toldUpsideDown = false;
  every(100, () => {
    const s = kit.stream;
    if (!still(pose.condition)) {
      if (holdStart !== null) { hint.textContent = "Hold still…"; buzz(80); }
      else if (name === "npose" && still(upsideDown)) {
        // the arm hangs still but the phone's top points down: the pose never starts, so
        // say why (the strap check said so too, but "I'm ready" goes on regardless)
        const turn = `The phone is upside down. Turn the phone round: its top toward ${TOP_TOWARD[kit.sensor]}.`;
        hint.textContent = turn;
        if (!toldUpsideDown) { toldUpsideDown = true; say(turn); }
      } else hint.textContent = "Get into position…";
      holdStart = null;
      count.textContent = "";
      return;
    }
    const now = s.now();
    if (holdStart === null) { holdStart = now; hint.textContent = "Hold still…"; }
    const left = HOLD_S - (now - holdStart);
    count.textContent = String(Math.max(1, Math.ceil(left)));
    if (left > 0) return;
    buzz(200);
    if (name === "npose") {
      kit.npose = [holdStart, now];
      say("Good.");
      calibrationPose("tpose");
    } else if (!kit.npose || holdStart - kit.npose[1] > TPOSE_WITHIN_S) {
      kit.npose = null;
      say("A little quicker: arm down again.");
      calibrationPose("npose");
    } else {
      s.mark("npose", kit.npose[0]);
      s.mark("end:npose", kit.npose[1]);
      s.mark("tpose", holdStart);
      s.mark("end:tpose", now);
      say("Good.");
      lowerArm();
    }
  });
}

function lowerArm() {
  saveStep("lower", 0);
  screen(el("h1", {}, "Lower your arm"), picture("npose"),
    el("p", { class: "lead" }, "Let it hang by your side. Calibration is done."),
    el("p", { class: "check", id: "hold" }, "Waiting for your arm to hang still…"));
  say("Lower your arm.");
  every(100, () => { if (still(hanging)) exerciseIntro(0); });
}

/** The exercises the phone measures where it is worn (device-today's measured_by). */
function exercisesForKit() {
  return kit.today.exercises.filter((e) => KitProgram.measuredOn(e, kit.sensor));
}

function exerciseIntro(index) {
  const list = exercisesForKit();
  if (index >= list.length) return finished();
  const ex = list[index];
  saveStep("intro", index);
  const count = el("div", { class: "count soon", id: "count" }, "");
  const hold = ex.hold_s ? ` Hold ${ex.hold_s} ${ex.hold_s === 1 ? "second" : "seconds"} at the end of each movement.` : "";
  screen(el("p", { class: "kicker" }, `Exercise ${index + 1} of ${list.length}`),
    el("h1", {}, ex.title), picture(ex.picture),
    el("p", { class: "lead" }, ex.instruction + hold),
    ex.note ? el("p", { class: "note", id: "exercise-note" }, ex.note) : null,
    el("p", { class: "dose", id: "dose" }, KitProgram.dose(ex) + "."), count,
    big("Start now", { id: "start-exercise", onclick: () => exercise(index, 0) }));
  say(`${ex.title}. ${ex.instruction}${hold} ${KitProgram.dose(ex).replaceAll(" · ", ", ")}.`);
  let left = 5;
  every(1000, () => {
    count.textContent = `Starts in ${left}`;  // by itself, or "Start now"
    if (left-- <= 0) exercise(index, 0);
  });
}

/** Rest between two sets, then the next set (its own marks, programs-hello.md). */
function restBetweenSets(index, set) {
  const ex = exercisesForKit()[index];
  saveStep("rest", index, { set });
  const count = el("div", { class: "count", id: "count" }, "");
  screen(el("p", { class: "kicker" }, `${ex.title} · set ${set + 1} of ${ex.sets}`),
    el("h1", { class: "welldone" }, "Rest"),
    el("p", { class: "lead" }, `Set ${set} done. Let your arm rest; set ${set + 1} starts when the count ends.`),
    count, big(`Start set ${set + 1} now`, { id: "start-set", onclick: () => exercise(index, set) }));
  say(`Rest. Set ${set + 1} follows.`);
  let left = Math.max(1, Math.round(ex.rest_s || 10));
  every(1000, () => {
    count.textContent = String(left);
    if (left-- <= 0) exercise(index, set);
  });
}

/** After each exercise: how hard it was and the pain, or skip (effort-pain/1). */
function rateExercise(index) {
  const ex = exercisesForKit()[index];
  saveStep("rating", index);
  say("How hard was it, and how much pain? Tap a number, or skip.");
  screen(KitProgram.ratingScreen(ex, async (effort, pain) => {
    if (effort != null || pain != null) await kit.stream.rate(ex.name, effort, pain, `${index}-${ex.name}`);
    exerciseIntro(index + 1);
  }));
}

/** Notes what exercise `index`'s screen showed: set `set`'s repetitions so far, and an
 * angle [deg] (its range is kept); saved when it changed. */
function noteDone(index, set, reps, angle) {
  const d = kit.did[index] || (kit.did[index] = { reps: {}, lo: null, hi: null });
  let changed = d.reps[set] !== reps;
  d.reps[set] = reps;
  if (angle != null && (d.lo == null || angle < d.lo || angle > d.hi)) {
    d.lo = d.lo == null ? angle : Math.min(d.lo, angle);
    d.hi = d.hi == null ? angle : Math.max(d.hi, angle);
    changed = true;
  }
  if (changed) localStorage.setItem(DID_KEY, JSON.stringify(kit.did));
}

function exercise(index, set = 0, resumed = false) {
  const list = exercisesForKit();
  const ex = list[index];
  const sets = ex.sets || 1;
  // after a reload the exercise goes on: its clock and the repetitions shown so far
  const kept = resumed ? JSON.parse(localStorage.getItem(STEP_KEY) || "{}") : {};
  // feedback counts from this set's mark on: an earlier set's, still on its way, is not this one's
  const markT = resumed && kept.markT != null ? kept.markT : kit.stream.now();
  if (!resumed) kit.stream.mark("exercise:" + ex.name, markT);
  const started = kept.started || Date.now();
  saveStep("exercise", index, { set, markT, started, reps: kept.reps || 0 });
  kit.feedback = null;
  const lo = ex.target.min_deg, hi = ex.target.max_deg;
  const span = Math.max(hi - lo, 1), pad = 0.25 * span;
  const scaleLo = lo - pad, scaleHi = hi + pad;
  const pos = (v) => `${Math.min(100, Math.max(0, 100 * (v - scaleLo) / (scaleHi - scaleLo)))}%`;
  const angle = el("div", { class: "angle", id: "angle" }, "—");
  const marker = el("div", { class: "marker" });
  const band = el("div", { class: "band" },
    el("div", { class: "zone", style: `left:${pos(lo)};width:calc(${pos(hi)} - ${pos(lo)})` }), marker);
  const reps = el("div", { class: "reps", id: "reps" }, `${kept.reps || 0} of ${ex.repetitions}`);
  const note = el("p", { class: "note", id: "live-note" }, "");
  const clock = el("div", { class: "timer", id: "timer" }, "0:00");
  const next = big(set + 1 < sets ? "End this set" : index + 1 < list.length ? "Next exercise" : "Finish",
    { id: "next", class: "big secondary" });
  screen(el("p", { class: "kicker" }, `Exercise ${index + 1} of ${list.length}`,
    sets > 1 ? ` · set ${set + 1} of ${sets}` : "", " · ", clock),
    el("h1", {}, ex.title),
    el("div", { class: "live" }, angle, el("div", { class: "target" }, KitProgram.bandWords(ex.target, ex.angle))),
    band, reps, note, next);
  // repetitions: per counting run of the server (feedback's count_from; one run goes on
  // across a resumed stream), a new run's count added to what was shown before it
  let run = kept.run, base = kept.run !== undefined ? (kept.runBase || 0) : (kept.reps || 0);
  let done = false, spoken = kept.reps || 0, shown = kept.reps || 0, reachedAt = null, backAt = null;
  let pairedAt = null;  // a both-ways set: when its last turn had its turn the other way
  let notElbow = null, notElbowAt = null;  // this run's movements not the elbow's; told when
  // the set's end: the next set after a rest, else well done and how it was
  const after = () => (set + 1 < sets ? restBetweenSets(index, set + 1) : wellDone(index));
  const end = () => {
    if (done) return;
    done = true;
    kit.stream.mark("end:exercise:" + ex.name);
    after();
  };
  next.addEventListener("click", end);
  every(100, () => {
    const secs = Math.floor((Date.now() - started) / 1000);
    clock.textContent = `${Math.floor(secs / 60)}:${String(secs % 60).padStart(2, "0")}`;
    const f = kit.feedback;
    const fresh = f && Date.now() - kit.feedbackAt < 3000 && f.exercise === ex.name && f.t >= markT;
    if (fresh && f.angle_deg != null) {
      const [deg, side] = KitProgram.angleParts(ex.angle, f.angle_deg);
      angle.replaceChildren(deg, ...(side ? [el("span", { class: "side" }, side)] : []));
      marker.style.left = pos(f.angle_deg);
      marker.hidden = false;
      // docs/extensions/kit-feedback.md: a new counting run starts from 0 and adds up
      if (f.count_from !== run) {
        if (run !== undefined) base = shown;
        run = f.count_from;
        notElbow = null;
      }
      const refused = f.not_elbow_movements || 0;
      if (notElbow !== null && refused > notElbow) {
        notElbowAt = Date.now();
        buzz([60, 80, 60]);
        say("That did not count. Bend only at the elbow.");
      }
      notElbow = refused;
      const n = Math.max(shown, base + f.repetitions);
      shown = n;
      reps.textContent = `${n} of ${ex.repetitions}`;
      noteDone(index, set, n, f.angle_deg);
      if (n > spoken) {
        spoken = n;
        buzz(60);
        if (n < ex.repetitions) say(String(n));
        saveStep("exercise", index, { set, markT, started, reps: n, run, runBase: base });
      }
      if (reachedAt === null) {
        note.textContent = notElbowAt !== null && Date.now() - notElbowAt < NOT_ELBOW_MS ? NOT_ELBOW_WORDS
          : f.warnings && f.warnings.length ? f.warnings[f.warnings.length - 1] : "";
      }
      if (n >= ex.repetitions) {
        // the last repetition is counted on the way up: the set ends once the arm is back
        // (RETURN_FRACTION, SETTLE_MS above)
        const owed = ex.both_ways && f.unpaired_turns > 0;
        if (reachedAt === null || (pairedAt === null && !owed)) {
          reachedAt = Date.now();
          if (!owed) pairedAt = reachedAt;
          note.textContent = owed ? "Last one: now turn the other way, then back to the start."
            : "That's all of them — now back to the start.";
          say(owed ? "Last one. Now the other way." : "That's all. Back to the start.");
        }
        const back = ex.both_ways ? Math.abs(f.angle_deg) <= RETURN_FRACTION * (hi - lo)
          : f.angle_deg <= lo + RETURN_FRACTION * (hi - lo);
        if (owed) backAt = null;
        else if (backAt === null && back) backAt = Date.now();
        if ((backAt !== null && Date.now() - backAt > SETTLE_MS) || Date.now() - reachedAt > RETURN_WAIT_MS) end();
      }
    } else {
      angle.textContent = "—";
      marker.hidden = true;
      note.textContent = kit.stream.connected
        ? "Measuring… your angle shows in a moment."
        : "No internet: keep going. Your movements are saved on this phone and sent when the internet is back. The count stops until then.";
    }
  });
}

function wellDone(index) {
  saveStep("welldone", index);
  buzz([120, 80, 120]);
  say("Well done!");
  screen(el("h1", { class: "welldone" }, "Well done!"),
    el("p", { class: "lead" }, "Rest a moment, then say how it was."),
    big("Next", { id: "next", onclick: () => rateExercise(index) }));
  let left = 3;
  every(1000, () => { if (left-- <= 0) rateExercise(index); });
}

/** The session's end: the patient's, or the therapist's (closed on their page while the
 * phone streamed it: the phone sends the rest and records no more). */
async function finished() {
  kit.weekAsked = false;
  const byTherapist = Boolean(kit.stream.state && kit.stream.state.closedByTherapist);
  saveStep("finished", 0);
  const done = KitProgram.done(exercisesForKit(), kit.did);
  localStorage.setItem(LAST_KEY, JSON.stringify({ at: Date.now(),
    lines: [...done.children].map((li) => li.textContent),
    session: (kit.stream.state && kit.stream.state.session) || null }));
  const info = el("p", { class: "lead", id: "sent" }, "Sending your session…");
  // this week's count with this session in it: asked again once all of it is stored
  const week = el("p", { class: "week", id: "this-week", hidden: "" }, "");
  screen(el("h1", { class: "welldone" }, byTherapist ? "Session ended" : "Session finished"),
    el("p", {}, byTherapist ? "Your therapist ended this session. Thank you — what you did is saved."
      : "Thank you. Your therapist will see it."),
    kit.today.program && KitProgram.next(exercisesForKit())
      ? el("p", { class: "lead", id: "next-time" }, KitProgram.next(exercisesForKit())) : null,
    week, el("h2", { class: "question" }, "What you did"), done, info,
    // only once all is sent: a new session starts a new outbox
    big("Start another session", { id: "again", class: "big secondary", disabled: "",
      onclick: () => { localStorage.removeItem(STEP_KEY); welcome(); } }));
  say(byTherapist ? "Your therapist ended this session. Thank you." : "Session finished. Well done!");
  await kit.stream.finish();
  every(300, () => {
    const s = kit.stream;
    info.textContent = s.state.finished ? "All sent ✓"
      : s.connected ? `Sending… ${s.unsent} to go`
        : "Saved on this phone, will send when online.";
    if (s.state.finished) {
      localStorage.removeItem(STEP_KEY);
      document.getElementById("again").removeAttribute("disabled");
      letSleep();
      if (!kit.weekAsked) { kit.weekAsked = true; weekNow(week); }
    }
  });
}

/** This week's count once the session is stored (device-today's this_week, which counts
 * it from then on): shown in `line` and kept for the next welcome; nothing is said
 * offline or from a server that does not count (no guess of the server's week). */
async function weekNow(line) {
  const today = await loadToday();
  if (today.offline || today.revoked || !today.this_week) return;
  kit.today.this_week = today.this_week;
  const words = KitProgram.week(today.this_week);
  if (words) { line.textContent = words; line.hidden = false; }
}

/** The server stopped taking this phone's readings (too many of them refused, close 4429
 * after ready): trying again would not help, so the kit stops and says, in plain words,
 * what happened and what to do. The server's own words follow, for the therapist. */
function stopped({ reason, lastRefused }) {
  screen(el("h1", {}, "Sending stopped"),
    el("p", { class: "lead", id: "stopped" },
      "The server stopped taking readings from this phone, because too many of them could not be used."),
    el("p", { class: "lead" }, "Please stop the exercises for now and contact your therapist. Show them this screen."),
    el("p", {}, "Your readings so far are saved (those not sent yet, on this phone). Your therapist will tell you when to open this page again."),
    el("p", { class: "note", id: "stopped-reason" },
      "For your therapist: " + (reason || "close 4429") + (lastRefused ? ` (last refused: ${lastRefused})` : "")));
  say("Sending stopped. Please contact your therapist.");
  letSleep();
}

// -- start, resume -----------------------------------------------------------------------
async function loadToday() {
  try {
    const answer = await fetch("/api/device/today", { headers: { Authorization: "Bearer " + kit.token } });
    if (answer.status === 401) return { revoked: true };
    if (!answer.ok) throw new Error(answer.statusText);
    const today = await answer.json();
    localStorage.setItem(TODAY_KEY, JSON.stringify(today));
    return today;
  } catch (_) {
    const kept = localStorage.getItem(TODAY_KEY);
    return { ...(kept ? JSON.parse(kept) : { exercises: FALLBACK_EXERCISES, side: "right" }), offline: true };
  }
}

async function resume(kept) {
  kit.sensor = kept.sensor;
  kit.side = kept.side;
  const step = JSON.parse(localStorage.getItem(STEP_KEY) || "null") || { phase: "npose", index: 0 };
  kit.stream = newStream(kept.program);
  await kit.stream.start({ resume: true });
  const go = async () => {
    if (!await motionAllowed()) return motionRefused();
    listen();
    await keepAwake();
    if (kit.stream.ended || step.phase === "finished") return finished();
    if (step.phase === "exercise") return exercise(step.index, step.set || 0, true);
    if (step.phase === "rest") return restBetweenSets(step.index, step.set);
    if (step.phase === "welldone" || step.phase === "rating") return rateExercise(step.index);
    if (step.phase === "intro") return exerciseIntro(step.index);
    if (step.phase === "lower") return lowerArm();
    return calibrationPose(step.phase === "tpose" ? "tpose" : "npose");
  };
  const needsTap = window.DeviceMotionEvent && typeof DeviceMotionEvent.requestPermission === "function";
  if (needsTap) {
    screen(el("h1", {}, "Continue your session"),
      el("p", { class: "lead" }, "Your session was interrupted. Nothing recorded is lost."),
      big("Continue", { id: "continue", onclick: go }));
  } else {
    await go();
  }
}

/** The session kept on this phone was recorded under another kit's link (a phone lent in
 * turn: state.token, kit-stream.js): it goes with that link, to that patient's session,
 * never with the link open now, and ends there. Resolves once all of it is sent; this
 * link's welcome follows. Offline, it waits on the phone and goes when online. Its own
 * link revoked, a resume is tried with the link open now (the same patient's new link
 * takes it; the server refuses another patient's, storing nothing); refused that way too,
 * or erased on the server, the screen says so and "Continue" drops it from the phone. */
function sendTheLastPatients(kept) {
  noStatus();  // the bar would show the other link's state as this one's
  screen(el("h1", {}, "Sending the last session on this phone"),
    el("p", {}, "This phone keeps readings of a session recorded with another link (another "
      + "patient's, or an older one). They go to that session first; then yours can start."));
  return sendAndEnd(kept, {
    lost: "The other patient's link was replaced or removed, so what was left of their session "
      + "on this phone cannot be sent. Their therapist has everything sent before.",
    erased: "The other patient's therapist erased that session, so what was left of it on this phone is not sent." });
}

/** When the session kept on this phone had its last reading [Date], or null when it
 * was within CARRY_ON_WITHIN_S (it is carried on). On the wall clock (lastWall): the
 * session's own clock (t = seconds since startEpoch plus clockShift, kit-stream.js) stops
 * while the phone sleeps, so a session locked between sets would seem to have stopped
 * that much earlier; a session kept before lastWall was: its own clock. */
function stoppedLongAgo(kept) {
  const last = (Number.isFinite(kept.lastWall) ? kept.lastWall
    : kept.startEpoch + (kept.lastT || 0) - (kept.clockShift || 0)) * 1000;
  return Number.isFinite(last) && Date.now() - last > CARRY_ON_WITHIN_S * 1000 ? new Date(last) : null;
}

/** This link's own session, cut short long ago (stoppedLongAgo): sent as it is and ended
 * (bye: the therapist's page shows it finished and estimated, not interrupted); the
 * welcome follows and says so. Offline it waits on the phone, and the patient may carry
 * on with that session instead (as before: nothing can be sent meanwhile). */
async function endTheStaleSession(kept, at) {
  const when = `${dayWords(at, "on ")} at ${at.toLocaleTimeString(undefined, { hour: "numeric", minute: "2-digit" })}`;
  screen(el("h1", {}, "Sending your last session"),
    el("p", { class: "lead" }, `Your last session, ${when}, stopped part way (the page was closed or the phone switched off). `
      + "What you did then is sent to your therapist as it is; then today's session starts afresh, with the arm poses."));
  const carryOn = big("Carry on with that session instead", { id: "carry-on", class: "big secondary", hidden: "",
    onclick: () => { sessionStorage.setItem(CARRY_ON_KEY, "1"); location.reload(); } });
  const sent = sendAndEnd(kept, {
    lost: "This link was replaced or removed, so what was left of that session on this phone cannot be sent. Your therapist has everything sent before.",
    erased: "Your therapist erased that session, so what was left of it on this phone is not sent.",
    offline: () => { carryOn.hidden = false; },
    online: () => { carryOn.hidden = true; } });
  document.getElementById("screen").append(carryOn);
  await sent;
  kit.notice = `Your last session, ${when}, stopped part way. What you did then was sent to your therapist.`;
}

/** Sends the kept session's rest with its own link and ends it (bye); resolves once all of
 * it is sent, the phone's storage of it cleared. ``words.lost``: what the screen says when
 * its link was revoked, ``words.erased``: when its session was erased (then "Continue"
 * drops it); ``words.offline()``: called while it cannot be sent (then it is ended only
 * once the server is reached, ``words.online()`` called then). */
function sendAndEnd(kept, words) {
  const info = el("p", { class: "lead", id: "handover" }, "Sending…");
  document.getElementById("screen").append(info);
  kit.stream = new KitStream({ token: kept.token || kit.token, sensor: kept.sensor, side: kept.side,
    device: PHONE_KIT, program: kept.program });
  return new Promise((resolve, reject) => {
    const done = () => {
      clearInterval(id);
      const sent = kit.stream;
      kit.stream = null;
      kit.did = {};
      localStorage.removeItem(DID_KEY);
      localStorage.removeItem(STEP_KEY);
      document.getElementById("status").hidden = false;
      // nothing of that session stays on this phone: another link's token would let
      // whoever holds the phone send readings into that patient's record (after its last save)
      sent._saving.then(() => KitStore.clear()).then(resolve, reject);
    };
    let viaThisLink = false;  // its own link revoked: resumed with this one (see below)
    let offlineTicks = 0;     // 300 ms each without a connection
    const id = setInterval(() => {
      const s = kit.stream;
      if (s.state && s.state.finished && !s.error) return done();
      if (/revoked/.test(s.error || "") && !viaThisLink && s.state && s.state.stream) {
        // its link was replaced: the link open now may be the same patient's new one. The
        // server resumes a stream for its own patient only and refuses it (nothing
        // stored) for another's, so a resume cannot land in another patient's session
        viaThisLink = true;
        s.token = kit.token;
        s.error = null;
        s.connect();
        return;
      }
      if ((s.state && s.state.finished) || /revoked/.test(s.error || "")) {
        clearInterval(id);
        info.textContent = viaThisLink || /revoked/.test(s.error || "") ? words.lost : words.erased;
        info.after(big("Continue", { id: "continue", onclick: async () => {
          if (!s.state.finished) {  // revoked, kept until now: it goes from this phone
            s._abandon();
            await s._saving;
          }
          done();
        } }));
        return;
      }
      info.textContent = s.connected ? `Sending… ${s.unsent} to go` : "Saved on this phone, will send when online.";
      if (words.offline && !finishing) {
        if (s.connected) finishOnce();
        else if (++offlineTicks > 10) words.offline();
      }
    }, 300);
    // with words.offline, the session is ended (kept so on the phone) only once the server
    // is reached: until then the patient may still choose to carry on with it
    let finishing = false;
    const finishOnce = () => {
      finishing = true;
      if (words.online) words.online();
      kit.stream.finish().catch(reject);
    };
    kit.stream.start({ resume: true }).then(() => { if (!words.offline) finishOnce(); }).catch(reject);
  });
}

/** How long the question whether to change links waits for the server's names [ms]. */
const ASK_MS = 8000;
/** What the server says a kit token is for: {device, first} (the kit's name, the patient's
 * first name); {revoked: true} when it does not take the token (nothing more is told);
 * {offline: true} when it cannot be asked (within ASK_MS). */
async function whoseKit(token) {
  try {
    const answer = await fetch("/api/device/today", { headers: { Authorization: "Bearer " + token },
      signal: AbortSignal.timeout(ASK_MS) });
    if (answer.status === 401) return { revoked: true };
    if (!answer.ok) return { offline: true };
    const today = await answer.json();
    return { device: today.device, first: today.patient_first_name };
  } catch (_) { return { offline: true }; }
}

/** "Anna's exercises, kit “Anna's phone”", or null when nothing is known. */
function kitWords(who) {
  if (!who || (!who.device && !who.first)) return null;
  return (who.first ? `${who.first}'s exercises` : "exercises") + (who.device ? `, kit “${who.device}”` : "");
}

/** A link of another kit opened on a phone that holds one: anyone can send a patient a
 * link, and taking it silently let the sender make the phone stream into a kit they
 * control. Resolves "replace" (the patient said so, or the phone's own link no longer
 * works: nothing to keep), "keep" (the patient said no) or "dead" (the link opened does
 * not work: it replaces nothing and is told nothing). */
async function askToReplace(held, given) {
  noStatus();
  screen(el("h1", {}, "Checking the link…"));
  const [old, next] = await Promise.all([whoseKit(held), whoseKit(given)]);
  if (old.revoked) return "replace";
  if (next.revoked) return "dead";
  const cached = JSON.parse(localStorage.getItem(TODAY_KEY) || "null");
  const oldWho = old.offline ? cached && { device: cached.device, first: cached.patient_first_name } : old;
  return new Promise((resolve) => screen(
    el("h1", {}, "Change this phone's exercise link?"),
    el("p", { class: "lead", id: "held-kit" }, "This phone is set up for " + (kitWords(oldWho) || "your exercises") + "."),
    el("p", { class: "lead", id: "new-kit" }, next.offline
      ? "The link you just opened is for another kit (it cannot be checked now: no connection)."
      : "The link you just opened is for " + kitWords(next) + "."),
    el("p", {}, "Change only if your therapist gave you this new link. If you are not sure who sent it, keep your link and ask your therapist."),
    big("Keep my link", { id: "keep-kit", onclick: () => resolve("keep") }),
    big("Use the new link", { id: "replace-kit", class: "big secondary", onclick: () => resolve("replace") })));
}

async function main() {
  // a new link opened in this tab changes only the fragment (no page load): start again
  // with it, as on a fresh open (it was left on "Open your link", a revoked link's screen or
  // the question whether to change to another kit's link)
  window.addEventListener("hashchange", () => {
    if (new URLSearchParams(location.hash.slice(1)).get("token")) location.reload();
  });
  const fragment = new URLSearchParams(location.hash.slice(1));
  const given = fragment.get("token");
  if (given) {
    history.replaceState(null, "", location.pathname);  // the token leaves the address bar
    // a link cut short does not take the place of the phone's working one; another kit's
    // link takes it only once the patient says so (askToReplace), and starts without the
    // last session's list: it was that kit's patient's
    const held = localStorage.getItem(TOKEN_KEY);
    if (TOKEN_SHAPE.test(given) && given !== held) {
      const answer = held ? await askToReplace(held, given) : "replace";
      document.getElementById("status").hidden = false;
      if (answer === "dead") {
        noStatus();
        return screen(el("h1", {}, "This link no longer works"),
          el("p", { class: "lead", id: "dead-link" }, "The link you opened was replaced or removed. Your exercise kit on this phone stays as it was."),
          big("Go to your exercises", { id: "to-kit", onclick: () => location.reload() }));
      }
      if (answer === "replace") {
        // the last link's patient's: their session's list, their recent sessions and
        // their program (with the therapist's note), which an offline welcome would show
        localStorage.removeItem(LAST_KEY);
        localStorage.removeItem(TODAY_KEY);
        localStorage.setItem(TOKEN_KEY, given);
      }
    }
  }
  kit.token = localStorage.getItem(TOKEN_KEY);
  if (given && !TOKEN_SHAPE.test(given)) return cutLink();
  if ("serviceWorker" in navigator) {
    navigator.serviceWorker.register("/kit-sw.js", { scope: "/kit" }).catch(() => {});
  }
  window.addEventListener("pagehide", () => { if (kit.stream) kit.stream.keepTail(); });
  window.addEventListener("online", status);
  window.addEventListener("offline", status);
  document.addEventListener("visibilitychange", () => {
    if (document.visibilityState === "hidden") kit.hiddenAt = Date.now();
    else {
      if (kit.hiddenAt && kit.stream && kit.stream.state && !kit.stream.ended) {
        const gap = (Date.now() - kit.hiddenAt) / 1000;
        kit.gaps.push(gap);
        const bar = document.getElementById("gap");
        bar.textContent = `Paused for ${Math.round(gap)} s while the screen was off. Everything before is saved; keep the screen on during the exercises.`;
        bar.hidden = false;
      }
      kit.hiddenAt = null;
      keepAwake();
    }
  });
  status();
  await holdTheKit();
  if (!kit.token) return noLink();
  let kept = await KitStore.getState("stream");
  if (kept && kept.token && kept.token !== kit.token) {
    // another link's session: sent with its own link (unsent), then gone from the phone
    // with that link's token (a finished one kept it until a new session started here)
    if (!kept.finished && kept.stream !== undefined) await sendTheLastPatients(kept);
    else await KitStore.clear();
    kept = null;
  }
  kit.today = await loadToday();
  if (kit.today.revoked) {
    noStatus();
    return screen(el("h1", {}, "This link no longer works"),
      el("p", { class: "lead" }, "Your therapist has replaced or removed it. Ask them for a new link."));
  }
  kit.side = kit.today.side || "right";
  // a session under way goes on (its stream's resume is taken: docs/extensions/discharge.md),
  // unless it was cut short long ago: then it is ended and the day starts afresh
  if (kept && !kept.finished && kept.stream !== undefined) {
    const at = stoppedLongAgo(kept);
    const carryOn = sessionStorage.getItem(CARRY_ON_KEY);
    sessionStorage.removeItem(CARRY_ON_KEY);
    if (!at || carryOn) return resume(kept);
    await endTheStaleSession(kept, at);
  }
  if (kit.today.discharged) {  // offline: as the server last said
    noStatus();
    return screen(el("h1", {}, "Your therapist has discharged you"),
      el("p", { class: "lead", id: "discharged" }, "This link starts no new session now. Everything you recorded is kept with your therapist."),
      el("p", {}, "If you should go on with the exercises, ask your therapist to readmit you: this same link then works again."));
  }
  welcome();
}

main().catch((error) => {
  screen(el("h1", {}, "Something went wrong"), el("p", { class: "lead" }, String(error.message || error)));
});

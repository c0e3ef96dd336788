// The live page follows the patient, not one session: the exercise going on with its
// repetitions, the day's sessions, and the next session when the patient starts one
// (the page moves to it by itself after a short notice, unless the therapist stays).
// Hooks: session.js calls LiveFollow.live(status) on each live poll of this session,
// LiveFollow.watch() once this session is over or when it opens as a replay.
"use strict";

const LiveFollow = (() => {
  const FOLLOW_KEY = "armtrack.follow.";
  const MOVE_AFTER_S = 5;
  const LAG_SHOWN_S = 2;    // a count further behind the stream than this says so
  let current = null;       // this page's session
  let watching = false;
  let offered = null;       // the newer session offered
  let countdown = null;

  function followKey() { return FOLLOW_KEY + current.patient_id; }

  function start(sessionRecord) {
    current = sessionRecord;
    if (current.status !== "closed") sessionStorage.setItem(followKey(), "1");
    history().catch(() => {});
  }

  // ------------------------------------------------------------ the exercise now
  function exerciseBox() {
    let box = document.getElementById("exercise-now");
    if (!box) {
      box = el("div", { class: "card exercise-now", id: "exercise-now", "aria-live": "polite" },
        el("div", { class: "label" }, "Exercise now"),
        el("div", { class: "row", style: "align-items:baseline;gap:14px;flex-wrap:wrap" },
          el("div", { class: "name", id: "exercise-name" }, "—"),
          el("div", { class: "reps", id: "exercise-reps" }, "")),
        el("div", { class: "muted small", id: "exercise-how" }, ""));
      const angles = document.getElementById("angles-card");
      angles.parentNode.insertBefore(box, angles);
    }
    return box;
  }

  function live(status) {
    exerciseBox();
    const exercise = status.exercise;
    const name = document.getElementById("exercise-name");
    const reps = document.getElementById("exercise-reps");
    const how = document.getElementById("exercise-how");
    if (!exercise) {
      name.textContent = status.estimating ? "No exercise going on" : "Calibrating";
      reps.textContent = "";
      how.textContent = status.estimating ? "Repetitions are counted as soon as a movement repeats." : "";
      return;
    }
    name.textContent = exercise.label;
    // repetitions done (live-exercise.md): a both-ways repetition counts once its turn the
    // other way comes, not with its first turn (a server of before sends only repetitions)
    const done = typeof exercise.repetitions_done === "number" ? exercise.repetitions_done : exercise.repetitions;
    // "one under way" apart, smaller and whole: at 390 px the large count broke it in two
    clear(reps, `${done} ${done === 1 ? "repetition" : "repetitions"}`,
      exercise.repetitions > done ? [" ", el("span", { class: "under-way" }, "one under way")] : null);
    const streamT = status.calibration ? status.calibration.stream_time_s : null;
    const behind = exercise.counted_to_s === null || exercise.counted_to_s === undefined || streamT === null
      ? null : streamT - exercise.counted_to_s;
    how.textContent = (exercise.source === "marks"
      ? `marked by the kit at ${exercise.since_s.toFixed(0)} s`
      : "found in the movement (no exercise mark)")
      + (behind !== null && behind > LAG_SHOWN_S ? ` · counted up to ${behind.toFixed(0)} s ago (the server is catching up)` : "");
  }

  // ------------------------------------------------------------ the day's sessions
  function sameDay(a, b) {
    const zone = (CLINIC && CLINIC.time_zone) || undefined;
    const day = (d) => new Date(d).toLocaleDateString("en-CA", { timeZone: zone });
    return day(a) === day(b);
  }

  // The session's own day in the clinic's zone, as a heading writes it ("Thu, Dec 3"; with
  // the year when it is not this year's).
  function dayWords(moment) {
    const zone = (CLINIC && CLINIC.time_zone) || undefined;
    const year = (d) => new Date(d).toLocaleDateString("en-CA", { timeZone: zone, year: "numeric" });
    return parseMoment(moment).toLocaleDateString(undefined, { weekday: "short", month: "short",
      day: "numeric", timeZone: zone, ...(year(parseMoment(moment)) !== year(Date.now()) ? { year: "numeric" } : {}) });
  }

  // The summaries of the sessions of `day`'s day, oldest first. The light session list is
  // read back (newest first, DAY_PAGE at a time, at most DAY_PAGES pages) until it starts
  // before that day; then the summaries of that stretch of the list only, one either side
  // (a session begun meanwhile shifts the list by one). Each summary is built from its
  // session's report: reading back every newer session's (up to 300) to show one day's few
  // cost the server the reports of them all.
  const DAY_PAGE = 30, DAY_PAGES = 10;
  async function sessionsOfDay(day) {
    let first = null, last = null;  // the day's sessions' places in the list (newest: 0)
    for (let page = 0; page < DAY_PAGES; page += 1) {
      const some = await api(`/api/patients/${current.patient_id}/sessions?limit=${DAY_PAGE}&offset=${page * DAY_PAGE}`);
      some.forEach((s, k) => {
        if (!sameDay(parseMoment(s.started_at), day)) return;
        if (first === null) first = page * DAY_PAGE + k;
        last = page * DAY_PAGE + k;
      });
      const oldest = some.length ? parseMoment(some[some.length - 1].started_at) : null;
      if (some.length < DAY_PAGE || (oldest < day && !sameDay(oldest, day))) break;
    }
    if (first === null) return [];
    const offset = Math.max(0, first - 1);
    const found = await api(`/api/patients/${current.patient_id}/summaries?limit=${Math.min(200, last + 2 - offset)}&offset=${offset}`);
    return found.filter((s) => sameDay(parseMoment(s.started_at), day)).reverse();
  }

  // The sessions of this session's day (a replay of last Thursday: Thursday's, not today's).
  async function history() {
    const day = parseMoment(current.started_at);
    const isToday = sameDay(day, Date.now());
    const today = await sessionsOfDay(day);
    let card = document.getElementById("day-history");
    if (!today.length) { if (card) card.remove(); return; }
    if (!card) {
      card = el("div", { class: "card day-history", id: "day-history" });
      const main = document.querySelector("main");
      main.insertBefore(card, document.getElementById("calibration"));
    }
    const times = fmtSessionTimes(today.map((s) => s.started_at));
    clear(card, el("h2", {}, isToday ? "Today's sessions" : `Sessions of ${dayWords(current.started_at)}`),
      el("div", { class: "row", style: "gap:8px;flex-wrap:wrap" }, today.map((s, k) => el(
        s.id === current.id ? "span" : "a",
        { class: "chip day-session" + (s.id === current.id ? " current" : ""),
          href: s.id === current.id ? null : "/sessions/" + s.id, dataset: { session: s.id } },
        times[k].replace(/^.*?(\d{1,2}:\d{2}.*)$/, "$1"), " · ",
        s.status === "live" ? "live now" : s.status === "interrupted" ? "interrupted"
          : (s.exercises.length ? exerciseChipTexts(s.exercises).join(", ") : fmtDuration(s.duration_s))))));
  }

  // ------------------------------------------------------------ the next session
  function offer(next) {
    if (offered === next.id) return;
    offered = next.id;
    const auto = sessionStorage.getItem(followKey()) === "1";
    let left = MOVE_AFTER_S;
    const text = el("span", { id: "next-session-text" });
    const banner = el("div", { class: "next-session", id: "next-session", role: "alert" },
      el("b", {}, "The patient started a new session"), text,
      el("a", { href: "/sessions/" + next.id, id: "open-next" }, el("button", {}, "Open the live session →")),
      auto ? el("button", { class: "secondary", id: "stay-here", onclick: () => {
        clearInterval(countdown); countdown = null;
        sessionStorage.removeItem(followKey());
        text.textContent = " (session " + next.id + ")";
        document.getElementById("stay-here").remove();
      } }, "Stay on this one") : null);
    document.getElementById("next-session")?.remove();
    document.querySelector("main").prepend(banner);
    if (!auto) { text.textContent = ` (session ${next.id}, live now)`; return; }
    const tick = () => {
      text.textContent = ` — following it in ${left} s`;
      if (left-- <= 0) { clearInterval(countdown); location.href = "/sessions/" + next.id; }
    };
    tick();
    countdown = setInterval(tick, 1000);
  }

  function newer(status) {
    if (status && status.session && status.session.id > current.id && status.session.status === "live") {
      offer(status.session);
      return true;
    }
    return false;
  }

  // after this session: ask about the patient until a new session starts
  function watch() {
    if (watching) return;
    watching = true;
    const ended = current.ended_at ? Date.parse(current.ended_at) : Date.now();
    if (Date.now() - ended > 6 * 3600 * 1000) sessionStorage.removeItem(followKey());
    let seen = undefined;
    const poll = async () => {
      try {
        const status = await api(`/api/patients/${current.patient_id}/live`);
        newer(status);
        const id = status.session ? status.session.id : null;
        if (seen !== undefined && id !== seen) history().catch(() => {});
        seen = id;
      } catch (_) { /* try again */ }
      setTimeout(poll, 1500);
    };
    poll();
  }

  return { start, live, newer, watch, history };
})();

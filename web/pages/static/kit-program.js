// armtrack phone kit: the therapist's program in the guided session (docs/programs.md) —
// the program's welcome (its name, whether the therapist changed it, its exercises with
// their dose), after each exercise the effort (Borg CR10) and pain (numeric rating scale)
// screen sent as effort-pain/1 (docs/extensions/effort-pain.md), and what was done, at
// the end. Uses kit.js's `el` (loaded after this file; called only once the page runs).
// Every text is set as text, never as HTML.
"use strict";

/** Borg CR10's verbal anchors (Borg 1998, "Borg's perceived exertion and pain scales"). */
const BORG_WORDS = { 0: "Nothing at all", 1: "Very light", 2: "Light", 3: "Moderate",
  5: "Hard", 7: "Very hard", 10: "Maximal" };
/** Numeric rating scale's anchors. */
const PAIN_WORDS = { 0: "No pain", 10: "Worst pain imaginable" };

/** The words for each side of a both-ways angle a phone may show, [negative, positive]
 * in docs/spec/kinematics.md's signs (``KitProgram.angleWords``). */
const ANGLE_SIDES = {
  forearm_pronation: ["palm up", "palm down"],
  shoulder_rotation: ["hand out", "hand in"],
  wrist_flexion: ["hand up", "hand down"],
};

const KitProgram = {
  /** "2 sets of 10 · hold 2 seconds · rest 20 seconds between sets", in the patient's
   * words (the rest only when there are sets). */
  dose(ex) {
    const sets = ex.sets || 1;
    const seconds = (n) => `${n} ${n === 1 ? "second" : "seconds"}`;
    const parts = [sets > 1 ? `${sets} sets of ${ex.repetitions}` : `${ex.repetitions} times`];
    if (ex.hold_s) parts.push(`hold ${seconds(ex.hold_s)}`);
    if (sets > 1 && ex.rest_s) parts.push(`rest ${seconds(ex.rest_s)} between sets`);
    return parts.join(" · ");
  },

  /** How often the therapist prescribed `ex`: "5 days a week", "every day"; null without
   * a program (or from an older server, which did not say). */
  often(ex) {
    const days = ex.days_per_week;
    if (!days) return null;
    return days === 7 ? "every day" : `${days} ${days === 1 ? "day" : "days"} a week`;
  },

  /** What comes next, for the finished screen, from the program the phone already has:
   * how often the therapist asks for the exercises ("Next: your therapist asks for these
   * exercises 5 days a week."; each its own where they differ); null without a program
   * (or from an older server, which did not say how often). Nothing is guessed: the
   * phone does not know the patient's other sessions of the week. */
  next(exercises) {
    const often = exercises.filter((ex) => ex.days_per_week)
      .map((ex) => ({ title: ex.title, words: KitProgram.often(ex) }));
    if (!often.length) return null;
    if (often.length === exercises.length && often.every((o) => o.words === often[0].words))
      return `Next: your therapist asks for ${often.length > 1 ? "these exercises" : often[0].title} ${often[0].words}.`;
    return "Next: your therapist asks for " + often.map((o) => `${o.title} ${o.words}`).join(", ") + ".";
  },

  /** Where the patient stands this week, in plain and kind words, from device-today's
   * `this_week` (the therapist's adherence count: days with a session of the program,
   * against the days asked): "This week: 2 of 5 days done."; none yet: "This week: 0 of
   * 5 days done. Today is a good day to start."; a week the program starts or ends in says
   * why it asks fewer days: "This week: 0 of 2 days done (your program started on
   * Saturday)."; a week whose days were changed meanwhile, that the change counts from
   * next week; all: "You have done all 5 days this week
   * — well done."; null without it (no program, or an older server). */
  week(w) {
    if (!w || !w.days_asked) return null;
    const days = (n) => `${n} ${n === 1 ? "day" : "days"}`;
    if (w.days_done >= w.days_asked)
      return w.days_asked === 1 ? "You have done your day this week — well done."
        : `You have done all ${w.days_asked} days this week — well done.`;
    const line = `This week: ${w.days_done} of ${days(w.days_asked)} done${KitProgram.why(w)}.`;
    return w.days_done ? line : `${line} Today is a good day to start.`;
  },

  /** Why this week asks other days than the list's "5 days a week" (device-today's
   * this_week: `shortened`, the program starts or ends within the week; `changed_on`, a
   * change of its days saved this week, which counts from next week as the therapist's
   * adherence counts it), in words to append: " (your program started on Saturday)",
   * " (its change of Thursday counts from next week)"; "" when neither. */
  why(w) {
    const weekday = (iso) => {
      const [y, m, d] = iso.split("-").map(Number);
      return new Date(y, m - 1, d).toLocaleDateString(undefined, { weekday: "long" });
    };
    const shortened = w.shortened || {};
    const parts = [];
    if (shortened.starts_on) parts.push(`your program started on ${weekday(shortened.starts_on)}`);
    else if (shortened.ends_on) parts.push(`your program ends on ${weekday(shortened.ends_on)}`);
    if (w.changed_on) parts.push(`${parts.length ? "its" : "your program's"} change of ${weekday(w.changed_on)} counts from next week`);
    return parts.length ? ` (${parts.join("; ")})` : "";
  },

  /** Whether a phone on `segment` measures exercise `ex` (device-today's measured_by;
   * an older server's answer: the exercise's sensor). */
  measuredOn(ex, segment) {
    return Array.isArray(ex.measured_by) ? ex.measured_by.includes(segment) : ex.sensor === segment;
  },

  /** Where the phone goes for `ex`, in words. */
  where(ex) {
    const on = Array.isArray(ex.measured_by) ? ex.measured_by : [ex.sensor];
    if (!on.length) return "not measured by a phone";
    return "phone on the " + on.map((s) => SEGMENT_WORDS[s] || s).join(" or ");
  },

  /** The program's exercises a phone on `segment` does not measure, and why (the
   * server's sentences); null when it measures them all. */
  skipped(exercises, segment) {
    const left = exercises.filter((ex) => !KitProgram.measuredOn(ex, segment));
    if (!left.length) return null;
    return el("div", { class: "skipped", id: "skipped" },
      `Not in this session: with the phone on your ${SEGMENT_WORDS[segment] || segment}, these are left out.`,
      el("ul", {}, left.map((ex) => el("li", {},
        (ex.not_measured && ex.not_measured[segment]) || `${ex.title}: ${KitProgram.where(ex)}.`))));
  },

  /** The welcome's part for a program: its name, whether the therapist changed it, and
   * today's exercises. */
  summary(today, exercises) {
    const program = today.program;
    return [
      el("p", { class: "kicker" }, "From your therapist"),
      el("h1", { id: "program-name" }, program.name),
      // a number says nothing to a patient: only that the therapist changed it
      program.version > 1 ? el("p", { class: "note", id: "program-version" },
        "Changed by your therapist" + (program.changed_at ? " " + dayWords(new Date(program.changed_at), "on ") : "")) : null,
      program.note ? el("p", { class: "lead", id: "program-note" }, program.note) : null,
      // this week's count only from the server's answer of now: a kept one may be last week's
      today.this_week && !today.offline && KitProgram.week(today.this_week)
        ? el("p", { class: "week", id: "this-week" }, KitProgram.week(today.this_week)) : null,
      el("ol", { class: "program", id: "program-list" }, exercises.map((ex) =>
        el("li", {}, el("span", { class: "title" }, ex.title),
          el("span", { class: "dose" }, [KitProgram.dose(ex), KitProgram.often(ex),
            KitProgram.where(ex)].filter(Boolean).join(" · "))))),
    ];
  },

  /** What the patient did, for the finished screen: per exercise of the session, the
   * repetitions its screen counted (all sets) against the prescribed ones, and the range
   * of the angles it showed [deg] beside the target; "not done" when it showed none.
   * `did`: per exercise index, { reps: { set: count }, lo, hi } (kit.js's noteDone). */
  done(exercises, did) {
    return el("ul", { class: "did", id: "did" }, exercises.map((ex, i) => {
      const d = did[i] || {};
      const reps = Object.values(d.reps || {}).reduce((a, b) => a + b, 0);
      return el("li", {}, KitProgram.didLine(ex.title, reps, (ex.sets || 1) * ex.repetitions,
        d.lo, d.hi, ex.target, ex.angle));
    }));
  },

  /** An angle [deg] as the patient reads it: a turn both ways in words, never a signed
   * number ("45° palm up", "70° palm down"), as docs/spec/kinematics.md signs them
   * (`forearm_pronation`: pronation +, the palm turned down; supination −, up;
   * `shoulder_rotation`: internal +, the hand in; `wrist_flexion`: flexion +, the hand
   * down); 0° and any other angle as the number ("112°"). The therapist's pages and the
   * API keep the signed numbers. */
  angleWords(angle, deg) {
    return KitProgram.angleParts(angle, deg).filter(Boolean).join(" ");
  },

  /** ``angleWords`` in two parts, the number and the side's words ("" when none):
   * ["45°", "palm up"]; the live screen shows the side smaller under the number. */
  angleParts(angle, deg) {
    const n = Math.round(deg);
    const words = ANGLE_SIDES[angle];
    if (!words || n === 0) return [`${n}°`, ""];
    return [`${Math.abs(n)}°`, n > 0 ? words[1] : words[0]];
  },

  /** The band shown beside an exercise: "target 0° to 110°" when the therapist set it
   * (the program's or the patient's target), "usual range 0° to 120°" when nobody did
   * (`from` default or catalogue: the exercise's usual range, which the therapist's
   * report does not call a target either, "Target then: –"); its ends in the words of
   * `angleWords` for the exercise's `angle` ("usual range 70° palm up to 70° palm down"). */
  bandWords(target, angle) {
    const usual = target.from === "default" || target.from === "catalogue";
    return `${usual ? "usual range" : "target"} ${KitProgram.angleWords(angle, target.min_deg)} to `
      + `${KitProgram.angleWords(angle, target.max_deg)}`;
  },

  /** One line of what was done: "Bend the elbow: 8 of 10 repetitions · from 3° to 112°
   * (target 0° to 120°)", or "…: not done" with no repetition and no range; `lo`, `hi`
   * [deg] the range reached (null: none shown), `target` { min_deg, max_deg, from }
   * (``bandWords``), `angle` the exercise's angle (``angleWords``: "from 40° palm up to
   * 60° palm down"). */
  didLine(title, reps, prescribed, lo, hi, target, angle) {
    if (!reps && lo == null) return `${title}: not done`;
    const range = lo == null ? "" : ` · from ${KitProgram.angleWords(angle, lo)} to `
      + `${KitProgram.angleWords(angle, hi)} (${KitProgram.bandWords(target, angle)})`;
    return `${title}: ${reps} of ${prescribed} repetitions${range}`;
  },

  /** The patient's recent sessions (device-today's `recent`, the server's count of each)
   * with the last one kept on this phone (`last`: { at, lines, session }), newest first:
   * [{ at: Date, lines }]. The phone's own words stand for the session it did. */
  recent(served, last) {
    const sessions = (served || []).map((r) => ({ at: new Date(r.started_at), session: r.session_id,
      lines: r.exercises.map((e) => KitProgram.didLine(e.title, e.repetitions, e.prescribed,
        e.min_deg, e.max_deg, e.target, e.angle)) }));
    if (last && last.lines && last.lines.length) {
      const same = sessions.find((r) => last.session != null && r.session === last.session);
      if (same) same.lines = last.lines;
      else sessions.push({ at: new Date(last.at), lines: last.lines });
    }
    return sessions.filter((r) => r.lines.length).sort((a, b) => b.at - a.at).slice(0, 3);
  },

  /** A 0–10 scale of large buttons; `onPick(value)` on a tap. */
  scale(id, words, onPick, kind) {
    const buttons = [];
    const row = el("div", { class: `scale ${kind}`, id, role: "radiogroup" });
    for (let v = 0; v <= 10; v++) {
      const b = el("button", { class: "pick", type: "button", role: "radio", "aria-checked": "false",
        "data-value": String(v), "aria-label": words[v] ? `${v}, ${words[v]}` : String(v) }, String(v));
      b.addEventListener("click", () => {
        for (const other of buttons) other.setAttribute("aria-checked", String(other === b));
        onPick(v);
      });
      buttons.push(b);
      row.append(b);
    }
    const legend = el("div", { class: "legend" },
      el("span", {}, `0 ${words[0]}`), el("span", {}, `${words[10]} 10`));
    return [row, legend];
  },

  /** The effort and pain screen's contents after exercise `ex`: `onDone(effort, pain)`
   * with the answers (null for one not given; both null: skipped). */
  ratingScreen(ex, onDone) {
    let effort = null, pain = null;
    const effortWord = el("p", { class: "word", id: "effort-word" }, "");
    const send = el("button", { class: "big", id: "rating-send", disabled: "" }, "Send");
    const picked = () => { if (effort != null || pain != null) send.removeAttribute("disabled"); };
    send.addEventListener("click", () => onDone(effort, pain));
    return [
      el("p", { class: "kicker" }, ex.title),
      el("h1", {}, "How was it?"),
      el("h2", { class: "question" }, "How hard was it?"),
      ...KitProgram.scale("effort", BORG_WORDS, (v) => {
        effort = v;
        effortWord.textContent = BORG_WORDS[v] || "";
        picked();
      }, "effort"),
      effortWord,
      el("h2", { class: "question" }, "How much pain?"),
      ...KitProgram.scale("pain", PAIN_WORDS, (v) => { pain = v; picked(); }, "pain"),
      el("div", { class: "answer" }, send,
        el("button", { class: "big secondary", id: "rating-skip", onclick: () => onDone(null, null) }, "Skip")),
    ];
  },
};

window.KitProgram = KitProgram;

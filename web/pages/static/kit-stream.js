// armtrack phone kit: the phone's motion sensors as a 6-axis sensor streamed per the
// stream protocol (docs: ingest protocol version 1, docs/phone-kit.md), with every message
// kept in IndexedDB until the server acks it. No framework, no build step.
// Extensions asked in hello (docs/extensions/): feedback/1 (live angle, repetitions),
// programs/1 (the session follows the therapist's program the kit names), effort-pain/1
// (effort and pain after each exercise, kept on the phone until the server stored them),
// closed-session/1 (a session closed while offline: the rest goes as a new session; one
// the therapist closed while it streamed ends here too: the rest goes, nothing more; one
// full at the server's cap ends with bye and the phone goes on in a new session),
// carried-on/1 (that new session names the one it carries on, where the poses were held).
//
// Axes (docs/phone-kit.md): the phone is strapped screen out (away from the skin), its top
// toward the joint above (the elbow for the forearm, the shoulder for the upper arm), on
// the arm's outer side. The W3C device frame (x right of the screen, y toward the top,
// z out of the screen) is then the recording's default sensor frame on that segment
// (+Y proximal along the long axis, +Z out of the skin), so:
//   ax, ay, az = accelerationIncludingGravity.x, .y, .z            [m/s²]
//   gx, gy, gz = rotationRate.beta, .gamma, .alpha × π/180         [rad/s]
// (rotationRate.alpha/beta/gamma are the rates about z/x/y).
"use strict";

const TAIL_KEY = "armtrack.kit.tail";
const EXTENSIONS = ["feedback/1", "programs/1", "effort-pain/1", "closed-session/1", "carried-on/1"];

const KitAxes = {
  /** One DeviceMotionEvent's reading as a row's 6 numbers, or null when incomplete. */
  row(event) {
    const a = event.accelerationIncludingGravity, r = event.rotationRate;
    if (!a || !r || a.x == null || a.y == null || a.z == null
        || r.alpha == null || r.beta == null || r.gamma == null) return null;
    const k = Math.PI / 180;
    const values = [a.x, a.y, a.z, r.beta * k, r.gamma * k, r.alpha * k];
    return values.every(Number.isFinite) ? values : null;
  },
};

// -- storage: IndexedDB "armtrack-kit": "outbox" (seq → message text), "state" (key → value)
const KitStore = {
  db: null,
  async open() {
    if (this.db) return this.db;
    this.db = await new Promise((resolve, reject) => {
      const request = indexedDB.open("armtrack-kit", 1);
      request.onupgradeneeded = () => {
        const db = request.result;
        db.createObjectStore("outbox");
        db.createObjectStore("state");
      };
      request.onsuccess = () => resolve(request.result);
      request.onerror = () => reject(request.error);
    });
    return this.db;
  },
  async tx(stores, mode, work) {
    const db = await this.open();
    return new Promise((resolve, reject) => {
      const tx = db.transaction(stores, mode);
      let result;
      Promise.resolve(work(tx)).then((r) => { result = r; });
      tx.oncomplete = () => resolve(result);
      tx.onerror = () => reject(tx.error);
      tx.onabort = () => reject(tx.error || new Error("storage transaction aborted"));
    });
  },
  req(request) {
    return new Promise((resolve, reject) => {
      request.onsuccess = () => resolve(request.result);
      request.onerror = () => reject(request.error);
    });
  },
  async getState(key) {
    return this.tx(["state"], "readonly", (tx) => this.req(tx.objectStore("state").get(key)));
  },
  async setState(key, value) {
    return this.tx(["state"], "readwrite", (tx) => { tx.objectStore("state").put(value, key); });
  },
  /** Store messages [seq, text] and the state in one transaction (both or neither). */
  async append(messages, state) {
    return this.tx(["outbox", "state"], "readwrite", (tx) => {
      const box = tx.objectStore("outbox");
      for (const [seq, text] of messages) box.put(text, seq);
      tx.objectStore("state").put(state, "stream");
    });
  },
  async dropThrough(seq) {
    return this.tx(["outbox"], "readwrite", (tx) => {
      tx.objectStore("outbox").delete(IDBKeyRange.upperBound(seq));
    });
  },
  async pending(fromSeq) {
    return this.tx(["outbox"], "readonly", async (tx) => {
      const store = tx.objectStore("outbox");
      const range = IDBKeyRange.lowerBound(fromSeq);
      const [keys, values] = await Promise.all([this.req(store.getAllKeys(range)),
                                                this.req(store.getAll(range))]);
      return keys.map((k, i) => [k, values[i]]);
    });
  },
  async count() {
    return this.tx(["outbox"], "readonly", (tx) => this.req(tx.objectStore("outbox").count()));
  },
  async clear() {
    return this.tx(["outbox", "state"], "readwrite", (tx) => {
      tx.objectStore("outbox").clear();
      tx.objectStore("state").delete("stream");
    });
  },
};

/**
 * One recording session of the phone: samples and marks numbered by seq, saved to the
 * outbox before they are sent, sent over /ws/ingest, dropped once acked; reconnects with
 * resume after a lost connection; survives a reload (the state is in IndexedDB).
 *
 * Times: t [s] = (performance.timeOrigin + event.timeStamp) / 1000 − the session's start
 * (epoch seconds kept with the state), so a reload continues the same clock; a reading
 * older than the last kept one is stamped with the last time (t never goes back); a clock
 * set back between two loads is made up by state.clockShift [s] (added to t). That clock
 * stops while a phone sleeps (performance.now() does not tick in sleep but on Windows), so
 * it falls behind the wall clock by every sleep of the session: state.lastWall [epoch s]
 * is the wall clock (Date.now) at the last reading, for how long ago it was taken.
 */
class KitStream {
  constructor({ token, sensor, side, device, program, onChange, onFeedback, onClose, onReady,
                onEndedByTherapist, onStopped }) {
    this.token = token;
    this.sensor = sensor;
    this.side = side;
    this.device = device;
    this.program = program == null ? null : program;  // the program's id (programs/1)
    this.onChange = onChange || (() => {});
    this.onFeedback = onFeedback || (() => {});
    this.onClose = onClose || (() => {});
    this.onReady = onReady || (() => {});
    this.onEndedByTherapist = onEndedByTherapist || (() => {});
    this.onStopped = onStopped || (() => {});
    this.stopped = null;   // {reason, lastRefused}: the server stopped this kit (_stopRefused)
    // {stream, session, nextSeq, startEpoch, lastT, sensor, side, acked, program, ratings,
    // token}; ratings: effort_pain messages not yet stored by the server (effort-pain/1);
    // token: the kit link the session was recorded under (its outbox goes with that one)
    this.state = null;
    this.extensions = [];  // those the server's ready listed
    this.rows = [];        // readings not yet in a message
    this.ws = null;
    this.connected = false;
    this.unsent = 0;       // messages in the outbox (not acked)
    this.closes = 0;       // connections lost (for the page and the tests)
    this.samples = 0;      // readings taken this page load
    this.ended = false;
    this.error = null;
    this._saving = Promise.resolve();
    this._retry = 500;
    this._flushTimer = null;
    this._sent = -1;       // highest seq sent on the current connection
    this._unsaved = new Map();  // seq → message queued, not yet in IndexedDB
    this._storageError = false;  // this.error is a failed save's (cleared by the next save)
    this._retrying = false;
  }

  /** The page is going away (reload, closed tab): what is not in IndexedDB yet — the
   * queued messages and the readings of the last 0.1 s — goes to localStorage at once
   * (it is synchronous); the next start takes it back. */
  keepTail() {
    if (!this.state || this.state.finished) return;
    const tail = [...this._unsaved.entries()].sort((a, b) => a[0] - b[0]);
    let seq = tail.length ? tail[tail.length - 1][0] + 1 : this.state.nextSeq;
    for (let i = 0; i < this.rows.length; i += 1000) {
      tail.push([seq, { type: "samples", seq, sensor: this.sensor, rows: this.rows.slice(i, i + 1000) }]);
      seq += 1;
    }
    if (tail.length) localStorage.setItem(TAIL_KEY, JSON.stringify(tail));
  }

  /** The tail a page going away kept: the messages IndexedDB does not hold yet, again. */
  _takeTail() {
    const kept = JSON.parse(localStorage.getItem(TAIL_KEY) || "[]");
    localStorage.removeItem(TAIL_KEY);
    for (const [seq, message] of kept) {
      if (seq <= this.state.savedThrough) continue;  // its save completed after all
      if (message.type === "samples" && message.rows.length) {
        this.state.lastT = Math.max(this.state.lastT, message.rows[message.rows.length - 1][0]);
      }
      this._queue((n) => ({ ...message, seq: n }));
    }
  }

  /** Start a new session, or continue the one kept on the phone: under the link it was
   * recorded with (state.token), whichever link opened the page (a phone lent in turn). */
  async start({ resume = false } = {}) {
    const kept = await KitStore.getState("stream");
    if (resume && kept && !kept.finished) {
      this.state = kept;
      if (kept.token) this.token = kept.token;
      else this.state.token = this.token;  // kept before the token was: the link open now
      this.sensor = kept.sensor;
      this.side = kept.side;
      this.program = kept.program == null ? null : kept.program;
      this.state.ratings = kept.ratings || [];
      this.ended = Boolean(kept.ended);
      // the outbox holds every seq up to savedThrough; a state saved while later messages
      // were queued (ready, a rating, finish) names a nextSeq past messages that never
      // reached IndexedDB: they are in the tail (or were never taken), numbered from here
      if (kept.savedThrough == null) this.state.savedThrough = kept.nextSeq - 1;
      this.state.nextSeq = this.state.savedThrough + 1;
      this._takeTail();
      // the phone's clock set back while the page was away (a network time fix): the
      // session clock goes on from its last time, not stuck there until the wall clock
      // catches up (every reading stamped alike); clockShift [s] keeps startEpoch as it was
      const behind = this.state.lastT - this._rawTime(performance.now());
      if (behind > 0) this.state.clockShift = (this.state.clockShift || 0) + behind;
    } else {
      localStorage.removeItem(TAIL_KEY);
      await KitStore.clear();
      this.state = { stream: null, session: null, nextSeq: 0, acked: -1,
                     startEpoch: (performance.timeOrigin + performance.now()) / 1000,
                     savedThrough: -1, lastT: 0, sensor: this.sensor, side: this.side, finished: false,
                     program: this.program, ratings: [], token: this.token };
      await KitStore.setState("stream", this.state);
    }
    this.unsent = await KitStore.count();
    this._flushTimer = setInterval(() => this.flush(), 100);
    this.connect();
    return this.state;
  }

  /** Seconds on the session's clock of an event's time stamp [ms since timeOrigin]. */
  time(timeStampMs) {
    return Math.max(this._rawTime(timeStampMs), this.state.lastT);
  }

  _rawTime(timeStampMs) {
    return (performance.timeOrigin + timeStampMs) / 1000 - this.state.startEpoch
      + (this.state.clockShift || 0);
  }

  /** A DeviceMotionEvent: its reading joins the next message. */
  reading(event) {
    if (!this.state || this.ended) return null;
    const values = KitAxes.row(event);
    if (!values) return null;
    const t = this.time(event.timeStamp);
    this.state.lastT = t;
    this.state.lastWall = Date.now() / 1000;
    this.rows.push([t, ...values, null, null, null]);
    this.samples += 1;
    return [t, ...values];
  }

  /** The session clock now [s]. */
  now() { return this.time(performance.now()); }

  /** A mark (npose, end:npose, exercise:<name>, …) at `t` [s, session clock], now by
   * default; a mark may name a time already passed (ingest.md: sent when the clock has
   * passed it). */
  mark(label, t = null) {
    if (!this.state || this.ended) return Promise.resolve();
    this.flush();  // the readings before it go first
    const at = t == null ? this.now() : t;
    this.state.lastT = Math.max(this.state.lastT, at);
    return this._queue((seq) => ({ type: "mark", seq, t: at, label }));
  }

  /** Effort (Borg CR10, 0–10) and pain (NRS 0–10) after an exercise, either null when
   * skipped (docs/extensions/effort-pain.md). Kept on the phone with the stream's state
   * and sent until the server answers effort_pain_stored; its id is unique in the session
   * (the server stores an id once). Resolves once it is saved on the phone. */
  rate(exercise, effort, pain, key) {
    if (!this.state || (effort == null && pain == null)) return Promise.resolve(null);
    const id = `r${Math.round(this.state.startEpoch * 1000)}-${key}`.slice(0, 64);
    if (this.state.ratings.some((r) => r.id === id)) return Promise.resolve(id);
    const message = { type: "effort_pain", id, exercise, t: this.now(), effort, pain };
    this.state.ratings = [...this.state.ratings, message];
    this._saving = this._saving.then(() => KitStore.setState("stream", { ...this.state }))
      .then(() => { this._sendRatings(); this.onChange(this); })
      .catch((error) => { this.error = "could not save on this phone: " + error; this.onChange(this); });
    return this._saving.then(() => id);
  }

  _sendRatings() {
    if (!this.connected || !this.extensions.includes("effort-pain/1")) return;
    for (const rating of this.state.ratings) {
      try { this.ws.send(JSON.stringify(rating)); } catch (_) { return; /* reconnects */ }
    }
  }

  /** The readings so far as one samples message (at most 1000 rows each). */
  flush() {
    while (this.rows.length) {
      const rows = this.rows.splice(0, 1000);
      this._queue((seq) => ({ type: "samples", seq, sensor: this.sensor, rows }));
    }
    if (this._storageError && this._unsaved.size && !this._retrying) {
      // no new message to carry the retry (ended, or no readings): try them again alone
      this._retrying = true;
      const upto = Math.max(...this._unsaved.keys());
      const state = { ...this.state, nextSeq: upto + 1 };
      this._saving = this._saving.then(() => this._save(upto, state)).catch(() => {})
        .then(() => { this._retrying = false; if (this.ended) this._byeWhenDone(); });
    }
    return this._saving;
  }

  _queue(make) {
    const seq = this.state.nextSeq++;
    const message = make(seq);
    const state = { ...this.state };
    this._unsaved.set(seq, message);
    // saved before it is sent, in order; a failed save keeps its messages in _unsaved and
    // the next save takes them again first (the outbox never has a gap in its seqs)
    this._saving = this._saving.then(() => this._save(seq, state)).catch((error) => {
      const full = error && error.name === "QuotaExceededError";
      this.error = full
        ? `This phone's storage is full: ${this._unsaved.size} messages wait in memory and ` +
          "are saved and sent as soon as there is room. Keep this page open; free some space on the phone."
        : "could not save on this phone: " + error;
      this._storageError = true;
      this.onChange(this);
    });
    return this._saving;
  }

  /** Save the messages not yet saved up to `upto` (in seq order) with `state` (whose
   * nextSeq is upto + 1), then send those the connection is ready for. */
  async _save(upto, state) {
    const batch = [...this._unsaved.entries()].filter(([s]) => s <= upto).sort((a, b) => a[0] - b[0])
      .map(([s, message]) => [s, JSON.stringify(message)]);
    if (!batch.length) return;  // an earlier retry saved it
    await KitStore.append(batch, { ...state, savedThrough: upto });
    for (const [s] of batch) this._unsaved.delete(s);
    this.state.savedThrough = Math.max(this.state.savedThrough ?? -1, upto);
    this.unsent += batch.length;
    if (this._storageError) { this._storageError = false; this.error = null; }
    for (const [s, text] of batch) {
      if (this.connected && s === this._sent + 1) this._send(s, text);
    }
    this.onChange(this);
  }

  _send(seq, text) {
    try {
      // a session carried over (_carryOver) numbers its messages on the wire from 0
      const base = this.state.seqBase || 0;
      // nothing goes to a full session from its first refused message on (_fullGoesOn)
      if (this.state.fullFrom != null && seq - base >= this.state.fullFrom) return;
      if (base) { const message = JSON.parse(text); message.seq = seq - base; text = JSON.stringify(message); }
      this.ws.send(text);
      this._sent = seq;
    } catch (_) { /* the close handler reconnects */ }
  }

  connect() {
    // an ended session still connects until everything is sent and bye is said
    if (this.state.finished || (this.ws && this.ws.readyState <= 1)) return;
    const scheme = location.protocol === "https:" ? "wss:" : "ws:";
    const ws = new WebSocket(`${scheme}//${location.host}/ws/ingest?token=${encodeURIComponent(this.token)}`);
    this.ws = ws;
    ws.onopen = () => {
      this._lastError = null;
      ws.send(JSON.stringify({
        type: "hello", protocol: 1, device: this.device, side: this.side,
        sensors: [this.sensor], rate_hz: 60, nine_axis: false,
        resume: this.state.stream, extensions: EXTENSIONS,
        ...(this.program != null ? { program: this.program } : {}),
        // carried-on/1: a new session going on from the full (or closed) one names it
        ...(this.state.stream == null && this.state.carriesOn != null ? { carries_on: this.state.carriesOn } : {}) }));
    };
    ws.onmessage = (event) => this._message(ws, JSON.parse(event.data));
    ws.onclose = (event) => {
      if (this.ws !== ws) return;
      const wasConnected = this.connected;
      this.connected = false;
      if (wasConnected) this.closes += 1;
      this.onClose(event);
      this.onChange(this);
      // the therapist closed the session while it streamed (server/api/sessions.py): it
      // ends here too; the reconnect below sends what was not acked (_carryOver) and bye
      if (event.code === 1000 && /closed by the therapist/.test(event.reason || "")) this._endedByTherapist();
      if (event.code === 4401) { this.error = "this link was revoked: ask your therapist for a new one"; return; }
      if (event.code === 4400 && this._closedNext != null) { this._carryOver(this._closedNext); return; }
      if (event.code === 4400 && this._gone) { this._abandon(); return; }
      // the error just before the close says why, whole (a close reason is at most 123
      // bytes: a longer one's is the code's short sentence)
      if (event.code === 4400) { this.error = "the server refused the stream: " + (this._lastError || event.reason); return; }
      // 4429 after ready: too many of this phone's own messages refused; sending them again
      // would be refused again (4429 in answer to hello is a busy server: tried again below)
      if (event.code === 4429 && ws.wasReady) { this._stopRefused(event.reason); return; }
      // the full session's bye is said: the rest goes on as a new session
      if (ws.fullBye) { this._carryOver(this.state.fullFrom); return; }
      if (!this.state.finished) {
        setTimeout(() => this.connect(), this._retry);
        this._retry = Math.min(this._retry * 2, 5000);
      }
    };
  }

  /** The server closed the stream after `ready` for too many refused messages (close
   * 4429, ARMTRACK_REFUSED_LIMIT): this phone's own data, not a busy server, so no retry
   * would help. The kit stops: no reconnect, no more readings taken; what is not sent stays
   * in the outbox (a reload of the page tries again) and the page tells the patient to
   * contact the therapist (onStopped). */
  _stopRefused(reason) {
    this.flush();  // the readings taken go to the outbox, kept
    this.ended = true;
    clearInterval(this._flushTimer);
    this.stopped = { reason: reason || "", lastRefused: this._lastRefused || null };
    this.error = "Sending stopped: please contact your therapist";
    this.onChange(this);
    this.onStopped(this.stopped);
  }

  /** The server closed this session (its stream stored `nextSeq` messages, on the wire's
   * numbers): the outbox's messages up to there are stored and go; the rest is sent as a
   * new session (hello without resume), numbered on the wire from 0 (state.seqBase: the
   * outbox's number of the new session's seq 0). Nothing recorded is dropped. */
  _carryOver(nextSeq) {
    this._closedNext = null;
    this._saving = this._saving.then(async () => {
      // a full session stored nothing from its first refused message on (the server
      // refuses every later one alike): that and the rest go
      const full = this.state.fullFrom;
      const stored = (full != null ? Math.min(nextSeq, full) : nextSeq) + (this.state.seqBase || 0);
      this.state.fullFrom = null;
      if (stored > 0) await KitStore.dropThrough(stored - 1);
      this.state.seqBase = stored;
      this.state.acked = stored - 1;
      this.state.stream = null;
      // the new session names this one (carried-on/1): its poses were held here
      if (this.state.session != null) this.state.carriesOn = this.state.session;
      this.state.session = null;
      await KitStore.setState("stream", { ...this.state });
      this.unsent = await KitStore.count();
      this.error = null;
      this.carriedOver = (this.carriedOver || 0) + 1;
      if (this.state.closedByTherapist && this.unsent === 0 && this._unsaved.size === 0
          && this.state.ratings.length === 0) {
        // all of it was stored before the close: no new session for nothing
        clearInterval(this._flushTimer);
        this.state.finished = true;
        await KitStore.setState("stream", { ...this.state });
        this.onChange(this);
        return;
      }
      this.onChange(this);
      this.connect();
    }).catch((error) => { this.error = "could not save on this phone: " + error; this.onChange(this); });
  }

  /** The therapist closed the session while this phone streamed it: the readings taken go
   * with the rest, none is taken after (the phone does not carry on into a new session on
   * its own); state.closedByTherapist is kept, so a reload shows the same end. */
  _endedByTherapist() {
    if (this.state.closedByTherapist || this.state.finished) return;
    this.flush();
    const already = this.ended;
    this.ended = true;
    this.state.ended = true;
    this.state.closedByTherapist = true;
    this._saving = this._saving.then(() => KitStore.setState("stream", { ...this.state }))
      .catch((error) => { this.error = "could not save on this phone: " + error; });
    if (!already) this.onEndedByTherapist(this);
  }

  /** The session was erased on the server: its data go from this phone too (nothing of
   * it may be sent again), and the next load of the page starts a new session. */
  _abandon() {
    this._gone = false;
    this.error = "This session was erased by your therapist: nothing more of it is sent. Reload the page to start a new session.";
    this.ended = true;
    this.state.finished = true;
    clearInterval(this._flushTimer);
    this.rows = [];
    this._unsaved.clear();
    localStorage.removeItem(TAIL_KEY);
    this._saving = this._saving.then(() => KitStore.clear()).catch(() => {});
    this.onChange(this);
  }

  async _message(ws, message) {
    if (message.type === "ready") {
      ws.wasReady = true;  // a 4429 from now on is about this phone's messages
      this.state.stream = message.stream;
      this.state.session = message.session;
      this.extensions = message.extensions || [];
      if (message.program) this.state.followed = message.program;  // the version that counts
      this.onReady(message);
      this._retry = 500;
      if (this._helloRefused) { this._helloRefused = false; this.error = null; }
      // in the save chain: what is saved before goes out now, what is saved after follows
      this._saving = this._saving.then(async () => {
        await KitStore.setState("stream", { ...this.state });
        // everything below next_seq is stored: drop it; send the rest again, in order
        // (a full session's next_seq counts its refused numbers as used up: none is stored)
        const full = this.state.fullFrom;
        const next = (full != null ? Math.min(message.next_seq, full) : message.next_seq)
          + (this.state.seqBase || 0);  // in the outbox's numbers
        if (next > 0) await KitStore.dropThrough(next - 1);
        this.state.acked = Math.max(this.state.acked, next - 1);
        const pending = await KitStore.pending(next);
        if (this.ws !== ws) return;
        this.unsent = pending.length;
        this._sent = next - 1;
        this.connected = true;
        for (const [seq, text] of pending) this._send(seq, text);
        this._sendRatings();
        this.onChange(this);
        this._fullGoesOn(ws);
        if (this.ended) this._byeWhenDone();
      }).catch((error) => { this.error = "could not read this phone's storage: " + error; });
    } else if (message.type === "ack") {
      // past a full session's first refused message nothing is dropped: it goes on in the
      // next session (_fullGoesOn); an ack past it says all before it is handled
      const full = this.state.fullFrom;
      const seq = (full != null ? Math.min(message.seq, full - 1) : message.seq)
        + (this.state.seqBase || 0);
      this.state.acked = Math.max(this.state.acked, seq);
      await this._saving;
      await KitStore.dropThrough(seq);
      this.unsent = await KitStore.count();
      this.onChange(this);
      this._fullGoesOn(ws);
      if (this.ended) this._byeWhenDone();
    } else if (message.type === "error") {
      this._lastError = message.reason;
      if (message.seq != null) this._lastRefused = message.reason;
      // the session is full (ARMTRACK_MAX_SESSION_SAMPLES): what is refused from here on is
      // not bad data and must not be dropped; nothing more goes to this session, and once
      // the rest of it is acked the phone says bye and goes on in a new one (_fullGoesOn)
      if (message.seq != null && this.state.fullFrom == null
          && /\(ARMTRACK_MAX_SESSION_SAMPLES\): start a new session/.test(message.reason || "")) {
        if (message.seq === 0) {
          // not even its first message fits a new session: a new one would refuse it too
          ws.close(1000);
          this._stopRefused(message.reason);
          return;
        }
        // kept for the carry-over (a reload too): the closed session's next_seq counts
        // the refused numbers as used up, but none of them is stored
        this.state.fullFrom = message.seq;
        this._saving = this._saving.then(() => KitStore.setState("stream", { ...this.state }))
          .then(() => this._fullGoesOn(ws));
      }
      if (message.seq == null && /resume|session/.test(message.reason || "")) {
        this.error = message.reason;
        this._helloRefused = true;  // a later ready clears it
      }
      // too many new sessions of this kit in an hour (the server closes 4429): the
      // readings stay on this phone and the close handler tries again until it is let in
      if (message.seq == null && /new sessions in the last hour/.test(message.reason || "")) {
        this.error = "Many sessions were started on this kit in the last hour: this one is saved on this phone and will be sent later.";
      }
      // the kit's day is spent (ARMTRACK_MAX_KIT_SAMPLES_PER_DAY, close 4429): the same
      if (message.seq == null && /in the last 24 hours/.test(message.reason || "")) {
        this.error = "This kit sent the most readings it may send in a day: this session is saved on this phone and will be sent later.";
        this._helloRefused = true;  // a later ready clears it
      }
      // the session was closed on the server (the therapist closed it while this phone
      // was offline): next_seq says what of it is stored; the rest goes as a new session
      if (message.seq == null && Number.isInteger(message.next_seq)
          && /is closed/.test(message.reason || "")) this._closedNext = message.next_seq;
      // the stream is gone on the server (the therapist erased the session)
      if (message.seq == null && /no stream .* to resume/.test(message.reason || "")) this._gone = true;
      // a refused message uses up its number: it is dropped with the next ack
    } else if (message.type === "feedback") {
      this.onFeedback(message);
    } else if (message.type === "effort_pain_stored") {
      this.state.ratings = this.state.ratings.filter((r) => r.id !== message.id);
      this._saving = this._saving.then(() => KitStore.setState("stream", { ...this.state }));
      await this._saving;
      this.onChange(this);
      if (this.ended) this._byeWhenDone();
    }
  }

  /** A full session (state.fullFrom: its first refused message, on the wire's numbers):
   * once everything before that is acked, bye ends it (the server closes and estimates
   * it) and the close handler sends the rest as a new session (_carryOver), numbered from
   * 0, as `armtrack stream` does. The phone takes readings all along: nothing waits for
   * the therapist. */
  _fullGoesOn(ws) {
    const full = this.state.fullFrom;
    if (full == null || ws.fullBye || this.ws !== ws || !this.connected
        || ws.readyState !== 1 || this.state.acked - (this.state.seqBase || 0) < full - 1) return;
    ws.fullBye = true;
    ws.send(JSON.stringify({ type: "bye" }));
    ws.close(1000);
  }

  /** The end of the session: everything is sent, then bye (now or once back online). */
  async finish() {
    this.flush();
    await this._saving;
    this.ended = true;
    this.state.ended = true;  // kept: a reload sends the rest, then says bye
    await KitStore.setState("stream", { ...this.state });
    this._byeWhenDone();  // the flush timer goes on until then: it retries a failed save
    this.connect();
  }

  _byeWhenDone() {
    // once: two acks answered together both end here, and the second, after the page had
    // cleared the phone (sendAndEnd), said bye again and saved the state with its token
    if (this.state.finished) return;
    // ratings wait for their answer, unless this server cannot store them (no effort-pain/1)
    const ratingsDone = this.state.ratings.length === 0 || !this.extensions.includes("effort-pain/1");
    // nothing may wait unsaved either (a failed save): bye would end the session without it
    if (this.connected && this.unsent === 0 && this._unsaved.size === 0 && ratingsDone
        && this.ws.readyState === 1) {
      this.ws.send(JSON.stringify({ type: "bye" }));
      clearInterval(this._flushTimer);
      this.state.finished = true;
      this._saving = this._saving.then(() => KitStore.setState("stream", { ...this.state }))
        .catch(() => {});  // unsaved, a reload resumes and says bye again
      this.onChange(this);
    }
  }
}

window.KitAxes = KitAxes;
window.KitStore = KitStore;
window.KitStream = KitStream;

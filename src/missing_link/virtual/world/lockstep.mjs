// Lockstep for host.mjs --fast --lockstep: the simulation runs only as far as its controller
// lets it, and takes a host's bytes only when the controller says they were sent, so a host on
// another process (a test's) gives the same run every time, however busy the machine.
//
// Theory of operation
// -------------------
// Simulated time is the simulation's (fastclock.mjs), but a host's bytes arrive when the
// machine delivers them: fed into the firmware as they come, the same host gives a different
// run on a busy machine.  In lockstep the simulation stands still until the control line
// {"sim": "run", "us": N, "rx": [B1, B2, ...]} (the host's connections in the order they were
// accepted, and how many bytes each has sent so far): once every connection named has been
// accepted and those bytes have come, it runs N simulated µs on, its firmware taking those
// bytes (and no later ones: they wait for the run that names them), at most CHUNK a step as
// ever; then it answers OK {"now": µs, "tx": [bytes sent to each connection so far],
// "stopped": bool} and stands still again.  A host that writes its bytes, then asks for a run,
// then waits for the bytes the answer says were sent, reacts in no simulated time and gives the
// same run every time (tests/memory_soak.py).  A connection the controller has not named yet
// reaches the firmware at the run that names it, a closed one at the first run after it
// closed.  Connections the firmware dials are not for lockstep.
//
// What the firmware sends a host in a run is written at the run's end, just before the answer
// (hold, flush): the host takes it only then, and one write a run instead of one a step (a
// soak's steps wrote 4,067 times in 30 simulated seconds, a tenth of the simulator's time, the
// host's reader woken as often).  A run's bytes past HOLD are written at once.

const HOLD = 16 * 1024;

export class Lockstep {
  constructor() {
    this.want = null; // the run asked for: { us, rx, reply }, until it may start
    this.untilNs = null; // the run going on: it stops at this simulated ns
    this.allowed = []; // bytes of each connection (1..) the firmware may take in this run
    this.got = new Map(); // connection -> bytes received from its host
    this.fed = new Map(); // connection -> bytes given to the firmware
    this.sent = new Map(); // connection -> bytes sent to its host
    this.accepted = new Map(); // connection -> open() not called yet
    this.closing = new Set(); // connections closed before this run began
    this.closed = new Set(); // ... since
    this.held = new Map(); // connection -> { parts, bytes, write }: sent in this run, not written
  }

  request(us, rx, reply) {
    if (this.want !== null || this.untilNs !== null) throw new Error("a run is going on");
    if (!(us >= 0) || !Array.isArray(rx) || !rx.every((b) => Number.isInteger(b) && b >= 0)) {
      throw new Error('expected {"sim": "run", "us": N, "rx": [bytes, ...]}');
    }
    this.want = { us, rx, reply };
  }

  accept(n, open) {
    this.accepted.set(n, open);
  }

  received(n, bytes) {
    this.got.set(n, (this.got.get(n) ?? 0) + bytes);
  }

  ended(n) {
    this.closed.add(n);
  }

  wrote(n, bytes) {
    this.sent.set(n, (this.sent.get(n) ?? 0) + bytes);
  }

  // The firmware sent `data` to connection n: written with `write` by the run's end
  hold(n, data, write) {
    this.wrote(n, data.length);
    const h = this.held.get(n) ?? { parts: [], bytes: 0, write };
    h.parts.push(data);
    h.bytes += data.length;
    this.held.set(n, h);
    if (h.bytes > HOLD) this.flush(n);
  }

  // what is held for connection `only` (null: every connection) written now
  flush(only = null) {
    for (const [n, h] of this.held) {
      if (only !== null && n !== only) continue;
      this.held.delete(n);
      h.write(h.parts.length === 1 ? h.parts[0] : Buffer.concat(h.parts));
    }
  }

  // The run asked for starts once its connections and bytes are here: -> whether one runs
  begin(nowNs) {
    const w = this.want;
    if (this.untilNs !== null) return true;
    if (w === null) return false;
    for (let i = 0; i < w.rx.length; i++) {
      if (!this.accepted.has(i + 1) && !this.fed.has(i + 1)) return false;
      if ((this.got.get(i + 1) ?? 0) < w.rx[i]) return false;
    }
    for (let i = 0; i < w.rx.length; i++) {
      const open = this.accepted.get(i + 1);
      this.accepted.delete(i + 1);
      if (!this.fed.has(i + 1)) this.fed.set(i + 1, 0);
      if (open) open();
    }
    this.allowed = w.rx;
    for (const n of this.closed) this.closing.add(n);
    this.closed.clear();
    this.untilNs = nowNs + w.us * 1000;
    return true;
  }

  // bytes of connection n the firmware may take now
  allowance(n) {
    if (this.untilNs === null) return 0;
    return Math.max(0, (this.allowed[n - 1] ?? 0) - (this.fed.get(n) ?? 0));
  }

  took(n, bytes) {
    this.fed.set(n, (this.fed.get(n) ?? 0) + bytes);
  }

  mayClose(n) {
    return this.closing.delete(n);
  }

  // after a step: the run is over at its end (or when the firmware stopped): answered
  after(nowNs, stopped, refused = false) {
    if (this.want === null || (!refused && this.untilNs === null)) return;
    if (nowNs < this.untilNs && !stopped) return;
    const w = this.want;
    const conns = Math.max(0, ...[...this.sent.keys(), ...this.fed.keys()].filter((n) => n < 1 << 20));
    const tx = Array.from({ length: conns }, (_, i) => this.sent.get(i + 1) ?? 0);
    this.want = null;
    this.untilNs = null;
    this.flush();
    w.reply(JSON.stringify({ now: Math.floor(nowNs / 1000), tx, stopped }));
  }
}

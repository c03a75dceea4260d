// The world beside the firmware under MicroPython (host.mjs --world-fds REQ,RESP): the world
// itself runs in the Python process that started node (virtual/world_mpy.py, missing_link/world);
// this side asks it for a tick when the simulation's time gets there, and makes what it answers
// happen in the simulated devices through worldfeed.py, between the firmware's steps.
//
// Theory of operation
// -------------------
// At the firmware's first step: "HELLO <now µs>" on REQ; the answer (one JSON line on RESP) numbers the world's parts
// for worldfeed.attach and says which actuator reads it wants before each tick and how long a
// tick is.  Before every firmware step (before(), at the simulation's `now`): when it has
// reached the next tick, the actuators are read (worldfeed: one small integer each).  The world
// answers a batch of ticks at once (up to 100 ms of them: worldlink.py's ahead), each with its
// time, its feed calls and its encoders' edges, computed on the assumption that the actuators
// hold: while they read as the batch took them, the batch's next tick happens here at its time
// (its feed calls made, its edges queued), with no word to the world; a step that ends a tick
// or more late (a sonar's echo wait under --fast) makes every tick due by then, each at its own
// time (as it was computed: a tick runs from its own time), the edges before each tick first.
// When they changed, "T <now> <used> <values...>" goes out (`used`: how many of the last batch
// happened; the world goes back to there), and when the batch is used up under them, "T <end>
// ..." (the next on time, from the batch's end); the answer comes back at once (a blocking
// read: the simulation stands still meanwhile, so the world's time is the simulation's, and the
// same simulation gives the same world); its first tick is made at once.  Asking once a batch,
// not once a tick: a wake-up of the world's thread costs far more than its tick.  Then every
// queued edge due by `now` is delivered, a run of one encoder's edges in one call
// (worldfeed.steps_at: each with its time, so the board's clock reads that time while the
// interrupt handler runs, under simulated time).  The function proxies are taken before the
// board's heap is capped (host.mjs), and every call carries small integers: nothing of the
// world in the board's heap.  Times to worldfeed are wrapped as the board's clock is (2^30 µs).
import { readSync, writeSync } from "node:fs";

const WRAP = 2 ** 30;
const FEED = ["attach", "ranger", "imu", "field", "fix", "volts", "off", "steps_at", "motor",
  "servo", "stepper", "stepper_on"];

// The board's clock in µs, not wrapped (the port's wraps at 2^30 µs: a time modulo 2^30 is the
// port's again), for the world's time in real time (without --fast)
function portClock(portUs) {
  let last = portUs();
  let total = last;
  const read = () => {
    const raw = portUs();
    total += (raw - last + WRAP) % WRAP;
    last = raw;
    return total;
  };
  // Not yet at `us` for certain: the port's clock is node's in whole ms (the wasm port's
  // ticks_us), so while node's own says `us` is more than a ms off, the port is not asked (a
  // call into the interpreter each step costs): whether it is there is the port's to say.
  let readAt = performance.now();
  let readUs = total;
  read.before = (us) => readUs + (performance.now() - readAt) * 1000 < us - 1000;
  read.asked = () => {
    readAt = performance.now();
    readUs = read();
    return readUs;
  };
  return read;
}

// host.mjs's one call, after the simulator's modules are in and before the board's heap is
// capped and the firmware boots: null without --world-fds.  worldfeed.py's functions are taken
// now, so that calling them later takes nothing of the board's heap; an edge's handler reads
// the edge's time (worldfeed.clock): simulated time's clock (simtime.py, --fast) or, in real
// time, the port's with an edge's time held while it is delivered (heldtime.py, the firmware's
// `time` from here on: it imports `time` after this).  The world's time is the simulation's.
export function worldBeside(mp, fds, fast) {
  if (fds === null) return null;
  const clock = fast ? "simworld.simtime" : "simworld.heldtime";
  mp.runPython(`from simworld.worldfeed import ${FEED.map((f) => `${f} as _wf_${f}`).join(", ")}` +
    `\nimport sys, simworld.worldfeed, ${clock}\nsimworld.worldfeed.clock = ${clock}` +
    (fast ? "" : `\nsimworld.worldfeed.release = ${clock}.release\n` +
      `sys.modules['time'] = ${clock}\nfrom ${clock} import port_us as _wf_port_us`));
  const feed = Object.fromEntries(FEED.map((f) => [f, mp.globals.get(`_wf_${f}`)]));
  const now = fast ? () => Math.floor(fast.now) : portClock(mp.globals.get("_wf_port_us"));
  if (fast) [now.before, now.asked] = [() => false, now];
  return new WorldTick(fds, feed, now);
}

export class WorldTick {
  // feed: worldfeed.py's functions (proxies, taken before the heap is capped); now: the
  // simulation's µs (the board's clock, never the host's own)
  constructor(fds, feed, now) {
    [this.req, this.resp] = fds.split(",").map(Number);
    this.feed = feed;
    this.now = now;
    this.due = null; // (null: not started; the firmware's devices are there at its first step)
    this.edges = []; // [t, a, b, d], in time order
    this.reads = [];
    this.tickUs = 10000;
    this.catchupUs = 1000000; // (worldlink.py's MAX_CATCHUP_US: later, the world asked from now)
    this.buf = Buffer.alloc(0);
    this.chunk = Buffer.alloc(65536); // (one, read into each time: not 64 KiB of garbage a tick)
    this.ticks = 0;
    this.delivered = 0;
    this.batch = []; // the world's ticks ahead: [t, calls, edges], this.used of them made
    this.used = 0;
    this.values = null; // the actuators' reads the batch was computed under
    this.end = null; // the world's time after the batch
  }

  line() {
    const chunk = this.chunk;
    for (;;) {
      const at = this.buf.indexOf(10);
      if (at >= 0) {
        const out = this.buf.subarray(0, at).toString();
        this.buf = this.buf.subarray(at + 1);
        return out;
      }
      let n;
      try {
        n = readSync(this.resp, chunk);
      } catch (e) {
        if (e.code === "EAGAIN") continue; // (a non-blocking pipe: the world is thinking)
        throw e;
      }
      if (n === 0) throw new Error("the world went away");
      this.buf = Buffer.concat([this.buf, chunk.subarray(0, n)]); // (a copy: chunk is reused)
    }
  }

  ask(text) {
    writeSync(this.req, text + "\n");
    const answer = JSON.parse(this.line());
    if (answer.error) throw new Error("the world: " + answer.error);
    return answer;
  }

  start(now) {
    const hello = this.ask(`HELLO ${Math.floor(now)}`);
    for (const args of hello.attach) this.feed.attach(...args);
    this.reads = hello.reads;
    this.tickUs = hello.tick_us;
    this.catchupUs = hello.catchup_us;
    this.due = now;
  }

  // before each firmware step (host.mjs run)
  before() {
    const next = this.edges.length ? Math.min(this.due, this.edges[0][0]) : this.due;
    if (this.due !== null && this.now.before(next)) return; // (neither a tick nor an edge due)
    const now = this.now.asked();
    if (this.due === null) this.start(now);
    while (now >= this.due) {
      this.deliverBy(this.due - 1); // (a handler may change an actuator: the tick reads it)
      this.tick(now);
    }
    this.deliverBy(now);
  }

  deliverBy(t) {
    let n = 0;
    while (n < this.edges.length && this.edges[n][0] <= t) n++;
    if (n) this.deliver(this.edges.splice(0, n));
  }

  // The tick due (at this.due, now or before): the next of the world's batch while the
  // actuators read as the batch took them (late too); else the world's next batch
  // (world_mpy.py), told how many of the last one happened: from now when they changed, from
  // the last batch's end when it was used up under them (within catchupUs)
  tick(now) {
    const values = this.reads.map(([fn, i]) => this.feed[fn](i)).join(" ");
    const next = this.batch[this.used];
    if (next && values === this.values) {
      this.apply(next);
    } else {
      const at = values === this.values && now - this.end <= this.catchupUs ? this.end : now;
      const answer = this.ask(`T ${Math.floor(at)} ${this.used} ${values}`);
      [this.batch, this.values, this.used, this.end] = [answer.ticks, values, 0, answer.due];
      this.apply(this.batch[0]);
    }
    this.due = this.used < this.batch.length ? this.batch[this.used][0] : this.end;
    this.ticks += 1;
  }

  apply([, calls, edges]) {
    for (const [fn, ...args] of calls) this.feed[fn](...args);
    if (edges.length) this.edges = this.edges.concat(edges).sort((x, y) => x[0] - y[0]);
    this.used += 1;
  }

  deliver(due) {
    // each encoder's edges, a run of them the same way in one call (worldfeed.steps_at: spread
    // evenly from the run's first edge's time to its last's, as a wheel turning steadily over
    // the few ms between two steps makes them)
    const byPin = new Map();
    for (const e of due) {
      if (!byPin.has(e[1])) byPin.set(e[1], []);
      byPin.get(e[1]).push(e);
    }
    for (const edges of byPin.values()) {
      for (let i = 0; i < edges.length; ) {
        const [t0, a, b, d] = edges[i];
        let j = i + 1;
        while (j < edges.length && edges[j][3] === d) j++;
        this.feed.steps_at(a, b, d, j - i, t0 % WRAP, edges[j - 1][0] - t0);
        this.delivered += j - i;
        i = j;
      }
    }
  }
}

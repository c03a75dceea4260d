// Simulated time for host.mjs --fast: the clock the firmware reads (simtime.py) and what moves it.
//
// Theory of operation
// -------------------
// `now` is simulated µs since the start.  A step runs from `now`: the firmware's clock moves in
// it by what it sleeps and, read after read, by the step's CPU time so far (cpu(): the
// interpreter's, process.cpuUsage, not the wall clock, so a loaded machine does not make the
// board slow; times `scale`, a CPU `scale` times slower than this one running the WebAssembly
// interpreter).  Afterwards the clock moves on by what the step slept plus the CPU time its
// reads had not seen.  (A clock that stood still in a step put the whole step's work after its
// last reading: a collection asked for at the turn's end was logged as holding the turn's work
// too, milliseconds the firmware could not see when it chose the moment.)  When the step did
// nothing (no bytes in or out) the clock jumps to the drivers' next deadline, at most IDLE_US
// on, as a board sleeps.
//
// Garbage collection on this port runs when the step returns (simgc.py), so the CPU time
// between the step's end (its mark()) and the return to node is the collection's.  One the
// firmware asked for was charged at the call with what the one before took (so the firmware
// times its collections as on a board); more than that moves the clock on after the step.  One
// nobody asked for (the allocation threshold: mpyhost.py tells it from the heap's allocated
// bytes) moves it on by what it took.  Every collection goes into `log` as [start, end] board
// µs: for a requested one, from where it was asked for to where it ended (with the step's CPU
// time after the request that no clock read saw), with "req" or "auto".  Not seen by the
// firmware: how much longer a requested collection took than its charge (the one before); the
// log has its whole span.

export const IDLE_US = 10000; // (the firmware's own longest wait: board/firmware.py run())
const TICKS_MASK = 2 ** 30 - 1;
const LOG_MAX = 100000;
const CPU_EVERY_US = 20; // (cpu(): a clock read's error from it is at most this, in CPU time)

function cpuUs() {
  const u = process.cpuUsage();
  return u.user + u.system;
}

export class FastClock {
  constructor(scale) {
    this.scale = scale;
    this.now = 0;
    this.lastGcUs = 0; // what the last collection took (simulated µs)
    this.log = []; // [start board µs, end board µs, "req" | "auto"]
    this.collections = { req: 0, auto: 0 };
    this.gcUs = []; // what each collection took (simulated µs), for the figures
    this.marked = 0; // CPU µs at the step's end (mark(), called from inside the step)
    this.due = -1; // µs from the last step to the drivers' next deadline (-1: none)
    this._prev = null; // the last step's end: [board µs, collection µs], for an "auto" seen late
    this.c0 = null; // CPU µs at the step's start (null: between steps)
    this.seen = 0; // simulated µs of the step's CPU time the firmware's clock has moved by
    this.asked = 0; // wall µs (performance.now) when cpu() last read the CPU time
  }

  // The step's CPU time so far, simulated µs (simtime.py: the clock moves by it as it is read).
  // Asked again within CPU_EVERY_US of wall time, the last answer: the firmware reads its
  // clock thousands of times a second and process.cpuUsage is a system call.
  cpu() {
    if (this.c0 === null) return this.seen;
    const wall = performance.now() * 1000;
    if (wall - this.asked < CPU_EVERY_US) return this.seen;
    this.asked = wall;
    this.seen = Math.max(this.seen, Math.floor((cpuUs() - this.c0) * this.scale));
    return this.seen;
  }

  mark() {
    this.marked = cpuUs();
  }

  // One step: run(nowWrapped, lastGcUs) -> "SLEPT REQ AT CLK0 AUTO DUE|output" (mpyhost.py
  // _step); returns the output.
  step(run) {
    const start = this.now;
    const c0 = cpuUs();
    this.c0 = c0;
    this.seen = 0;
    this.asked = performance.now() * 1000;
    let out;
    try {
      out = run(start & TICKS_MASK, Math.round(this.lastGcUs));
    } finally {
      this.c0 = null;
    }
    const c1 = cpuUs();
    const bar = out.indexOf("|");
    const [slept, req, at, clk0, auto, due] = out.slice(0, bar).split(" ").map(Number);
    this.due = due;
    if (auto && this._prev !== null) {
      const [from, took] = this._prev;
      this._record(from, from + took, "auto", took);
      this.lastGcUs = took;
    }
    this._prev = null;
    // (what the clock moved by in the step is in `slept`)
    const work = Math.max(0, (this.marked - c0) * this.scale - this.seen);
    const gc = Math.max(0, c1 - this.marked) * this.scale;
    this.now = start + slept + work;
    if (req) {
      const charged = this.lastGcUs; // (in `slept`: simgc.py advanced the clock by it)
      this.now += Math.max(0, gc - charged);
      this._record(clk0 + at, clk0 + (this.now - start), "req", gc);
      this.lastGcUs = gc;
    } else {
      // a collection nobody asked for ran here if the next step says so: it took `gc`
      this._prev = [clk0 + (this.now - start), gc];
      this.now += gc;
    }
    return out.slice(bar + 1);
  }

  _record(from, to, kind, took) {
    this.collections[kind] += 1;
    this.gcUs.push(took);
    if (this.log.length < LOG_MAX) this.log.push([Math.floor(from), Math.ceil(to), kind]);
  }

  idle() {
    this.now += this.due < 0 ? IDLE_US : Math.min(IDLE_US, Math.max(0, this.due));
  }
}

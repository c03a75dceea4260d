// Simulated time for host.mjs --fast: the clock the firmware reads (simtime.py) and what moves it.
//
// Theory of operation
// -------------------
// `now` is simulated µs since the start.  A step runs at `now` (the firmware's clock stands
// still in it, but for what it sleeps); afterwards the clock moves on by what the step slept
// plus what it cost: the interpreter's CPU time for it (process.cpuUsage, not the wall clock, so
// a loaded machine does not make the board slow) times `scale` (a CPU `scale` times slower than
// this one running the WebAssembly interpreter).  When the step did nothing (no bytes in or
// out) the clock jumps to the drivers' next deadline, at most IDLE_US on, as a board sleeps.
//
// Garbage collection on this port runs when the step returns (simgc.py), so the CPU time
// between the step's end (its mark()) and the return to node is the collection's.  One the
// firmware asked for was charged at the call with what the one before took (so the firmware
// times its collections as on a board); more than that moves the clock on after the step.  One
// nobody asked for (the allocation threshold: mpyhost.py tells it from the heap's allocated
// bytes) moves it on by what it took.  Every collection goes into `log` as [start, end] board
// µs: for a requested one, from where it was asked for to where it ended (the step's own CPU
// time before it included: the firmware cannot see that within a step, the log does), with
// "req" or "auto".

export const IDLE_US = 10000; // (the firmware's own longest wait: board/firmware.py run())
const TICKS_MASK = 2 ** 30 - 1;
const LOG_MAX = 100000;

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
  }

  mark() {
    this.marked = cpuUs();
  }

  // One step: run(nowWrapped, lastGcUs) -> "SLEPT REQ AT CLK0 AUTO DUE|output" (mpyhost.py
  // _step); returns the output.
  step(run) {
    const start = this.now;
    const c0 = cpuUs();
    const out = run(start & TICKS_MASK, Math.round(this.lastGcUs));
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
    const work = Math.max(0, this.marked - c0) * this.scale;
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

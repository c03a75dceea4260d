// Simulated time for host.mjs --fast: the clock the firmware reads (simtime.py) and what moves it.
//
// Theory of operation
// -------------------
// `nowNs` is simulated ns since the start (`now`: µs).  A step runs from it: inside the step
// the firmware's clock moves by what its work costs in the cost model (simcost.py: the step's
// own cost, each clock read, each byte in and out, each peripheral call, each heap scan) and by
// what it sleeps; the step says how far it moved (mpyhost.py _step) and the clock goes on from
// there.  Nothing here reads the host's clock or CPU time: the same
// simulation moves the clock the same way on a quiet machine or a busy one.  When the step did
// nothing (no bytes in or out) the clock jumps to the drivers' next deadline, at most IDLE_US
// on (and not past `limit`: a lockstep run's end, host.mjs), as a board sleeps.
//
// Garbage collection on this port runs when the step returns (simgc.py).  One the firmware
// asked for was charged at the call with what the model makes of the heap then (the blocks
// live after the collection before); once it has run, settle() learns the live blocks and what
// it took, and the clock moves on by what it took beyond its charge.  One the allocator made
// (the firmware's gc.threshold reached, simgc.py) moves the clock on by what it took.  Every
// collection goes into `log` as [start, end] board µs: for a requested one, from where it was
// asked for, as long as its charge and what it took beyond (that beyond falls after the step on
// the board's clock: a few µs, as the live blocks change little from one collection to the
// next); for the allocator's, from the step's end; with "req" or "auto".  With --heap, `heap`
// has each collection's [bytes in use as it began, bytes live after it] (simgc.py), as `log`.

export const IDLE_US = 10000; // (the firmware's own longest wait: board/firmware.py run())
const TICKS_MASK = 2 ** 30 - 1;
const LOG_MAX = 100000;

export class FastClock {
  constructor() {
    this.nowNs = 0;
    this.log = []; // [start board µs, end board µs, "req" | "auto"]
    this.collections = { req: 0, auto: 0 };
    this.gcUs = []; // what each collection took (simulated µs), for the figures
    this.heap = []; // [bytes in use, bytes live after] of each collection (--heap)
    this.due = -1; // µs from the last step to the drivers' next deadline (-1: none)
    this.steps = 0;
  }

  get now() {
    return Math.floor(this.nowNs / 1000);
  }

  // What a step reports (mpyhost.py report): SLEPT NS REQ AT CHARGED CLK0 AUTO DUE
  report(...figures) {
    this.figures = figures;
  }

  // One step: run(nowWrapped, ns) -> its output, having reported its figures (mpyhost.py
  // _step); settle() -> ns the collection it left took (mpyhost.py _settle); heap() -> that
  // collection's [bytes in use, bytes live after] (--heap; null: none).  Returns the output.
  step(run, settle, heap = null) {
    const start = this.nowNs;
    const rem = start % 1000;
    this.figures = null;
    const out = run(Math.floor(start / 1000) & TICKS_MASK, rem);
    const [slept, ns, req, at, charged, clk0, auto, due] = this.figures.map(Number);
    this.due = due;
    this.steps += 1;
    this.nowNs = start - rem + slept * 1000 + ns;
    if (req || auto) {
      const took = Number(settle());
      const end = clk0 + (this.now - Math.floor(start / 1000));
      if (req) {
        const extra = Math.max(0, took - charged); // (charged already: in `slept`)
        this.nowNs += extra;
        this._record(clk0 + at, clk0 + at + Math.ceil((charged + extra) / 1000), "req", took);
      } else {
        this.nowNs += took;
        this._record(end, end + Math.ceil(took / 1000), "auto", took);
      }
      if (heap && this.heap.length < LOG_MAX) this.heap.push(heap());
    }
    return out;
  }

  _record(from, to, kind, tookNs) {
    this.collections[kind] += 1;
    this.gcUs.push(Math.round(tookNs / 1000));
    if (this.log.length < LOG_MAX) this.log.push([from, to, kind]);
  }

  // nothing to do: the clock jumps to the next deadline, at most IDLE_US, not past `limitNs`
  idle(limitNs = Infinity) {
    const us = this.due < 0 ? IDLE_US : Math.min(IDLE_US, Math.max(0, this.due));
    this.nowNs = Math.max(this.nowNs, Math.min(this.nowNs + us * 1000, limitNs));
  }
}

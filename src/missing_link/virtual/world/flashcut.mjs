// The simulated flash's power cut and journal (host.mjs --flash DIR): what of the firmware's
// writes reaches DIR, counted in units.  A file's write (as it is closed: host.mjs mirrors a
// file when the firmware closes it) is its bytes + 1 unit: all of them, the file whole; fewer,
// the file torn (units - 1 bytes of it, none for a single unit: truncated, as a filesystem
// without copy-on-write leaves it); a rename, a removal or a directory made is 1 unit.
//
// A cut armed (--cut-after N, or {"cut": N} on host.mjs's control lines) lets N more units
// through, the last change perhaps in part, then the power goes: "POWER CUT" on stdout and the
// process ends, as a board whose power is lost (DIR keeps what reached it).  --journal FILE
// appends one JSON line per change that reached DIR whole (what a test replays to make the
// flash of a cut at any unit without running the update again).
import { appendFileSync } from "node:fs";
import { relative } from "node:path";

export class FlashCut {
  constructor(after, journal) {
    this.left = after === null ? null : Number(after); // units before the power goes (null: never)
    this.journal = journal;
    this.gone = false;
  }

  arm(n) {
    if (!Number.isInteger(n) || n < 0) throw new Error(`cut: ${n}: a number of units >= 0`);
    this.left = n;
    return `armed: the power goes after ${n} units`;
  }

  // How many of a change's `units` reach the flash (then `gone` says whether the power went).
  take(units) {
    if (this.left === null) return units;
    const n = Math.min(units, this.left);
    this.left -= n;
    if (this.left === 0) this.gone = true; // (after this change, whole or torn)
    return n;
  }

  // a change that reached `dir` whole: {op: write|rename|remove|mkdir, path, to, data}
  record(dir, op, path, extra = {}) {
    if (!this.journal) return;
    const entry = { op, path: relative(dir, path), ...extra };
    if (entry.to) entry.to = relative(dir, entry.to);
    if (entry.data) entry.data = Buffer.from(entry.data).toString("base64");
    appendFileSync(this.journal, JSON.stringify(entry) + "\n");
  }

  powerOff() {
    process.stdout.write("POWER CUT\n");
    process.exit(0);
  }
}

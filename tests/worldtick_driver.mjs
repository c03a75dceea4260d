// Node's side of the world under MicroPython (src/missing_link/virtual/world/worldtick.mjs's
// WorldTick) driven without MicroPython, for tests/test_worldtick_node.py: the world answers
// over the pipes of --world-fds REQ,RESP (virtual/world_mpy.py's NodeWorld, in the test's
// process); worldfeed.py's functions are a recorder here, and the simulation's clock and the
// actuators' reads are a script's.  stdin: one JSON list of firmware steps, [now µs, {"fn part":
// value}] (the actuators as worldfeed would read them then); stdout: one JSON list, for each
// step the world's next due time after it (WorldTick's `due`) and every feed call it made, an
// actuator's read too (["read", fn, part, the world's due time then]: a tick's reads open it).
import { readFileSync } from "node:fs";
import { WorldTick } from "../src/missing_link/virtual/world/worldtick.mjs";

const READS = ["motor", "servo", "stepper", "stepper_on"];
const FED = ["attach", "ranger", "imu", "field", "fix", "volts", "off", "steps_at"];
const at = process.argv.indexOf("--world-fds");
const steps = JSON.parse(readFileSync(0, "utf8"));

let t = 0;
let reads = {};
let heard = [];
const feed = {};
for (const fn of READS) {
  feed[fn] = (i) => {
    const v = reads[`${fn} ${i}`];
    if (!Number.isInteger(v)) throw new Error(`the script has no ${fn} ${i}`);
    heard.push(["read", fn, i, world.due]);
    return v;
  };
}
for (const fn of FED) feed[fn] = (...args) => heard.push([fn, ...args]);
const now = () => t;
[now.before, now.asked] = [() => false, now]; // (as under --fast: the simulation's time)

const world = new WorldTick(process.argv[at + 1], feed, now);
const out = [];
for (const [us, values] of steps) {
  [t, reads, heard] = [us, values, []];
  world.before();
  out.push([world.due, heard]);
}
process.stdout.write(JSON.stringify(out) + "\n");

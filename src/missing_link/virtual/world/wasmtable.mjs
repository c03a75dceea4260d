// The function table's entries read once (host.mjs, before MicroPython is loaded).
//
// The npm build of MicroPython is built with emscripten's assertions on: its invoke_* wrappers
// (the interpreter's nlr_push, around most calls it makes) take each function from emscripten's
// own copy of the table, then ask the table for the same entry again to check that copy
// (getWasmTableEntry).  That second read, a call into the engine at every wrapped call, was
// 10 % of a --fast soak's time in the simulator (node --cpu-prof: WebAssembly.Table's get).
// Here a table's entries are remembered once read, and forgotten when JavaScript sets an entry
// or grows the table (emscripten's addFunction: the only ones that change it; C code cannot).
// What the interpreter calls is the same function either way: emscripten calls its own copy's.

export function rememberTableEntries() {
  const T = WebAssembly.Table.prototype;
  const { get, set, grow } = T;
  const seen = new WeakMap(); // table -> its entries read so far, by index
  T.get = function (i) {
    let entries = seen.get(this);
    if (entries === undefined) seen.set(this, (entries = []));
    let f = entries[i];
    if (f === undefined) f = entries[i] = get.call(this, i);
    return f;
  };
  T.set = function (...a) {
    seen.delete(this);
    return set.apply(this, a);
  };
  T.grow = function (...a) {
    seen.delete(this);
    return grow.apply(this, a);
  };
}

// An independent Foxglove client for the standard types: the official protocol library
// (@foxglove/ws-protocol) decodes the first message of each topic given with its advertised
// ros2msg schema (@foxglove/rosmsg parses it, dependencies included, as Foxglove's panels do;
// @foxglove/rosmsg2-serialization reads the CDR).  No missing-link code.  Prints one JSON line:
//   node foxglove_standard_client.mjs ws://127.0.0.1:PORT /rig/imu/imu /rover/tof/range ...
import wsProtocol from "@foxglove/ws-protocol";
import rosmsg from "@foxglove/rosmsg";
import rosmsg2 from "@foxglove/rosmsg2-serialization";
import WebSocket from "ws";

const { FoxgloveClient } = wsProtocol;
const { parse } = rosmsg;
const { MessageReader } = rosmsg2;

const [url, ...topics] = process.argv.slice(2);
const ws = new WebSocket(url, ["foxglove.sdk.v1", FoxgloveClient.SUPPORTED_SUBPROTOCOL]);
const client = new FoxgloveClient({ ws });
const byId = new Map(); // subscription id -> {topic, channel, reader}
const out = {};
const timer = setTimeout(() => {
  console.error("timeout; got " + JSON.stringify(Object.keys(out)));
  process.exit(2);
}, 30000);

const plain = (v) =>
  JSON.parse(
    JSON.stringify(v, (_k, x) =>
      typeof x === "bigint" ? Number(x) : ArrayBuffer.isView(x) ? Array.from(x, Number) : x,
    ),
  );

client.on("advertise", (list) => {
  for (const ch of list) {
    if (!topics.includes(ch.topic)) continue;
    if ([...byId.values()].some((s) => s.topic === ch.topic)) continue;
    const reader = new MessageReader(parse(ch.schema, { ros2: true }));
    const id = client.subscribe(ch.id);
    byId.set(id, { topic: ch.topic, channel: ch, reader });
  }
});
client.on("message", ({ subscriptionId, timestamp, data }) => {
  const s = byId.get(subscriptionId);
  if (!s || out[s.topic]) return;
  const bytes = new Uint8Array(data.buffer, data.byteOffset, data.byteLength);
  out[s.topic] = {
    schemaName: s.channel.schemaName,
    encoding: s.channel.encoding,
    schemaEncoding: s.channel.schemaEncoding,
    log_time_ns: timestamp.toString(),
    message: plain(s.reader.readMessage(bytes)),
  };
  if (topics.every((t) => out[t])) {
    clearTimeout(timer);
    console.log(JSON.stringify(out));
    ws.close();
    process.exit(0);
  }
});
client.on("error", (e) => {
  console.error(String(e));
  process.exit(3);
});

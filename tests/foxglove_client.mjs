// An independent Foxglove client: the official protocol library (@foxglove/ws-protocol) over
// `ws`, decoding a message with its advertised ros2msg schema (@foxglove/rosmsg +
// @foxglove/rosmsg2-serialization).  No missing-link code.  Prints one JSON line.
//   node foxglove_client.mjs ws://127.0.0.1:PORT /thesis/dist_ir
import wsProtocol from "@foxglove/ws-protocol";
import rosmsg from "@foxglove/rosmsg";
import rosmsg2 from "@foxglove/rosmsg2-serialization";
import WebSocket from "ws";

const { FoxgloveClient } = wsProtocol;
const { parse } = rosmsg;
const { MessageReader } = rosmsg2;

const [url, topic] = process.argv.slice(2);
// foxglove-sdk servers speak the protocol under the "foxglove.sdk.v1" subprotocol name.
const ws = new WebSocket(url, ["foxglove.sdk.v1", FoxgloveClient.SUPPORTED_SUBPROTOCOL]);
const client = new FoxgloveClient({ ws });
const channels = new Map();
const timer = setTimeout(() => { console.error("timeout"); process.exit(2); }, 20000);
let reader = null;
let serverName = "";
client.on("serverInfo", (info) => { serverName = info.name; });
client.on("advertise", (list) => {
  for (const ch of list) channels.set(ch.topic, ch);
  const ch = channels.get(topic);
  if (ch && reader === null) {
    reader = new MessageReader(parse(ch.schema, { ros2: true }));
    client.subscribe(ch.id);
  }
});
client.on("message", ({ timestamp, data }) => {
  const ch = channels.get(topic);
  const msg = reader.readMessage(new Uint8Array(data.buffer, data.byteOffset, data.byteLength));
  clearTimeout(timer);
  console.log(JSON.stringify({
    server: serverName,
    protocol: ws.protocol,
    topics: [...channels.keys()].sort(),
    channel: { encoding: ch.encoding, schemaName: ch.schemaName, schemaEncoding: ch.schemaEncoding },
    log_time_ns: timestamp.toString(),
    values: Array.from(msg.values, Number),
    times_sec: msg.times.map((t) => t.sec),
  }));
  ws.close();
  process.exit(0);
});
client.on("error", (e) => { console.error(String(e)); process.exit(3); });

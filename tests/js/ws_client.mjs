// Independent client of `radical monitor foxglove` (tests/monitors/test_fox_live.py runs it).
//
//   node ws_client.mjs ws://127.0.0.1:PORT SECONDS [MIN_PER_TOPIC]  ->  JSON summary on stdout
//
// Connects with the official @foxglove/ws-protocol client over the `ws` WebSocket, offering the
// subprotocol "foxglove.sdk.v1", subscribes to every advertised channel, decodes the JSON
// messages, validates foxglove.FrameTransform and foxglove.Log messages against the schemas
// Foxglove publishes (@foxglove/schemas) and stops after SECONDS, or as soon as every advertised
// channel among the expected ones has MIN_PER_TOPIC messages and a log said the node is gone.
import WebSocket from "ws";
import wsProtocol from "@foxglove/ws-protocol";
import Ajv from "ajv";
import { FrameTransform, Log } from "@foxglove/schemas/jsonschema.js";

const [url, seconds, minPer] = [process.argv[2], Number(process.argv[3]), Number(process.argv[4] ?? 5)];
const expected = ["/tlm/small", "/tlm/medium", "/tlm/large", "/tf/body", "/tf/st1", "/tf/st2",
  "/paper/calibration", "/log/faults", "/diag"];
const { FoxgloveClient } = wsProtocol;
const ajv = new Ajv({ strict: false, allErrors: true });
const official = { "foxglove.FrameTransform": ajv.compile(FrameTransform), "foxglove.Log": ajv.compile(Log) };
const ws = new WebSocket(url, ["foxglove.sdk.v1"]);
const client = new FoxgloveClient({ ws });
const out = { protocol: null, serverInfo: null, channels: {}, counts: {}, errors: [], officialErrors: [],
  first: {}, last: {}, logTexts: [] };
const bySub = new Map();
const done = (code) => {
  try { client.close(); } catch { /* closing twice */ }
  process.stdout.write(JSON.stringify(out));
  process.exit(code);
};
const check = () => {
  const have = expected.filter((t) => t in out.channels && t !== "/log/faults");
  const gone = out.logTexts.some((t) => t.includes(" gone"));
  if (have.length >= 8 && have.every((t) => (out.counts[t] ?? 0) >= minPer) && gone) done(0);
};
ws.on("open", () => { out.protocol = ws.protocol; });
client.on("serverInfo", (info) => { out.serverInfo = { name: info.name, capabilities: info.capabilities }; });
client.on("error", (e) => { out.errors.push(String(e?.message ?? e)); });
// foxglove-sdk's server sends an advertisement before it enters the channel in the client's
// table (rust/foxglove/src/websocket/connected_client.rs, advertise_channels), so a subscribe
// that arrives in between is refused with "Unknown channel ID: N" (seen on a loaded 2-core CI
// machine). The bridge is not at fault: subscribe again, a few times, and count it.
const byChannel = new Map();
client.on("status", (s) => {
  const m = /Unknown channel ID: (\d+)/.exec(String(s?.message ?? ""));
  const ch = m && byChannel.get(Number(m[1]));
  if (!ch || (ch.retries = (ch.retries ?? 0) + 1) > 5) return;
  out.resubscribed = (out.resubscribed ?? 0) + 1;
  setTimeout(() => bySub.set(client.subscribe(ch.id), ch), 50);
});
client.on("advertise", (channels) => {
  for (const ch of channels) {
    out.channels[ch.topic] = { encoding: ch.encoding, schemaName: ch.schemaName,
      schemaEncoding: ch.schemaEncoding, schemaType: JSON.parse(ch.schema || "{}").type ?? null };
    byChannel.set(ch.id, ch);
    bySub.set(client.subscribe(ch.id), ch);
  }
  if (!out.ready) {  // the first advertisement is subscribed: tell the test to start the node
    out.ready = true;
    process.stderr.write("subscribed\n");
  }
});
client.on("message", ({ subscriptionId, timestamp, data }) => {
  const ch = bySub.get(subscriptionId);
  if (!ch) return;
  let msg;
  try {
    msg = JSON.parse(new TextDecoder().decode(data));
  } catch (e) {
    out.errors.push(`${ch.topic}: invalid JSON`);
    return;
  }
  out.counts[ch.topic] = (out.counts[ch.topic] ?? 0) + 1;
  const v = official[ch.schemaName];
  if (v && !v(msg) && out.officialErrors.length < 20) {
    out.officialErrors.push(`${ch.topic}: ${ajv.errorsText(v.errors)}`);
  }
  if (ch.topic === "/log/faults") out.logTexts.push(msg.message);
  const rec = { timestamp: timestamp.toString(), msg };
  if (!(ch.topic in out.first)) out.first[ch.topic] = rec;
  out.last[ch.topic] = rec;
  check();
});
client.on("close", () => done(1));
setTimeout(() => done(0), seconds * 1000);

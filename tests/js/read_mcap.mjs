// Independent reader of a `radical export --foxglove` archive (tests/monitors/test_fox_export.py runs it).
//
//   node read_mcap.mjs FILE.mcap  ->  one JSON summary on stdout, exit 0; exit 1 on a read error
//
// Reads the file with the official TypeScript MCAP reader (@mcap/core, zstd/lz4 chunks through
// @mcap/support's decompress handlers), parses every message as JSON, validates it against its
// own channel schema (ajv, JSON Schema 2020-12) and validates every foxglove.FrameTransform and
// foxglove.Log message against the schemas Foxglove publishes in @foxglove/schemas. It also checks
// each channel schema against the subset of JSON Schema that Foxglove/Lichtblick turn into
// datatypes (restated from Lichtblick's packages/mcap-support/src/parseJsonSchema.ts: objects with
// properties, one type per property, no arrays of arrays).
import { readFile } from "node:fs/promises";
import { McapIndexedReader } from "@mcap/core";
import { loadDecompressHandlers } from "@mcap/support";
import Ajv2020 from "ajv/dist/2020.js";
import Ajv from "ajv";
import { FrameTransform, Log } from "@foxglove/schemas/jsonschema.js";

function lichtblickSubset(schema, where) {
  const errs = [];
  if (schema.type !== "object" || typeof schema.properties !== "object") {
    return [`${where}: not an object schema with properties`];
  }
  for (const [name, f] of Object.entries(schema.properties)) {
    const p = `${where}.${name}`;
    if (f.type === "object") errs.push(...lichtblickSubset(f, p));
    else if (f.type === "array") {
      const it = f.items ?? {};
      if (it.type === "object") errs.push(...lichtblickSubset(it, p + "[]"));
      else if (!["boolean", "string", "number", "integer"].includes(it.type)) {
        errs.push(`${p}: unsupported array item type ${JSON.stringify(it.type)}`);
      }
    } else if (!["boolean", "string", "number", "integer"].includes(f.type)) {
      errs.push(`${p}: unsupported field type ${JSON.stringify(f.type)}`);
    }
  }
  return errs;
}

class FileReadable {
  constructor(buf) { this.buf = buf; }
  async size() { return BigInt(this.buf.byteLength); }
  async read(offset, length) {
    return this.buf.subarray(Number(offset), Number(offset + length));
  }
}

const path = process.argv[2];
const buf = new Uint8Array(await readFile(path));
const reader = await McapIndexedReader.Initialize({
  readable: new FileReadable(buf),
  decompressHandlers: await loadDecompressHandlers(),
});

const official = new Ajv({ strict: false, allErrors: true });
const officialValidators = {
  "foxglove.FrameTransform": official.compile(FrameTransform),
  "foxglove.Log": official.compile(Log),
};
const ajv = new Ajv2020({ strict: false, allErrors: true });
const channelValidators = new Map();
const out = {
  library: reader.header.library,
  channels: {},
  schemaErrors: [],
  messageErrors: [],
  officialErrors: [],
  frames: {},
  firstMessages: {},
  lastMessages: {},
  metadata: [],
};
for (const [id, ch] of reader.channelsById) {
  const sc = reader.schemasById.get(ch.schemaId);
  const schema = JSON.parse(new TextDecoder().decode(sc.data));
  out.channels[ch.topic] = {
    messageEncoding: ch.messageEncoding, schemaName: sc.name, schemaEncoding: sc.encoding,
    count: 0, officialChecked: 0,
  };
  if (!sc.name.startsWith("foxglove.")) {
    out.schemaErrors.push(...lichtblickSubset(schema, sc.name));
  }
  channelValidators.set(id, ajv.compile(schema));
}
for await (const md of reader.readMetadata()) {
  out.metadata.push({ name: md.name, keys: [...md.metadata.keys()] });
}
let lastLogTime = -1n;
let outOfOrder = 0;
for await (const m of reader.readMessages()) {
  const ch = reader.channelsById.get(m.channelId);
  const sc = reader.schemasById.get(ch.schemaId);
  const info = out.channels[ch.topic];
  info.count += 1;
  if (m.logTime < lastLogTime) outOfOrder += 1;
  lastLogTime = m.logTime;
  let msg;
  try {
    msg = JSON.parse(new TextDecoder().decode(m.data));
  } catch (e) {
    out.messageErrors.push(`${ch.topic}: invalid JSON: ${e}`);
    continue;
  }
  const v = channelValidators.get(m.channelId);
  if (!v(msg) && out.messageErrors.length < 20) {
    out.messageErrors.push(`${ch.topic}: ${ajv.errorsText(v.errors)}`);
  }
  const ov = officialValidators[sc.name];
  if (ov) {
    info.officialChecked += 1;
    if (!ov(msg) && out.officialErrors.length < 20) {
      out.officialErrors.push(`${ch.topic}: ${official.errorsText(ov.errors)}`);
    }
    if (sc.name === "foxglove.FrameTransform") {
      const key = `${msg.parent_frame_id}->${msg.child_frame_id}`;
      out.frames[key] = (out.frames[key] ?? 0) + 1;
    }
  }
  if (!(ch.topic in out.firstMessages)) {
    out.firstMessages[ch.topic] = { logTime: m.logTime.toString(), msg };
  }
  out.lastMessages[ch.topic] = { logTime: m.logTime.toString(), msg };
}
out.outOfOrder = outOfOrder;
// keep the summary small: only a few topics' first/last messages in full
const keep = new Set(["/tf/body", "/tf/body_truth", "/tf/st1", "/tf/st2", "/tf/st2_truth",
  "/log/faults",
  "/paper/calibration", "/tlm/large", "/truth/attitude", "/siru"]);
for (const k of Object.keys(out.firstMessages)) {
  if (!keep.has(k)) { delete out.firstMessages[k]; delete out.lastMessages[k]; }
}
process.stdout.write(JSON.stringify(out));

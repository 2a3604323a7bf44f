// Decodes every message of a cellcal recording with readers written by others: @mcap/core (MCAP) and
// @foxglove/omgidl-parser + @foxglove/omgidl-serialization (the recorded omgidl schema, CDR), and compares every
// field with the writer's truth (recording_sample_writer).
//   node recording_cdr_reader.mjs FILE.mcap TRUTH.json
import { McapIndexedReader } from "@mcap/core";
import { parseIDL } from "@foxglove/omgidl-parser";
import { MessageReader } from "@foxglove/omgidl-serialization";
import { readFileSync } from "fs";

const [file, truthFile] = process.argv.slice(2);
const buf = readFileSync(file);
const truth = JSON.parse(readFileSync(truthFile, "utf8"));
const fail = (m) => { console.error(`FAIL ${file}: ${m}`); process.exit(1); };

const readable = { size: async () => BigInt(buf.length), read: async (off, len) => buf.subarray(Number(off), Number(off + len)) };
const mcap = await McapIndexedReader.Initialize({ readable });
const readers = new Map();
for (const ch of mcap.channelsById.values()) {
  const schema = mcap.schemasById.get(ch.schemaId);
  if (!schema || schema.encoding !== "omgidl" || ch.messageEncoding !== "cdr") fail(`channel ${ch.topic}: schema/encoding`);
  if (!ch.metadata.get("dds_type") || ch.metadata.get("dds_type") !== schema.name) fail(`channel ${ch.topic}: dds_type metadata`);
  readers.set(ch.id, { topic: ch.topic, reader: new MessageReader(schema.name, parseIDL(new TextDecoder().decode(schema.data))) });
}

// Field-by-field comparison; returns the first difference ("" when equal).
const norm = (v) => (typeof v === "bigint" ? v.toString() : ArrayBuffer.isView(v) ? Array.from(v) : v);
function differs(expected, decoded) {
  for (const [k, want] of Object.entries(expected)) {
    if (k === "topic" || k === "log_time_ns") continue;
    const got = norm(decoded[k]);
    if (Array.isArray(want)) {
      if (!Array.isArray(got) || got.length !== want.length) return `${k}: length ${got?.length} != ${want.length}`;
      for (let i = 0; i < want.length; i++) if (norm(got[i]) !== want[i]) return `${k}[${i}]: ${got[i]} != ${want[i]}`;
    } else if (typeof want === "boolean" ? Boolean(got) !== want : String(got) !== String(want)) {
      return `${k}: ${got} != ${want}`;
    }
  }
  return "";
}

let i = 0;
let lastDecoded = null;
for await (const m of mcap.readMessages()) {
  const want = truth[i];
  if (!want) fail(`more messages than the truth (${truth.length})`);
  const { topic, reader } = readers.get(m.channelId);
  if (topic !== want.topic || m.logTime.toString() !== want.log_time_ns) fail(`message ${i}: ${topic} at ${m.logTime}`);
  const decoded = reader.readMessage(m.data);
  const d = differs(want, decoded);
  if (d) fail(`message ${i} (${topic}): ${d}`);
  lastDecoded = { want, decoded };
  i++;
}
if (i !== truth.length) fail(`${i} messages, truth has ${truth.length}`);
// The comparison itself must be able to fail: a changed value is caught.
const changed = structuredClone(lastDecoded.want);
changed.source_stamp_ns = (BigInt(changed.source_stamp_ns) + 1n).toString();
if (!differs(changed, lastDecoded.decoded)) fail("the comparison does not see a changed stamp");
console.log(`OK ${file}: ${i} messages decoded from CDR with the recorded omgidl schemas, every field as written`);

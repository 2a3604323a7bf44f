// Reads a cellcal MCAP file with @mcap/core (Foxglove's reader, not ours) and compares it with the writer's truth:
// the indexed reader (footer, summary, chunk and message indexes) and the stream reader with CRC checks.
//   node mcap_independent_reader.mjs FILE.mcap TRUTH.json
import { McapIndexedReader, McapStreamReader } from "@mcap/core";
import { readFileSync } from "fs";

const [file, truthFile] = process.argv.slice(2);
const buf = readFileSync(file);
const truth = JSON.parse(readFileSync(truthFile, "utf8"));
const fail = (m) => { console.error(`FAIL ${file}: ${m}`); process.exit(1); };

const readable = { size: async () => BigInt(buf.length), read: async (off, len) => buf.subarray(Number(off), Number(off + len)) };
const indexed = await McapIndexedReader.Initialize({ readable });
if (indexed.channelsById.size !== truth.channels) fail(`channels ${indexed.channelsById.size} != ${truth.channels}`);
if (indexed.schemasById.size !== truth.schemas) fail(`schemas ${indexed.schemasById.size}`);
if (indexed.statistics?.messageCount !== BigInt(truth.messages)) fail(`statistics ${indexed.statistics?.messageCount}`);
if (indexed.chunkIndexes.length === 0) fail("no chunk index");
let n = 0, bytes = 0, sum = 0, last = 0n, seq = -1;
for await (const m of indexed.readMessages()) {
  n++;
  bytes += m.data.length;
  for (const b of m.data) sum += b;
  if (m.sequence <= seq) fail(`sequence ${m.sequence} after ${seq}`);
  seq = m.sequence;
  last = m.logTime;
}
if (n !== truth.messages) fail(`indexed messages ${n} != ${truth.messages}`);
if (bytes !== truth.payload_bytes || sum !== truth.payload_byte_sum) fail("payloads differ");
if (last !== BigInt(truth.last_log_time_ns)) fail(`last log time ${last}`);
for (const ch of indexed.channelsById.values())
  if (ch.messageEncoding !== "cdr" || !ch.metadata.has("index")) fail(`channel ${ch.topic}`);

const stream = new McapStreamReader({ validateCrcs: true });
stream.append(buf);
let k = 0, rec, footer = false;
while ((rec = stream.nextRecord())) {
  if (rec.type === "Message") k++;
  if (rec.type === "Footer") footer = true;
}
if (!stream.done() || !footer || k !== truth.messages) fail(`stream reader: ${k} messages, done ${stream.done()}`);
console.log(`OK ${file}: ${n} messages, ${indexed.channelsById.size} channels, ${indexed.chunkIndexes.length} chunks (indexed and streamed, CRCs checked)`);

// A Foxglove client written by others (@foxglove/ws-protocol's FoxgloveClient over the `ws` WebSocket) against
// `cellcal foxglove`: subscribes to every advertised channel, decodes every message with @foxglove/omgidl-parser and
// @foxglove/omgidl-serialization from the advertised omgidl schema, and writes what it received, decoded, with the
// latency each message took from the bridge's DDS receipt (the frame's receive time) to here.
//   node live_view_client.mjs ws://127.0.0.1:PORT OUT.json STOP_FILE [--count-only]
// Stops when STOP_FILE exists (or after 300 s), then writes OUT.json. --count-only (benchmarks): every message is
// still decoded, but only its latency is kept.
import wsProtocol from "@foxglove/ws-protocol";  // CommonJS: no named exports
import { parseIDL } from "@foxglove/omgidl-parser";
import { MessageReader } from "@foxglove/omgidl-serialization";
import WebSocket from "ws";
import { existsSync, writeFileSync } from "fs";

const { FoxgloveClient } = wsProtocol;
const [url, outFile, stopFile, mode] = process.argv.slice(2);
const countOnly = mode === "--count-only";
const fail = (m) => { console.error(`FAIL live_view_client: ${m}`); process.exit(1); };
const nowMs = () => performance.timeOrigin + performance.now();
// JSON has no NaN, Infinity or 64-bit integers: those are written as strings, on both sides of every comparison.
const plain = (v) => (typeof v === "bigint" ? v.toString() : typeof v === "number" && !Number.isFinite(v) ? String(v) : ArrayBuffer.isView(v) ? Array.from(v, plain)
  : Array.isArray(v) ? v.map(plain) : v && typeof v === "object" ? Object.fromEntries(Object.entries(v).map(([k, x]) => [k, plain(x)])) : v);

const client = new FoxgloveClient({ ws: new WebSocket(url, [FoxgloveClient.SUPPORTED_SUBPROTOCOL]) });
let serverInfo = null;
const channels = new Map();  // channel id -> {topic, schemaName, reader}
const bySubscription = new Map();
const received = {};  // topic -> [{receive_time_ns, latency_ms, message}]
const statuses = [];
let decodeErrors = 0;

client.on("serverInfo", (info) => { serverInfo = info; });
client.on("status", (s) => statuses.push(s));
client.on("error", (e) => fail(`socket error: ${e?.message ?? e}`));
client.on("advertise", (list) => {
  for (const ch of list) {
    if (ch.encoding !== "cdr" || ch.schemaEncoding !== "omgidl") fail(`channel ${ch.topic}: ${ch.encoding}/${ch.schemaEncoding}`);
    const reader = new MessageReader(ch.schemaName, parseIDL(ch.schema));
    channels.set(ch.id, { topic: ch.topic, schemaName: ch.schemaName, schema: ch.schema, reader });
    received[ch.topic] = [];
    bySubscription.set(client.subscribe(ch.id), ch.id);
  }
  writeFileSync(`${stopFile}.ready`, "");  // subscribed: the cell may start
});
client.on("message", ({ subscriptionId, timestamp, data }) => {
  const at = nowMs();
  const ch = channels.get(bySubscription.get(subscriptionId));
  if (!ch) fail(`message on unknown subscription ${subscriptionId}`);
  let message;
  try {
    message = ch.reader.readMessage(new Uint8Array(data.buffer, data.byteOffset, data.byteLength));
  } catch (e) {
    decodeErrors++;
    return;
  }
  const latency_ms = at - Number(timestamp) / 1e6;
  received[ch.topic].push(countOnly ? { latency_ms } : { receive_time_ns: timestamp.toString(), latency_ms, message: plain(message) });
});

const started = Date.now();
const timer = setInterval(() => {
  if (!existsSync(stopFile) && Date.now() - started < 300000) return;
  clearInterval(timer);
  const advertised = [...channels.values()].map(({ topic, schemaName, schema }) => ({ topic, schemaName, schema }));
  writeFileSync(outFile, JSON.stringify({ serverInfo, advertised, statuses, decodeErrors, received }));
  const n = Object.values(received).reduce((a, v) => a + v.length, 0);
  console.log(`live_view_client: ${n} messages on ${Object.keys(received).length} channels, ${decodeErrors} not decodable`);
  client.close();
  process.exit(0);
}, 100);

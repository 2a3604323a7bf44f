// Judges what a Foxglove client received from `cellcal foxglove` beside a running cell (live_view_client.mjs) against
// the cell's own numbers:
//  1. every cell topic was advertised (cdr, omgidl, the recording's schema name) and received;
//  2. every message, decoded by the client, equals field by field the same sample (topic, key, sequence_number) in
//     the cell's recording, read with @mcap/core and decoded independently (how many reach both is reported);
//  3. the last CalibrationState per robot has the cell's final version, and the CompensatedTargets applied and
//     refused per robot are the cell's counts (those published before a reader matched the writer are reported);
//  4. config/foxglove/cellcal.json: every panel path names an advertised topic and fields of its schema, and plots
//     data both live and from the recording (the same layout opens both).
// Prints the latency the bridge adds (DDS receipt in the bridge -> decoded in the client) beside the DDS latency
// the bridge measured (source timestamp -> receipt), and writes them to RESULT.json.
//   node check_live_view.mjs CLIENT.json RECORDING.mcap CELL_SUMMARY.json BRIDGE_SUMMARY.json LAYOUT.json RESULT.json
import { McapIndexedReader } from "@mcap/core";
import { parseIDL } from "@foxglove/omgidl-parser";
import { MessageReader } from "@foxglove/omgidl-serialization";
import { readFileSync, writeFileSync } from "fs";

const [clientFile, mcapFile, cellFile, bridgeFile, layoutFile, resultFile] = process.argv.slice(2);
const client = JSON.parse(readFileSync(clientFile, "utf8"));
const cell = JSON.parse(readFileSync(cellFile, "utf8"));
const bridge = JSON.parse(readFileSync(bridgeFile, "utf8"));
const layout = JSON.parse(readFileSync(layoutFile, "utf8"));
const failures = [];
const fail = (m) => failures.push(m);
// JSON has no NaN, Infinity or 64-bit integers: those are written as strings, on both sides of every comparison.
const plain = (v) => (typeof v === "bigint" ? v.toString() : typeof v === "number" && !Number.isFinite(v) ? String(v) : ArrayBuffer.isView(v) ? Array.from(v, plain)
  : Array.isArray(v) ? v.map(plain) : v && typeof v === "object" ? Object.fromEntries(Object.entries(v).map(([k, x]) => [k, plain(x)])) : v);

// --- the recording, decoded independently
const buf = readFileSync(mcapFile);
const readable = { size: async () => BigInt(buf.length), read: async (off, len) => buf.subarray(Number(off), Number(off + len)) };
const mcap = await McapIndexedReader.Initialize({ readable });
const recChannels = new Map();
for (const ch of mcap.channelsById.values()) {
  const schema = mcap.schemasById.get(ch.schemaId);
  recChannels.set(ch.id, { topic: ch.topic, schemaName: schema.name,
    reader: new MessageReader(schema.name, parseIDL(new TextDecoder().decode(schema.data))) });
}
const recorded = {};  // topic -> [message]
const recordedAnswers = new Map();  // robot_id -> [message] of cellcal/compensated_target, as recorded
for await (const m of mcap.readMessages()) {
  const ch = recChannels.get(m.channelId);
  const message = plain(ch.reader.readMessage(m.data));
  (recorded[ch.topic] ??= []).push(message);
  if (ch.topic === "cellcal/compensated_target") {
    if (!recordedAnswers.has(message.robot_id)) recordedAnswers.set(message.robot_id, []);
    recordedAnswers.get(message.robot_id).push(message);
  }
}

// --- 1. channels and topics
if (client.serverInfo?.name !== "cellcal") fail(`serverInfo: ${JSON.stringify(client.serverInfo)}`);
if (client.decodeErrors) fail(`${client.decodeErrors} messages the client could not decode`);
if (client.statuses.length) fail(`status messages from the server: ${JSON.stringify(client.statuses)}`);
const advertised = new Map(client.advertised.map((c) => [c.topic, c]));
for (const ch of recChannels.values()) {
  const a = advertised.get(ch.topic);
  if (!a) fail(`${ch.topic}: recorded but not advertised`);
  else if (a.schemaName !== ch.schemaName) fail(`${ch.topic}: schema ${a.schemaName}, recording ${ch.schemaName}`);
}
for (const topic of advertised.keys())
  if (!(client.received[topic]?.length > 0)) fail(`${topic}: advertised, nothing received`);

// --- 2. field by field against the recording
const keyOf = (topic, m) => `${topic}|${m.robot_id ?? m.target_id}|${m.sequence_number}`;
function differs(a, b, path = "") {
  if (Array.isArray(a) || Array.isArray(b)) {
    if (!Array.isArray(a) || !Array.isArray(b) || a.length !== b.length) return `${path}: length`;
    for (let i = 0; i < a.length; i++) { const d = differs(a[i], b[i], `${path}[${i}]`); if (d) return d; }
    return "";
  }
  if (a && typeof a === "object") {
    const keys = new Set([...Object.keys(a), ...Object.keys(b ?? {})]);
    for (const k of keys) { const d = differs(a[k], b?.[k], path ? `${path}.${k}` : k); if (d) return d; }
    return "";
  }
  const same = typeof a === "number" && typeof b === "number" ? Object.is(a, b) || a === b : a === b;
  return same ? "" : `${path}: ${a} != ${b}`;
}
const perTopic = {};
let compared = 0, lastPair = null;
for (const [topic, list] of Object.entries(client.received)) {
  const index = new Map();
  for (const m of recorded[topic] ?? []) {
    const k = keyOf(topic, m);
    if (!index.has(k)) index.set(k, []);
    index.get(k).push(m);
  }
  let matched = 0;
  for (const { message } of list) {
    const candidates = index.get(keyOf(topic, message));
    if (!candidates) continue;
    matched++;
    const diffs = candidates.map((c) => differs(c, message));
    if (!diffs.includes("")) fail(`${topic} ${keyOf(topic, message)}: live differs from the recording: ${diffs[0]}`);
    else lastPair = { recorded: candidates[diffs.indexOf("")], live: message };
    compared++;
  }
  const nRec = (recorded[topic] ?? []).length;
  perTopic[topic] = { live: list.length, recorded: nRec, matched };
  // The bridge and the recorder are two readers of the same writers. How many samples reach both is reported, not
  // judged: best-effort sensor streams may drop, and a reader of the calibration topics (reliable, keep last 1 per
  // robot) may skip a version on a busy machine, for either reader. Each topic must have samples in both to compare.
  if (matched === 0) fail(`${topic}: no sample in both the live view (${list.length}) and the recording (${nRec})`);
}
// The comparison must be able to fail: one changed field is caught.
if (!lastPair) fail("no message compared");
else {
  const changed = structuredClone(lastPair.live);
  changed.sequence_number = String(BigInt(changed.sequence_number) + 1n);
  if (!differs(lastPair.recorded, changed)) fail("the comparison does not see a changed field");
}

// --- 3. the cell's own numbers
for (const r of cell.robots) {
  const states = client.received["cellcal/calibration_state"].filter((x) => x.message.robot_id === r.robot_id);
  const last = states.length ? Math.max(...states.map((x) => Number(x.message.version))) : -1;
  if (last !== r.final_version) fail(`${r.robot_id}: last CalibrationState version ${last} live, cell says ${r.final_version}`);
  // CompensatedTarget is reliable and volatile: a reader gets every answer published after it matched the compensation
  // publisher's writer. The cell waits for neither the bridge nor its recorder before it sends targets, so on a busy
  // machine either may match after the first answers (a CI run's recording lacked the first refusal). Judged per
  // reader, by the TargetPose each answers (1, 2, ... per robot): what it got is one run without a gap that ends at
  // the last answer anyone got, at or beyond the cell's count (nothing lost at the stop); what it lacks is a prefix of
  // at most 2 s of answers, reported; its applied / refused counts are within the cell's and make them up with that
  // prefix.
  const answers = client.received["cellcal/compensated_target"].filter((x) => x.message.robot_id === r.robot_id)
    .map((x) => x.message);
  const rec = recordedAnswers.get(r.robot_id) ?? [];
  const n = r.targets_applied + r.targets_refused;
  const allowed = Math.ceil(2 * n / cell.duration_s);
  const seqs = (list) => list.map((m) => Number(m.target_sequence)).sort((a, b) => a - b);
  const lastTarget = Math.max(...seqs(answers), ...seqs(rec));
  if (!(lastTarget >= n)) fail(`${r.robot_id}: the last answer any reader got answers target ${lastTarget}; the cell got ${n} answers`);
  // One reader's answers judged; returns the failures (the notes printed).
  const judge = (name, list) => {
    const out = [];
    const s = seqs(list);
    if (!s.length) return [`${r.robot_id}: no CompensatedTarget in the ${name}`];
    const missing = [];
    for (let k = s[0], i = 0; k <= lastTarget; ++k) { if (s[i] === k) ++i; else missing.push(k); }
    if (missing.length) out.push(`${r.robot_id}: the ${name} lacks ${missing.length} answers after its first (targets ${missing.slice(0, 10).join(", ")})`);
    // The cell's own answers are targets lo..last; the reader's count is judged on that range.
    const lo = lastTarget - n + 1, prefix = Math.max(0, s[0] - lo);
    if (prefix > allowed) out.push(`${r.robot_id}: the ${name} lacks the first ${prefix} answers (more than 2 s of them, ${allowed})`);
    const inRange = list.filter((m) => Number(m.target_sequence) >= lo);
    const applied = inRange.filter((m) => m.applied).length, refused = inRange.length - applied;
    const counts = prefix === 0 ? applied === r.targets_applied && refused === r.targets_refused
                                : applied <= r.targets_applied && refused <= r.targets_refused && applied + refused + prefix === n;
    if (!counts)
      out.push(`${r.robot_id}: ${applied} applied / ${refused} refused in the ${name} (+${prefix} before it matched), ` +
               `the cell says ${r.targets_applied} / ${r.targets_refused}`);
    if (prefix > 0 && !out.length)
      console.log(`NOTE ${r.robot_id}: the ${name} matched the compensation publisher after its first ${prefix} answer(s); ` +
                  `all ${list.length} later ones arrived`);
    return out;
  };
  for (const [name, list] of [["live view", answers], ["recording", rec]]) judge(name, list).forEach(fail);
  // The judgement must be able to fail: the live view without one answer in the middle, or without the last.
  const sorted = [...answers].sort((a, b) => Number(a.target_sequence) - Number(b.target_sequence));
  if (sorted.length > 2) {
    if (!judge("live view less one", sorted.filter((_, k) => k !== sorted.length >> 1)).length)
      fail(`${r.robot_id}: the answers' judgement does not see one missing in the middle`);
    if (Number(sorted.at(-1).target_sequence) === lastTarget && !judge("live view less the last", sorted.slice(0, -1)).length)
      fail(`${r.robot_id}: the answers' judgement does not see the last one missing`);
  }
}

// --- 4. the layout
const definitions = new Map();  // schema name -> parsed IDL (with every nested definition)
for (const c of client.advertised) definitions.set(c.schemaName, parseIDL(c.schema));
function fieldType(schemaName, fields) {
  const defs = definitions.get(schemaName);
  let struct = defs.find((d) => d.name === schemaName);
  let field = null;
  for (const f of fields) {
    field = struct?.definitions?.find((d) => d.name === f && !d.isConstant);
    if (!field) return null;
    struct = field.isComplex ? defs.find((d) => d.name === field.type) : null;
  }
  return field;
}
const pathRe = /^([a-zA-Z0-9_/-]+)(?:\{([a-zA-Z0-9_]+)==(\$[a-zA-Z0-9_]+|"[^"]*"|-?[0-9.]+)\})?((?:\.[a-zA-Z0-9_]+)*)$/;
const panelsInTree = [];
(function walk(n) { if (typeof n === "string") panelsInTree.push(n); else if (n) { walk(n.first); walk(n.second); } })(layout.layout);
const panelIds = Object.keys(layout.configById);
for (const id of panelIds) if (!panelsInTree.includes(id)) fail(`layout: panel ${id} is not placed`);
for (const id of panelsInTree) if (!layout.configById[id]) fail(`layout: ${id} placed but not configured`);
const layoutPaths = [];
for (const [id, cfg] of Object.entries(layout.configById)) {
  for (const p of cfg.paths ?? []) layoutPaths.push({ id, path: p.value, plot: id.startsWith("Plot!") });
  if (cfg.topicPath) layoutPaths.push({ id, path: cfg.topicPath, plot: false });
}
function evaluate(path, messagesByTopic) {
  const m = pathRe.exec(path);
  const [, topic, filterField, filterValue, fieldPart] = m;
  const fields = fieldPart ? fieldPart.slice(1).split(".") : [];
  let want = filterValue;
  if (want?.startsWith("$")) want = layout.globalVariables[want.slice(1)];
  else if (want?.startsWith('"')) want = want.slice(1, -1);
  const values = [];
  for (const x of messagesByTopic[topic] ?? []) {
    if (filterField && String(x[filterField]) !== String(want)) continue;
    values.push(fields.reduce((v, f) => v?.[f], x));
  }
  return values;
}
const liveByTopic = Object.fromEntries(Object.entries(client.received).map(([t, l]) => [t, l.map((x) => x.message)]));
for (const { id, path, plot } of layoutPaths) {
  const m = pathRe.exec(path);
  if (!m) { fail(`layout ${id}: '${path}' is not a message path of the form topic{field==value}.field`); continue; }
  const [, topic, filterField, filterValue, fieldPart] = m;
  const ch = advertised.get(topic);
  if (!ch) { fail(`layout ${id}: topic ${topic} is not a cell topic`); continue; }
  if (filterField && !fieldType(ch.schemaName, [filterField])) fail(`layout ${id}: ${ch.schemaName} has no field ${filterField}`);
  if (filterValue?.startsWith("$") && !(filterValue.slice(1) in layout.globalVariables))
    fail(`layout ${id}: variable ${filterValue} is not in globalVariables`);
  const fields = fieldPart ? fieldPart.slice(1).split(".") : [];
  if (fields.length) {
    const f = fieldType(ch.schemaName, fields);
    if (!f) { fail(`layout ${id}: ${ch.schemaName} has no field ${fields.join(".")}`); continue; }
    if (plot && (f.isComplex || f.isArray || f.type === "string")) fail(`layout ${id}: ${path} is not a number to plot`);
  }
  for (const [source, data] of [["live", liveByTopic], ["recording", recorded]]) {
    const values = evaluate(path, data);
    const asNumber = (v) => (typeof v === "string" && /^-?[0-9]+$/.test(v) ? Number(v) : v);  // 64-bit integers
    const usable = plot ? values.map(asNumber).filter((v) => typeof v === "number" && Number.isFinite(v))
      : values.filter((v) => v !== undefined);
    if (!usable.length) fail(`layout ${id}: '${path}' has nothing to show from the ${source}`);
  }
}

// --- latencies
const pct = (v, p) => { const s = [...v].sort((a, b) => a - b); return s.length ? s[Math.min(s.length - 1, Math.floor(p * s.length))] : NaN; };
const all = Object.values(client.received).flat().map((x) => x.latency_ms);
const latency = { bridge_added_ms: { p50: pct(all, 0.5), p99: pct(all, 0.99), samples: all.length }, per_topic: {} };
for (const [t, l] of Object.entries(client.received)) {
  const v = l.map((x) => x.latency_ms);
  latency.per_topic[t] = { bridge_added_p50_ms: pct(v, 0.5), bridge_added_p99_ms: pct(v, 0.99),
    dds_p50_ms: bridge.topics[t]?.dds_latency_p50_ms, dds_p99_ms: bridge.topics[t]?.dds_latency_p99_ms };
}
if (!(latency.bridge_added_ms.p50 >= -1)) fail(`latency: bridge-added p50 ${latency.bridge_added_ms.p50} ms (clocks?)`);
writeFileSync(resultFile, JSON.stringify({ per_topic: perTopic, compared, latency, bridge }, null, 1));

console.log("topic                              live  recorded  both  | bridge-added p50/p99 ms | DDS p50/p99 ms");
for (const [t, s] of Object.entries(perTopic)) {
  const l = latency.per_topic[t];
  console.log(`${t.padEnd(34)} ${String(s.live).padStart(6)} ${String(s.recorded).padStart(8)} ${String(s.matched).padStart(6)}  | ` +
    `${l.bridge_added_p50_ms.toFixed(3)} / ${l.bridge_added_p99_ms.toFixed(3)} | ${l.dds_p50_ms?.toFixed(3)} / ${l.dds_p99_ms?.toFixed(3)}`);
}
console.log(`bridge-added latency over all ${all.length} messages: p50 ${latency.bridge_added_ms.p50.toFixed(3)} ms, ` +
  `p99 ${latency.bridge_added_ms.p99.toFixed(3)} ms; bridge CPU ${bridge.cpu_percent_of_one_core.toFixed(1)} % of one core`);
console.log(`${compared} live messages compared field by field with the recording; ${layoutPaths.length} layout paths checked live and recorded`);
if (failures.length) {
  for (const f of failures.slice(0, 30)) console.error(`FAIL ${f}`);
  if (failures.length > 30) console.error(`... and ${failures.length - 30} more`);
  process.exit(1);
}
console.log("OK: every cell topic live in a Foxglove client, decoded, equal to the recording and the cell's counts");

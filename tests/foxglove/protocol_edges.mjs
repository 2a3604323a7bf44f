// The edges of cellcal's Foxglove server, with the `ws` client: a handshake without the foxglove.websocket.v1
// subprotocol is refused (HTTP 400, saying why); requests it does not serve or cannot parse are answered with an
// error status, and the connection stays usable (a valid subscribe afterwards still delivers messages).
//   node protocol_edges.mjs ws://127.0.0.1:PORT
import WebSocket from "ws";

const url = process.argv[2];
const fail = (m) => { console.error(`FAIL protocol_edges: ${m}`); process.exit(1); };
setTimeout(() => fail("timed out after 60 s"), 60000).unref();

// 1. no subprotocol
await new Promise((resolve) => {
  const ws = new WebSocket(url);
  ws.on("open", () => fail("a client without the foxglove subprotocol was accepted"));
  ws.on("unexpected-response", (req, res) => {
    if (res.statusCode !== 400) fail(`refused with HTTP ${res.statusCode}, not 400`);
    let body = "";
    res.on("data", (d) => (body += d));
    res.on("end", () => {
      if (!body.includes("foxglove.websocket.v1")) fail(`refusal does not say why: '${body}'`);
      resolve();
    });
  });
  ws.on("error", () => {});
});

// 2. bad requests, then a good one on the same connection
const ws = new WebSocket(url, ["foxglove.websocket.v1"]);
const statuses = [];
let channels = null, gotData = false;
ws.on("message", (data, isBinary) => {
  if (isBinary) { if (data[0] === 1) gotData = true; return; }
  const m = JSON.parse(data.toString());
  if (m.op === "advertise") channels = m.channels;
  if (m.op === "status") statuses.push(m);
});
await new Promise((r) => ws.on("open", r));
while (!channels) await new Promise((r) => setTimeout(r, 20));
const bad = [
  ["not json", "not a JSON object"],
  [JSON.stringify({ op: "subscribe", subscriptions: [{ id: 1, channelId: 999 }] }), "not advertised"],
  [JSON.stringify({ op: "subscribe", subscriptions: [{ id: -1, channelId: 1 }] }), "unsigned 32-bit"],
  [JSON.stringify({ op: "getParameters", parameterNames: [] }), "read-only"],
  [JSON.stringify({ op: "unsubscribe", subscriptionIds: [42] }), "no such subscription"],
];
for (const [text] of bad) ws.send(text);
ws.send(Buffer.from([1, 0, 0, 0, 0]));  // client message data: no client publishing
ws.send(JSON.stringify({ op: "subscribe", subscriptions: [{ id: 7, channelId: channels[0].id }, { id: 7, channelId: channels[1].id }] }));
const deadline = Date.now() + 30000;
while ((statuses.length < bad.length + 2 || !gotData) && Date.now() < deadline) await new Promise((r) => setTimeout(r, 20));
for (const [, want] of bad)
  if (!statuses.some((s) => s.level === 2 && s.message.includes(want))) fail(`no error status saying '${want}': ${JSON.stringify(statuses)}`);
if (!statuses.some((s) => s.message.includes("binary client messages"))) fail("binary client message not refused");
if (!statuses.some((s) => s.message.includes("id already in use"))) fail("a reused subscription id was accepted");
if (!gotData) fail("no message after a valid subscribe on the same connection");
console.log(`OK protocol_edges: refused a handshake without the subprotocol; ${statuses.length} error statuses for bad requests; the connection still delivers`);
ws.close();
process.exit(0);

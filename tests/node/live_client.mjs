// A Foxglove WebSocket client we did not write (@foxglove/ws-protocol over `ws`), for
// tests/test_liveview.py. Usage: node live_client.mjs ws://127.0.0.1:PORT LISTEN_S
//
// Connects, subscribes to every advertised channel, listens LISTEN_S seconds, then tries to
// write to the server: a client channel (clientAdvertise) with one message on it, and a
// service call. Prints one JSON document on stdout with what the server said and sent.
import wsProtocol from "@foxglove/ws-protocol";
import WebSocket from "ws";

const { FoxgloveClient } = wsProtocol;

const [url, listenArg] = process.argv.slice(2);
const listenMs = Math.round(Number(listenArg ?? "2") * 1000);
const decoder = new TextDecoder();
const out = {
  serverInfo: null,
  channels: [],
  services: [],
  messages: [], // [topic, log time in ns as a string, message text]
  statuses: [],
  serviceCallFailures: [],
  serviceCallResponses: 0,
  errors: [],
  closed: false,
};
const topics = new Map(); // subscription id -> topic

// foxglove-sdk servers accept only their newer name of the protocol, "foxglove.sdk.v1" (the
// Foxglove app offers both); the messages are those of ws-protocol's spec.
const ws = new WebSocket(url, [FoxgloveClient.SUPPORTED_SUBPROTOCOL, "foxglove.sdk.v1"]);
const client = new FoxgloveClient({ ws });
client.on("serverInfo", (info) => { out.serverInfo = info; });
client.on("advertise", (channels) => {
  for (const ch of channels) {
    out.channels.push(ch);
    topics.set(client.subscribe(ch.id), ch.topic);
  }
});
client.on("advertiseServices", (services) => { out.services.push(...services); });
client.on("message", ({ subscriptionId, timestamp, data }) => {
  const bytes = new Uint8Array(data.buffer, data.byteOffset, data.byteLength);
  out.messages.push([topics.get(subscriptionId), String(timestamp), decoder.decode(bytes)]);
});
client.on("status", (s) => { out.statuses.push(s); });
client.on("serviceCallFailure", (f) => { out.serviceCallFailures.push(f); });
client.on("serviceCallResponse", () => { out.serviceCallResponses += 1; });
client.on("error", (e) => { out.errors.push(String(e?.message ?? e)); });
client.on("close", () => { out.closed = true; });

const sleep = (ms) => new Promise((resolve) => setTimeout(resolve, ms));
const finish = (code) => {
  process.stdout.write(JSON.stringify(out) + "\n", () => process.exit(code));
};
setTimeout(() => { out.errors.push("timed out"); finish(3); }, listenMs + 10000).unref();

await new Promise((resolve, reject) => {
  ws.once("open", resolve);
  ws.once("error", reject);
}).catch((e) => { out.errors.push(`connect: ${e.message}`); finish(2); });
await sleep(listenMs);

// Writing attempts: a read-only server must refuse them.
const marker = { written_by_client: "live_client.mjs" };
if (!out.closed) {
  const mine = client.advertise({ topic: "/client/write", encoding: "json", schemaName: "" });
  client.sendMessage(mine, new TextEncoder().encode(JSON.stringify(marker)));
  const hijack = client.advertise({
    topic: "/furnace/thermocouples", encoding: "json", schemaName: "furnace.Thermocouples",
  });
  client.sendMessage(hijack, new TextEncoder().encode(JSON.stringify(marker)));
  client.sendServiceCallRequest({
    serviceId: 1, callId: 7, encoding: "json", data: new TextEncoder().encode("{}"),
  });
  await sleep(1000);
}
client.close();
finish(0);

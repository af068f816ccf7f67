// The official Foxglove WebSocket protocol client (@foxglove/ws-protocol, pinned in package.json) against
// `attitude-sil run --foxglove`: what Lichtblick and older Foxglove releases connect with.
//
//   node client.mjs URL [--attitude N] [--tf N] [--get NAME,...] [--set NAME=JSON ...] [--set-after N] [--updates N]
//                   [--timeout S]
//
// Connects asking for the subprotocol the client library supports (foxglove.websocket.v1), subscribes to
// every advertised channel, decodes /attitude (geometry_msgs/msg/QuaternionStamped, CDR) until N messages
// came and /tf (tf2_msgs/msg/TFMessage) until N came, optionally gets and sets parameters (subscribing to the
// got ones' updates, waiting for N of them; the sets once --set-after N attitude messages came, default at once),
// and prints one JSON object:
// {subprotocol, capabilities, channels, counts, attitude: [[sec, nanosec, x, y, z, w], ...],
//  tf: [[[sec, nanosec, frame_id, child_frame_id, tx, ty, tz, qx, qy, qz, qw], ...], ...], parameters,
//  setResult, updates, statuses}. Exit 0 when everything asked for arrived, 1 otherwise (the JSON says what is missing).
import cdr from "@foxglove/cdr";
import wsProtocol from "@foxglove/ws-protocol";
import WebSocket from "ws";

const { CdrReader } = cdr;
const { FoxgloveClient } = wsProtocol;

const args = process.argv.slice(2);
const url = args[0];
const opt = (name, fallback) => {
  const i = args.indexOf(name);
  return i >= 0 ? args[i + 1] : fallback;
};
const wantAttitude = Number(opt("--attitude", "20"));
const wantTf = Number(opt("--tf", "0"));
const getNames = opt("--get", "") ? opt("--get", "").split(",") : [];
const setArgs = args.flatMap((a, i) => (a === "--set" ? [args[i + 1]] : []));
const wantUpdates = Number(opt("--updates", "0"));
const setAfter = Number(opt("--set-after", "0"));
let setSent = false;
const deadline = Date.now() + 1000 * Number(opt("--timeout", "60"));

const out = { subprotocol: null, capabilities: [], channels: [], counts: {}, attitude: [], tf: [], parameters: null,
              setResult: null, updates: [], statuses: [] };
const subscriptions = new Map(); // subscription id -> channel
let client;
let setDone = setArgs.length === 0;
let getDone = getNames.length === 0;

function finish(code) {
  process.stdout.write(JSON.stringify(out) + "\n");
  process.exit(code);
}

function done() {
  return out.attitude.length >= wantAttitude && out.tf.length >= wantTf && getDone && setDone
    && out.updates.length >= wantUpdates;
}

function decodeAttitude(data) {
  const reader = new CdrReader(new DataView(data.buffer, data.byteOffset, data.byteLength));
  const sec = reader.int32();
  const nanosec = reader.uint32();
  reader.string(); // frame_id
  return [sec, nanosec, reader.float64(), reader.float64(), reader.float64(), reader.float64()];
}

function decodeTf(data) {
  // geometry_msgs/TransformStamped[] transforms: header (stamp, frame_id), child_frame_id, translation, rotation
  const reader = new CdrReader(new DataView(data.buffer, data.byteOffset, data.byteLength));
  const transforms = [];
  for (let n = reader.sequenceLength(); n > 0; n--) {
    const sec = reader.int32();
    const nanosec = reader.uint32();
    const frame = reader.string();
    const child = reader.string();
    const values = [];
    for (let i = 0; i < 7; i++) {
      values.push(reader.float64());
    }
    transforms.push([sec, nanosec, frame, child, ...values]);
  }
  return transforms;
}

function sendSets() {
  if (setSent || setArgs.length === 0 || out.attitude.length < setAfter) {
    return;
  }
  setSent = true;
  const params = setArgs.map((a) => ({ name: a.slice(0, a.indexOf("=")), value: JSON.parse(a.slice(a.indexOf("=") + 1)) }));
  client.setParameters(params, "set");
}

function connect() {
  if (Date.now() > deadline) {
    finish(1);
  }
  const ws = new WebSocket(url, [FoxgloveClient.SUPPORTED_SUBPROTOCOL]);
  ws.on("error", (err) => {
    if (!client && err.code === "ECONNREFUSED") {
      setTimeout(connect, 50); // the server's port is not open yet: nothing to wait on but time
    }
  });
  ws.on("open", () => {
    out.subprotocol = ws.protocol;
    client = new FoxgloveClient({ ws });
    client.on("serverInfo", (info) => {
      out.capabilities = info.capabilities;
      if (getNames.length > 0) {
        client.subscribeParameterUpdates(getNames);
        client.getParameters(getNames, "get");
      }
      sendSets();
    });
    client.on("parameterValues", ({ parameters, id }) => {
      if (id === "get") {
        out.parameters = parameters;
        getDone = true;
      } else if (id === "set") {
        out.setResult = parameters;
        setDone = true;
      } else {
        out.updates.push(...parameters);
      }
      if (done()) {
        finish(0);
      }
    });
    client.on("status", (st) => out.statuses.push(st.message)); // the server's one-line problems (a refused set)
    client.on("advertise", (advertised) => {
      for (const ch of advertised) {
        out.channels.push({ topic: ch.topic, encoding: ch.encoding, schemaName: ch.schemaName,
                            schemaEncoding: ch.schemaEncoding });
        subscriptions.set(client.subscribe(ch.id), ch); // subscribe returns the subscription's id
      }
    });
    client.on("message", ({ subscriptionId, data }) => {
      const ch = subscriptions.get(subscriptionId);
      const topic = ch ? ch.topic : `?${subscriptionId}`;
      out.counts[topic] = (out.counts[topic] ?? 0) + 1;
      if (topic === "/attitude" && out.attitude.length < Math.max(wantAttitude, setAfter)) {
        out.attitude.push(decodeAttitude(data));
        sendSets();
      }
      if (topic === "/tf" && out.tf.length < wantTf) {
        out.tf.push(decodeTf(data));
      }
      if (done()) {
        finish(0);
      }
    });
    client.on("close", () => finish(done() ? 0 : 1));
  });
}

setTimeout(() => finish(1), Math.max(deadline - Date.now(), 0));
connect();

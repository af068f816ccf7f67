// The official Foxglove WebSocket protocol client (@foxglove/ws-protocol, pinned in package.json) against
// `attitude-sil run --foxglove`: what Lichtblick and older Foxglove releases connect with.
//
//   node client.mjs URL [--attitude N] [--get NAME,...] [--set NAME=JSON] [--timeout S]
//
// Connects asking for the subprotocol the client library supports (foxglove.websocket.v1), subscribes to
// every advertised channel, decodes /attitude (geometry_msgs/msg/QuaternionStamped, CDR) until N messages
// came, optionally gets and sets parameters (subscribing to their updates), and prints one JSON object:
// {subprotocol, capabilities, channels, counts, attitude: [[sec, nanosec, x, y, z, w], ...], parameters,
//  setResult, updates}. Exit 0 when everything asked for arrived, 1 otherwise (the JSON says what is missing).
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
const getNames = opt("--get", "") ? opt("--get", "").split(",") : [];
const setArg = opt("--set", "");
const deadline = Date.now() + 1000 * Number(opt("--timeout", "60"));

const out = { subprotocol: null, capabilities: [], channels: [], counts: {}, attitude: [], parameters: null,
              setResult: null, updates: [] };
const channels = new Map();
let client;
let setDone = !setArg;
let getDone = getNames.length === 0;

function finish(code) {
  process.stdout.write(JSON.stringify(out) + "\n");
  process.exit(code);
}

function done() {
  return out.attitude.length >= wantAttitude && getDone && setDone;
}

function decodeAttitude(data) {
  const reader = new CdrReader(new DataView(data.buffer, data.byteOffset, data.byteLength));
  const sec = reader.int32();
  const nanosec = reader.uint32();
  reader.string(); // frame_id
  return [sec, nanosec, reader.float64(), reader.float64(), reader.float64(), reader.float64()];
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
      if (setArg) {
        const [name, value] = [setArg.slice(0, setArg.indexOf("=")), setArg.slice(setArg.indexOf("=") + 1)];
        client.setParameters([{ name, value: JSON.parse(value) }], "set");
      }
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
    });
    client.on("advertise", (advertised) => {
      for (const ch of advertised) {
        channels.set(ch.id, ch);
        out.channels.push({ topic: ch.topic, encoding: ch.encoding, schemaName: ch.schemaName,
                            schemaEncoding: ch.schemaEncoding });
        client.subscribe(ch.id);
      }
    });
    client.on("message", ({ subscriptionId, data }) => {
      const ch = channels.get(subscriptionIdToChannel.get(subscriptionId));
      if (!ch) {
        return;
      }
      out.counts[ch.topic] = (out.counts[ch.topic] ?? 0) + 1;
      if (ch.topic === "/attitude" && out.attitude.length < wantAttitude) {
        out.attitude.push(decodeAttitude(data));
      }
      if (done()) {
        finish(0);
      }
    });
    client.on("close", () => finish(done() ? 0 : 1));
  });
}

// FoxgloveClient.subscribe returns the subscription id: remember which channel each is for
const subscriptionIdToChannel = new Map();
const subscribe = FoxgloveClient.prototype.subscribe;
FoxgloveClient.prototype.subscribe = function (channelId) {
  const id = subscribe.call(this, channelId);
  subscriptionIdToChannel.set(id, channelId);
  return id;
};

setTimeout(() => finish(1), Math.max(deadline - Date.now(), 0));
connect();

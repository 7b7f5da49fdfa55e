// A Foxglove client driving `diffbot view`, as the Foxglove app does: the official
// @foxglove/ws-protocol client (subprotocol foxglove.sdk.v1), ros2msg schemas parsed by
// @foxglove/rosmsg and CDR decoded by @foxglove/rosmsg2-serialization.
//
// usage: node view_client.mjs URL ROBOT OUT.json [PHASE]
//   full (default): receives the channels, decodes a LaserScan, an Image and the scene;
//     publishes a Twist on /ROBOT/cmd_vel_unstamped as the Teleop panel does (cdr) and reports the
//     ground truth before and after; writes a summary to OUT.json.
//   reset: full, then calls the /reset_simulation service as the Service Call panel does and
//     reports the ground truth after it.
//   receive: the same without the Twist.
//   watch: (the view bench) keeps trying to connect until the view is there, subscribes
//     to every channel, decodes every message, and on SIGINT/SIGTERM writes the counts.
//   layout: as watch, but subscribes only to what bridges/foxglove_layout.json shows (and
//     /tf, /tf_static, /scene), as the Foxglove app with that layout does.
import fs from "node:fs";
import WebSocket from "ws";
import wsp from "@foxglove/ws-protocol";
import { parse } from "@foxglove/rosmsg";
import { MessageReader, MessageWriter } from "@foxglove/rosmsg2-serialization";

const { FoxgloveClient } = wsp;
const [url, robot, outPath, phase = "full"] = process.argv.slice(2);
const TIMEOUT_MS = (phase === "watch" || phase === "layout") ? 3600000 : 40000;
const watch = phase === "watch" || phase === "layout";
let layoutTopics = null;
if (phase === "layout") {
  const text = fs.readFileSync(new URL("../../bridges/foxglove_layout.json", import.meta.url), "utf8");
  layoutTopics = new Set(["/tf", "/tf_static", "/scene"]);
  for (const m of text.matchAll(/"(\/[A-Za-z0-9_\/]+)/g)) {
    let t = m[1];
    // a plot path "/follower/ground_truth.twist..." names its topic before the first "."
    layoutTopics.add(t);
  }
}

let client = null;
let opened = false;
function connect() {
  const ws = new WebSocket(url, ["foxglove.sdk.v1"]);
  ws.on("error", () => {});
  ws.on("open", () => { opened = true; out.subprotocol = ws.protocol; });
  ws.on("close", () => { if (watch && !opened && !done) setTimeout(connect, 200); });
  client = new FoxgloveClient({ ws });
  setup(client);
}
const channels = new Map();   // id -> {topic, schemaName, reader}
const subs = new Map();       // subscription id -> channel
const out = { channels: [], scans: [], image: null, scene: null, ground_truth: [], tf: 0,
              errors: [] };
out.counts = {};
const want = new Set([`/${robot}/scan`, `/${robot}/camera/image_raw`, "/scene", "/tf",
                      `/${robot}/ground_truth`, `/${robot}/robot_description`, "/tf_static",
                      `/${robot}/odom`]);
let done = false;

function finish(code) {
  if (done) return;
  done = true;
  const cpu = process.cpuUsage();
  out.cpu_s = (cpu.user + cpu.system) / 1e6;
  fs.writeFileSync(outPath, JSON.stringify(out));
  try { client.close(); } catch (e) { /* closing */ }
  setTimeout(() => process.exit(code), 50);
}
setTimeout(() => { out.errors.push("timeout"); finish(1); }, TIMEOUT_MS);
process.on("SIGINT", () => finish(0));
process.on("SIGTERM", () => finish(0));

function setup(client) {
client.on("error", (e) => { out.errors.push(String(e && e.message || e)); });
client.on("serverInfo", (info) => { out.server = { name: info.name, capabilities: info.capabilities,
                                                   supportedEncodings: info.supportedEncodings }; });
client.on("advertise", (chs) => {
  for (const ch of chs) {
    out.channels.push({ topic: ch.topic, encoding: ch.encoding, schemaName: ch.schemaName,
                        schemaEncoding: ch.schemaEncoding });
    if (ch.encoding !== "cdr" || ch.schemaEncoding !== "ros2msg") continue;
    const reader = new MessageReader(parse(ch.schema, { ros2: true }));
    channels.set(ch.id, { topic: ch.topic, schemaName: ch.schemaName, reader });
    const pick = layoutTopics ? layoutTopics.has(ch.topic) : (watch || want.has(ch.topic));
    if (pick) subs.set(client.subscribe(ch.id), channels.get(ch.id));
  }
});

let twistChannel = null;
let resetAt = null;           // ground truths received when the reset answered
const services = new Map();   // name -> service
client.on("advertiseServices", (svcs) => { for (const s of svcs) services.set(s.name, s); });
client.on("serviceCallResponse", (r) => {
  out.reset_response = { encoding: r.encoding, bytes: r.data.byteLength };
  resetAt = out.ground_truth.length;
});
client.on("serviceCallFailure", (f) => { out.errors.push(`service call: ${f.message}`); finish(1); });
let twistTimer = null;
client.on("message", ({ subscriptionId, data }) => {
  const ch = subs.get(subscriptionId);
  if (!ch) return;
  const msg = ch.reader.readMessage(new Uint8Array(data.buffer, data.byteOffset, data.byteLength));
  out.counts[ch.topic] = (out.counts[ch.topic] || 0) + 1;
  if (watch) return;
  const stamp = msg.header ? msg.header.stamp.sec * 1e9 + msg.header.stamp.nanosec : null;
  if (ch.topic.endsWith("/scan") && out.scans.length < 5) {
    out.scans.push({ stamp, frame_id: msg.header.frame_id, ranges: Array.from(msg.ranges,
      (r) => (Number.isFinite(r) ? r : null)) });
  } else if (ch.topic.endsWith("/camera/image_raw") && !out.image) {
    out.image = { stamp, frame_id: msg.header.frame_id, width: msg.width, height: msg.height,
                  encoding: msg.encoding, bytes: msg.data.length,
                  sum: msg.data.reduce((a, b) => a + b, 0) };
  } else if (ch.topic === "/scene" && !out.scene) {
    out.scene = msg.markers.map((m) => ({ ns: m.ns, id: m.id, type: m.type, frame: m.header.frame_id,
      name: m.text, position: [m.pose.position.x, m.pose.position.y, m.pose.position.z],
      orientation: [m.pose.orientation.x, m.pose.orientation.y, m.pose.orientation.z,
                    m.pose.orientation.w],
      scale: [m.scale.x, m.scale.y, m.scale.z], color: [m.color.r, m.color.g, m.color.b] }));
  } else if (ch.topic === "/tf") {
    out.tf += 1;
  } else if (ch.topic === "/tf_static") {
    out.tf_static = msg.transforms.map((t) => [t.header.frame_id, t.child_frame_id]);
  } else if (ch.topic.endsWith("/robot_description")) {
    out.robot_description = msg.data;
  } else if (ch.topic.endsWith("/odom") && !out.odom) {
    const p = msg.pose.pose.position;
    out.odom = { stamp, frame_id: msg.header.frame_id, child_frame_id: msg.child_frame_id,
                 x: p.x, y: p.y };
  } else if (ch.topic.endsWith("/ground_truth")) {
    const p = msg.pose.pose.position;
    out.ground_truth.push([stamp, p.x, p.y]);
  }
  const ready = out.scans.length >= 3 && out.image && out.scene && out.tf > 0;
  if (phase === "receive" && ready) finish(0);
  if ((phase === "full" || phase === "reset") && ready && !twistChannel) {
    // As Foxglove's Teleop panel: advertise geometry_msgs/msg/Twist (cdr) and publish it.
    const def = "geometry_msgs/Vector3 linear\ngeometry_msgs/Vector3 angular\n" +
      "================================================================================\n" +
      "MSG: geometry_msgs/Vector3\nfloat64 x\nfloat64 y\nfloat64 z\n";
    twistChannel = client.advertise({ topic: `/${robot}/cmd_vel_unstamped`, encoding: "cdr",
                                      schemaName: "geometry_msgs/msg/Twist", schema: def,
                                      schemaEncoding: "ros2msg" });
    const writer = new MessageWriter(parse(def, { ros2: true }));
    out.twist_from = out.ground_truth.length;
    twistTimer = setInterval(() => {
      const bytes = writer.writeMessage({ linear: { x: 0.4, y: 0, z: 0 }, angular: { x: 0, y: 0, z: 0 } });
      client.sendMessage(twistChannel, bytes);
      out.twists_sent = (out.twists_sent || 0) + 1;
    }, 100);
  }
  if (twistChannel && twistTimer && out.ground_truth.length - out.twist_from > 40) {
    const a = out.ground_truth[out.twist_from];
    const b = out.ground_truth[out.ground_truth.length - 1];
    out.moved_m = Math.hypot(b[1] - a[1], b[2] - a[2]);
    if ((out.moved_m > 0.1 || out.ground_truth.length - out.twist_from > 2000) && twistTimer) {
      clearInterval(twistTimer);
      twistTimer = null;
      const reset = services.get("/reset_simulation");
      if (phase !== "reset") finish(0);
      else if (!reset) { out.errors.push("no /reset_simulation service"); finish(1); }
      // as Foxglove's Service Call panel: std_srvs/srv/Empty, an empty request
      else client.sendServiceCallRequest({ serviceId: reset.id, callId: 1, encoding: "cdr",
                                           data: new Uint8Array([0, 1, 0, 0, 0]) });
    }
  }
  if (resetAt !== null && out.ground_truth.length > resetAt + 3) {
    out.after_reset = out.ground_truth.slice(resetAt + 2, resetAt + 4);
    finish(0);
  }
});
}
connect();

// zensim viz page: meshcat's viewer for the robot, a panel that talks JSON over our own websocket.
// Nothing received is eval'd: meshcat's set_control (which evals callback strings) is switched off
// and only drawing commands reach the viewer.
"use strict";

const state = {
  connected: false, sceneReady: false, generation: -1, framesApplied: 0, connects: 0,
  robot: null, status: null, lastReply: null, lastError: null,
};
window.zensim = state;

const viewer = new MeshCat.Viewer(document.getElementById("meshcat-pane"));
viewer.set_control = function () { console.warn("zensim: set_control ignored"); };
const DRAWING_COMMANDS = new Set(["set_object", "set_transform", "set_property", "delete"]);
const meshcatHandle = viewer.handle_command.bind(viewer);
viewer.handle_command = (cmd) => { if (DRAWING_COMMANDS.has(cmd.type)) meshcatHandle(cmd); };
state.viewer = viewer;
// For tests and the console: where a link of `robot` or `ghost` is drawn now.
state.linkPosition = (root, link) => {
  const p = viewer.scene_tree.find([root, link]).object.position;
  return [p.x, p.y, p.z];
};

// Camera for a standing humanoid. meshcat's camera frame is y-up: [x, up, -y] in the world.
viewer.set_property(["Cameras", "default", "rotated", "<object>"], "position", [2.0, 1.1, 1.0]);

let ws = null;
let nodes = [];
let ghostVisible = false;
const sliders = new Map();   // joint name -> {input, value, touched}
const $ = (id) => document.getElementById(id);

function send(obj) {
  if (ws && ws.readyState === WebSocket.OPEN) ws.send(JSON.stringify(obj));
}

function connect() {
  const url = (location.protocol === "https:" ? "wss://" : "ws://") + location.host + "/ws";
  ws = new WebSocket(url);
  ws.binaryType = "arraybuffer";
  ws.onopen = () => { state.connected = true; state.connects += 1; banner(); };
  ws.onclose = () => {
    state.connected = false; state.sceneReady = false; banner();
    setTimeout(connect, 1000);   // the viz may be restarting: come back by ourselves
  };
  ws.onmessage = (ev) => {
    if (typeof ev.data === "string") onJson(JSON.parse(ev.data));
    else onBinary(ev.data);
  };
}

function onBinary(buf) {
  const head = new Uint32Array(buf, 0, 2);
  const kind = head[0], generation = head[1];
  if (kind === 1) {
    viewer.handle_command_bytearray(new Uint8Array(buf.slice(8)));
  } else if (kind === 2) {
    if (generation === state.generation && nodes.length) applyFrame(new Float32Array(buf, 8));
    // Ack once drawn: the server sends the next (newest) frame only then, so nothing queues.
    requestAnimationFrame(() => {
      if (generation === state.generation && state.framesApplied > 0) state.sceneReady = true;
      send({ type: "ack" });
    });
  }
}

function applyFrame(floats) {
  const n = Math.min(nodes.length, floats.length / 16);
  for (let i = 0; i < n; i++) nodes[i].set_transform(floats.subarray(16 * i, 16 * i + 16));
  viewer.set_dirty();
  state.framesApplied += 1;
}

function onJson(msg) {
  if (msg.type === "robot") onRobot(msg);
  else if (msg.type === "status") onStatus(msg);
  else if (msg.type === "ctl_reply") {
    state.lastReply = msg;
    $("reply").textContent = `${msg.verb}: ${msg.ok ? "ok" : "failed: " + (msg.error || "")}`;
    $("reply").className = msg.ok ? "small" : "small bad";
  } else if (msg.type === "error") {
    state.lastError = msg.error;
    $("reply").textContent = msg.error; $("reply").className = "small bad";
  }
}

function onRobot(msg) {
  state.robot = msg;
  state.generation = msg.generation;
  state.sceneReady = false;
  nodes = msg.paths.map((p) => viewer.scene_tree.find(p.split("/").filter((x) => x.length)));
  ghostVisible = false;
  $("robot-name").textContent = msg.name;
  buildSliders(msg.joints);
}

function buildSliders(joints) {
  const box = $("sliders");
  box.textContent = "";
  sliders.clear();
  for (const j of joints) {
    const div = document.createElement("div");
    div.className = "joint";
    const label = document.createElement("label");
    const name = document.createElement("span"); name.textContent = j.name;
    const value = document.createElement("span"); value.textContent = "0.000";
    label.append(name, value);
    const input = document.createElement("input");
    input.type = "range"; input.id = "slider-" + j.name; input.dataset.joint = j.name;
    input.min = j.lower; input.max = j.upper; input.step = 0.001;
    input.value = Math.min(Math.max(0, j.lower), j.upper);
    const entry = { input, value, touched: 0 };
    input.addEventListener("input", () => {
      entry.touched = performance.now();
      value.textContent = Number(input.value).toFixed(3);
      send({ type: "targets", names: [j.name], q: [Number(input.value)] });
    });
    div.append(label, input);
    box.append(div);
    sliders.set(j.name, entry);
  }
}

function onStatus(msg) {
  state.status = msg;
  const sim = msg.sim;
  $("sim-time").textContent = sim ? sim.sim_time_s.toFixed(2) + " s" : "–";
  $("rtf").textContent = sim ? sim.rtf.toFixed(2) : "–";
  $("sim-state").textContent = sim ? `${sim.paused ? "paused" : "running"}, ${sim.mode}` : "–";
  $("fallen").textContent = sim ? (sim.fallen ? "yes" : "no") : "–";
  $("fallen").className = sim && sim.fallen ? "bad" : "";
  if (sim && document.activeElement !== $("mode")) $("mode").value = sim.mode;
  const alive = $("alive");
  alive.textContent = "";
  for (const s of ["sim", "bridge", "viz", "router"]) {
    const span = document.createElement("span");
    const up = msg.alive.includes(s);
    span.className = up ? "up" : "down"; span.textContent = s;
    alive.append(span);
  }
  $("description").textContent = msg.description === "ok" ? (state.robot ? state.robot.source : "") : msg.description;
  if (msg.targets) {
    if (!ghostVisible) { viewer.set_property(["ghost"], "visible", true); ghostVisible = true; }
    // Sliders follow the targets the bridge holds, except one the user moved in the last second.
    const now = performance.now();
    msg.targets.names.forEach((name, i) => {
      const s = sliders.get(name);
      if (s && now - s.touched > 1000) { s.input.value = msg.targets.q[i]; s.value.textContent = msg.targets.q[i].toFixed(3); }
    });
  }
}

function banner() {
  const b = $("banner");
  b.textContent = state.connected ? "" : "disconnected: reconnecting…";
  b.className = state.connected ? "ok" : "";
}

for (const verb of ["reset", "pause", "resume", "step"]) {
  $("btn-" + verb).addEventListener("click", () => send({ type: "ctl", verb }));
}
$("mode").addEventListener("change", () => send({ type: "mode", mode: $("mode").value }));

connect();

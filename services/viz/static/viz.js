// zensim viz page: meshcat's viewer for the robot, a panel that talks JSON over our own websocket.
// Nothing received is eval'd: meshcat's set_control (which evals callback strings) is switched off
// and only drawing commands reach the viewer.
"use strict";

const state = {
  connected: false, sceneReady: false, generation: -1, framesApplied: 0, connects: 0,
  robot: null, status: null, lastReply: null, lastError: null,
  selected: null,   // a world's viewer: the robot the panel acts on
  role: null,       // "operator" (drives) or "viewer" (watches), from the viz's hello
  loco: null,       // the walking controller's state (state/loco), as the last status carried it
  drive: { sent: 0, last: null, keys: [], gamepad: false },
  follow: true,     // the camera follows the selected robot
};
window.zensim = state;

const viewer = new MeshCat.Viewer(document.getElementById("meshcat-pane"));
viewer.set_control = function () { console.warn("zensim: set_control ignored"); };
const DRAWING_COMMANDS = new Set(["set_object", "set_transform", "set_property", "delete"]);
const meshcatHandle = viewer.handle_command.bind(viewer);
viewer.handle_command = (cmd) => { if (DRAWING_COMMANDS.has(cmd.type)) meshcatHandle(cmd); };
state.viewer = viewer;
// For tests and the console: where a link of `robot` or `ghost` (a world's `robots/<id>`, `ghosts/<id>`)
// is drawn now, in the world frame.
const pathOf = (root) => root.split("/");
state.linkPosition = (root, link) => {
  const p = viewer.scene_tree.find([...pathOf(root), link]).object.position;
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

// A robot's scene commands (kind 1) are kept until the robot message that follows them and applied
// in one task: applied as they arrive, the viewer redraws the growing scene between messages, which
// with the G1's shells and software WebGL made the first full frame seconds late.
let pendingScene = { generation: -1, commands: [] };

function onBinary(buf) {
  const head = new Uint32Array(buf, 0, 2);
  const kind = head[0], generation = head[1];
  if (kind === 1) {
    if (generation !== pendingScene.generation) pendingScene = { generation, commands: [] };
    pendingScene.commands.push(new Uint8Array(buf.slice(8)));
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
  followCamera();
  viewer.set_dirty();
  state.framesApplied += 1;
}

function onJson(msg) {
  if (msg.type === "hello") onHello(msg);
  else if (msg.type === "robot") onRobot(msg);
  else if (msg.type === "status") onStatus(msg);
  else if (msg.type === "ctl_reply") {
    state.lastReply = msg;
    $("reply").textContent = `${msg.verb}: ${msg.ok ? "ok" : "failed: " + (msg.error || "")}`;
    $("reply").className = msg.ok ? "small" : "small bad";
  } else if (msg.type === "plot") {
    onPlot(msg);
  } else if (msg.type === "error") {
    state.lastError = msg.error;
    $("reply").textContent = msg.error; $("reply").className = "small bad";
  }
}

function onRobot(msg) {
  if (pendingScene.generation === msg.generation) {
    for (const command of pendingScene.commands) viewer.handle_command_bytearray(command);
  }
  pendingScene = { generation: -1, commands: [] };
  state.robot = msg;
  state.generation = msg.generation;
  state.sceneReady = false;
  nodes = msg.paths.map((p) => viewer.scene_tree.find(p.split("/").filter((x) => x.length)));
  ghostVisible = false;
  followFrom = null;
  if (msg.robots) { onWorld(msg); return; }
  $("robot-name").textContent = msg.name;
  buildSliders(msg.joints);
  buildPlotChoices(msg.joints);
}

// --- a world of several robots (zensim viz --world) ----------------------------------------------
// Every robot is drawn at its own pose; the panel (sliders, buttons, status, plots, the ghost) acts on
// the one selected here, and the viz is told which (`select`), so what it sends back is that robot's.

let worldFramed = false;

function onWorld(msg) {
  for (const robot of msg.robots) {
    if (robot.copy_of) {
      // Sent without shapes: its description is another robot's, whose shapes it copies.
      const from = msg.robots.find((r) => r.id === robot.copy_of);
      robot.roots.forEach((root, i) =>
        copyShapes(viewer.scene_tree.find(pathOf(from.roots[i])), viewer.scene_tree.find(pathOf(root))));
    }
    if (robot.roots[1]) viewer.set_property(pathOf(robot.roots[1]), "visible", false);
  }
  const select = $("robot-select");
  select.textContent = "";
  for (const robot of msg.robots) {
    const option = document.createElement("option");
    option.value = robot.id;
    option.textContent = `${robot.id} (${robot.name}, ${robot.mode})`;
    select.append(option);
  }
  $("robot-choice").hidden = false;
  $("mode-choice").hidden = true;   // the sim refuses ctl/mode for a robot of a world
  if (!worldFramed) frameWorld(msg.robots);   // once: a later scene (the world restarted) keeps the user's view
  worldFramed = true;
  const kept = msg.robots.some((r) => r.id === state.selected) ? state.selected : msg.robots[0].id;
  state.selected = null;
  selectRobot(kept, false);
}

// Copies of the shapes under `from` (meshcat scene nodes) under `to`: the same geometry and materials
// in memory, so the meshes of a description cross the network and sit in the GPU once.
function copyShapes(from, to) {
  for (const [name, child] of Object.entries(from.children)) {
    const node = to.find([name]);
    if (name === "<object>") {
      node.set_object(child.object.clone());
      continue;
    }
    for (const part of ["position", "quaternion", "scale"]) node.object[part].copy(child.object[part]);
    copyShapes(child, node);
  }
}

function selectedRobot() {
  return state.robot && state.robot.robots ? state.robot.robots.find((r) => r.id === state.selected) : null;
}

function selectRobot(id, recentre) {
  const before = selectedRobot();
  if (before && before.roots[1]) viewer.set_property(pathOf(before.roots[1]), "visible", false);
  ghostVisible = false;
  state.selected = id;
  state.status = null;
  followFrom = null;
  followRecentre = recentre;   // the user picked another robot: the camera moves to it
  const robot = selectedRobot();
  $("robot-select").value = id;
  $("robot-name").textContent = `${state.robot.name}: ${id}`;
  send({ type: "select", robot: id });   // first: the plot request that may follow is for this robot
  buildSliders(robot.joints);
  buildPlotChoices(robot.joints);
}

// The camera looks at the middle of the robots' spawn places, from the -y side and far enough to see
// them all (meshcat's camera frame is y-up: [x, up, -y] in the world).
function frameWorld(robots) {
  const xs = robots.map((r) => r.xy[0]), ys = robots.map((r) => r.xy[1]);
  const cx = (Math.min(...xs) + Math.max(...xs)) / 2, cy = (Math.min(...ys) + Math.max(...ys)) / 2;
  const k = Math.max(1, 0.5 + Math.max(Math.max(...xs) - Math.min(...xs), Math.max(...ys) - Math.min(...ys)) / 4);
  viewer.controls.target.set(cx, 0.5, -cy);
  viewer.set_property(["Cameras", "default", "rotated", "<object>"], "position", [cx + 1.2 * k, 1.4 * k, -cy + 2.6 * k]);
  viewer.controls.update();
  viewer.set_dirty();
}

$("robot-select").addEventListener("change", () => selectRobot($("robot-select").value, true));

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
    input.disabled = state.role === "viewer";
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
  if (msg.robot !== undefined && msg.robot !== state.selected) return;   // sent before the page switched
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
  if (sim) onRtf(sim.rtf);
  onLoco(msg.loco, msg.drive);
  onDisturbances(sim);
  const shown = selectedRobot() || state.robot;
  $("description").textContent = msg.description === "ok" ? (shown ? shown.source : "") : msg.description;
  if (msg.targets) {
    if (!ghostVisible) {
      const robot = selectedRobot();
      const ghost = robot ? robot.roots[1] : "ghost";
      if (ghost) viewer.set_property(pathOf(ghost), "visible", true);
      ghostVisible = true;
    }
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

// --- plot panel ------------------------------------------------------------------------------
// plotly.js (from the plotly wheel, served by the viz) draws the axes; it is loaded only when the
// panel is first opened. The 3D view comes first: a redraw waits for the browser to be idle (at most
// PLOT_REDRAW_MAX_WAIT_MS), happens at most every PLOT_REDRAW_MS, and draws at most
// PLOT_MAX_POINTS points a curve (a 10 s window at 100 Hz is 1000 samples; the plot is ~600 px wide).
const PLOT_WINDOW_S = 10, RTF_WINDOW_S = 60, PLOT_REDRAW_MS = 250, PLOT_REDRAW_MAX_WAIT_MS = 1000;
const PLOT_MAX_POINTS = 300, MAX_PLOT_JOINTS = 6;
const PLOT_COLOURS = ["#4e9cff", "#ff9f40", "#5ad17a", "#ff5c7a", "#c38bff", "#ffd34e"];
const plot = { on: false, joints: [], t: [], q: [], target: [], tau: [], rtfT: [], rtf: [], redraws: 0, redrawMs: 0, timer: null };
state.plot = plot;

function buildPlotChoices(joints) {
  const select = $("plot-joints");
  const keep = new Set(plot.joints);
  select.textContent = "";
  for (const j of joints) {
    const option = document.createElement("option");
    option.value = option.textContent = j.name;
    option.selected = keep.has(j.name);
    select.append(option);
  }
  if (plot.on) requestPlot();
}

function loadPlotly() {
  if (window.Plotly) return Promise.resolve();
  return new Promise((resolve, reject) => {
    const script = document.createElement("script");
    script.src = "/plotly/plotly.min.js";
    script.onload = resolve; script.onerror = () => reject(new Error("plotly.js did not load"));
    document.head.append(script);
  });
}

function requestPlot() {
  plot.joints = [...$("plot-joints").selectedOptions].map((o) => o.value).slice(0, MAX_PLOT_JOINTS);
  plot.t = []; plot.q = plot.joints.map(() => []); plot.target = plot.joints.map(() => []); plot.tau = plot.joints.map(() => []);
  send({ type: "plot", joints: plot.joints });
  scheduleRedraw();
}

async function setPlotting(on) {
  plot.on = on;
  $("btn-plot").textContent = on ? "Hide plots" : "Show plots";
  if (!on) { $("plots").hidden = true; send({ type: "plot", joints: [] }); return; }
  try { await loadPlotly(); } catch (err) { state.lastError = String(err); $("reply").textContent = String(err); return; }
  $("plots").hidden = false;
  requestPlot();
}

function onPlot(msg) {
  if (msg.joints.join() !== plot.joints.join()) return;   // a batch for an earlier choice
  if (msg.clear) { plot.t = []; plot.q = plot.joints.map(() => []); plot.target = plot.joints.map(() => []); plot.tau = plot.joints.map(() => []); }
  plot.t.push(...msg.t);
  msg.joints.forEach((_, i) => { plot.q[i].push(...msg.q[i]); plot.target[i].push(...msg.target[i]); plot.tau[i].push(...msg.tau[i]); });
  const start = plot.t.length ? plot.t[plot.t.length - 1] - PLOT_WINDOW_S : 0;
  let cut = 0;
  while (cut < plot.t.length && plot.t[cut] < start) cut++;
  if (cut) {
    plot.t.splice(0, cut);
    for (const arr of [...plot.q, ...plot.target, ...plot.tau]) arr.splice(0, cut);
  }
  scheduleRedraw();
}

function onRtf(rtf) {
  const now = performance.now() / 1000;
  plot.rtfT.push(now); plot.rtf.push(rtf);
  while (plot.rtfT.length && plot.rtfT[0] < now - RTF_WINDOW_S) { plot.rtfT.shift(); plot.rtf.shift(); }
  if (plot.on) scheduleRedraw();
}

function scheduleRedraw() {
  if (!plot.on || !window.Plotly || plot.timer !== null) return;
  plot.timer = setTimeout(() => {
    const idle = window.requestIdleCallback || ((f) => setTimeout(f, 0));
    idle(() => { plot.timer = null; redrawPlots(); }, { timeout: PLOT_REDRAW_MAX_WAIT_MS });
  }, PLOT_REDRAW_MS);
}

function thin(values, stride) {
  return stride <= 1 ? values.slice() : values.filter((_, i) => i % stride === 0 || i === values.length - 1);
}

const PLOT_LAYOUT = {
  paper_bgcolor: "rgba(0,0,0,0)", plot_bgcolor: "rgba(0,0,0,0)", font: { color: "#dde", size: 11 },
  margin: { l: 50, r: 10, t: 24, b: 34 }, showlegend: true, legend: { orientation: "h", y: 1.12, font: { size: 10 } },
};

function redrawPlots() {
  if (!plot.on || $("plots").hidden) return;
  const started = performance.now();
  const traces = [];
  const stride = Math.ceil(plot.t.length / PLOT_MAX_POINTS);
  const t = thin(plot.t, stride);
  plot.joints.forEach((name, i) => {
    const colour = PLOT_COLOURS[i % PLOT_COLOURS.length];
    traces.push({ x: t, y: thin(plot.q[i], stride), name: name + " q", mode: "lines", line: { color: colour, width: 2 } });
    traces.push({ x: t, y: thin(plot.target[i], stride), name: "target", mode: "lines", line: { color: colour, width: 1.5, dash: "dash" } });
    traces.push({ x: t, y: thin(plot.tau[i], stride), name: "torque", mode: "lines", line: { color: colour, width: 1 }, yaxis: "y2", showlegend: false });
  });
  // The arrays grow in place: datarevision tells Plotly.react the data changed.
  const joints = Object.assign({}, PLOT_LAYOUT, { datarevision: plot.redraws,
    title: { text: plot.joints.length ? "" : "pick joints in the panel", font: { size: 12 } },
    xaxis: { title: { text: "sim time (s)" }, anchor: "y2", gridcolor: "#3c434e" },
    yaxis: { title: { text: "position (rad)" }, domain: [0.42, 1], gridcolor: "#3c434e" },
    yaxis2: { title: { text: "torque (N m)" }, domain: [0, 0.32], gridcolor: "#3c434e" },
  });
  const config = { staticPlot: true, displayModeBar: false };
  Plotly.react("plot-joints-chart", traces, joints, config);
  const now = performance.now() / 1000;
  Plotly.react("plot-rtf-chart",
    [{ x: plot.rtfT.map((t) => t - now), y: plot.rtf, name: "RTF", mode: "lines", line: { color: "#e377c2", width: 2 } }],
    Object.assign({}, PLOT_LAYOUT, { datarevision: plot.redraws, showlegend: false, title: { text: "real-time factor", font: { size: 12 } },
      xaxis: { title: { text: "wall time (s)" }, gridcolor: "#3c434e" }, yaxis: { rangemode: "tozero", gridcolor: "#3c434e" } }),
    config);
  plot.redraws += 1;
  plot.redrawMs += performance.now() - started;   // main-thread time the plots took (benchmarks/viz_plots.py)
}

$("btn-plot").addEventListener("click", () => setPlotting(!plot.on));

// --- the page's role -------------------------------------------------------------------------
// A page opened with the viewer's token watches: its driving controls are hidden, and the viz refuses
// whatever driving message it would send anyway.
function onHello(msg) {
  state.role = msg.role;
  const watching = msg.role !== "operator";
  for (const id of ["controls", "drive-buttons", "drive-keys", "band-buttons", "push-controls"]) $(id).hidden = watching;
  $("watch-only").hidden = !watching;
  for (const s of sliders.values()) s.input.disabled = watching;
}

// --- driving: keys and gamepad -> cmd/velocity (and cmd/remote, Unitree's wireless remote) --------
// The page sends a `drive` message when what is held changes, and again every KEEP_ALIVE_MS while
// something is held (each command holds for 1 s of sim time: a page that dies leaves a robot that stops).
// Auto-repeat keydowns are not sent; the viz paces every page's drive puts per robot anyway.
const KEY_VELOCITY = { vx: 0.5, vy: 0.3, wz: 0.6 };   // m/s, m/s, rad/s while a key is held
const KEEP_ALIVE_MS = 100, GAMEPAD_POLL_MS = 50, STICK_DEADZONE = 0.12;
const DRIVE_KEYS = new Set(["w", "a", "s", "d", "q", "e"]);
// The standard gamepad mapping's buttons, as Unitree's remote names them (cmd/remote).
const PAD_BUTTONS = { 0: "A", 1: "B", 2: "X", 3: "Y", 4: "L1", 5: "R1", 6: "L2", 7: "R2", 8: "Select", 9: "Start",
                      12: "Up", 13: "Down", 14: "Left", 15: "Right" };
const held = new Set();
let lastDrive = null, lastDriveAt = 0, padWasPressed = {};

// Tests (and the console) can stand in for a gamepad: `zensim.setGamepads([{axes: [0, -1, 0, 0],
// buttons: [{pressed: true}]}])`; null gives the browser's own back.
state.fakeGamepads = null;
state.setGamepads = (pads) => { state.fakeGamepads = pads; pollDrive(); };
state.send = send;

function gamepads() {
  if (state.fakeGamepads) return state.fakeGamepads;
  return navigator.getGamepads ? [...navigator.getGamepads()].filter((p) => p) : [];
}

function stick(value) {
  return Math.abs(value) < STICK_DEADZONE ? 0 : Math.max(-1, Math.min(1, value));
}

function round(x) { return Math.round(x * 1000) / 1000; }

// What is held now: keys and the first gamepad, summed.
function driveInput() {
  const k = (key) => (held.has(key) ? 1 : 0);
  const remote = { lx: k("d") - k("a"), ly: k("w") - k("s"), rx: k("e") - k("q"), ry: 0 };
  const buttons = [];
  const pad = gamepads()[0];
  state.drive.gamepad = Boolean(pad);
  if (pad) {
    const axes = pad.axes || [];
    // Browsers report "up" as negative: the remote's ly and ry are forward positive.
    remote.lx += stick(axes[0] || 0); remote.ly -= stick(axes[1] || 0);
    remote.rx += stick(axes[2] || 0); remote.ry -= stick(axes[3] || 0);
    (pad.buttons || []).forEach((b, i) => {
      const pressed = Boolean(b && (b.pressed || b.value > 0.5));
      if (pressed && PAD_BUTTONS[i]) buttons.push(PAD_BUTTONS[i]);
      if (pressed && !padWasPressed[i] && state.role === "operator") {
        if (i === 0) send({ type: "loco", verb: "walk" });   // A: stand up, then walk
        if (i === 1) send({ type: "loco", verb: "damp" });   // B: damp
      }
      padWasPressed[i] = pressed;
    });
  }
  // Polled 20 times a second: the DOM is touched only when the text changes.
  const padText = pad ? `gamepad: ${String(pad.id || "").slice(0, 40)} (sticks walk and turn; A stand, B damp)` : "no gamepad";
  if ($("gamepad").textContent !== padText) $("gamepad").textContent = padText;
  for (const axis of ["lx", "ly", "rx", "ry"]) remote[axis] = round(Math.max(-1, Math.min(1, remote[axis])));
  // Sticks at full tilt ask for the robot's limits (state/loco); keys for KEY_VELOCITY.
  const limits = (state.loco && state.loco.velocity_limits) || [KEY_VELOCITY.vx, KEY_VELOCITY.vy, KEY_VELOCITY.wz];
  const scale = pad ? limits : [KEY_VELOCITY.vx, KEY_VELOCITY.vy, KEY_VELOCITY.wz];
  return { type: "drive", vx: round(remote.ly * scale[0]), vy: round(-remote.lx * scale[1]), wz: round(-remote.rx * scale[2]),
           buttons, lx: remote.lx, ly: remote.ly, rx: remote.rx, ry: remote.ry };
}

function isZero(d) {
  return !d.vx && !d.vy && !d.wz && !d.buttons.length && !d.lx && !d.ly && !d.rx && !d.ry;
}

// Send what is held when it changed, or again while something is held (the keep-alive).
function pollDrive(force) {
  if (state.role !== "operator") return;
  const input = driveInput();
  const text = JSON.stringify(input), now = performance.now();
  // Nothing held since the page opened: nothing to say (a page opening must not stop a robot another drives).
  if (lastDrive === null && isZero(input) && !force) return;
  const changed = text !== lastDrive;
  if (!force && !changed && (isZero(input) || now - lastDriveAt < KEEP_ALIVE_MS)) return;
  if (!state.connected) return;
  send(input);
  lastDrive = text; lastDriveAt = now;
  state.drive.sent += 1; state.drive.last = input; state.drive.keys = [...held];
}

function typingIn(target) {
  const tag = target && target.tagName;
  return tag === "SELECT" || tag === "TEXTAREA" || (tag === "INPUT" && target.type !== "range" && target.type !== "checkbox");
}

window.addEventListener("keydown", (ev) => {
  if (ev.ctrlKey || ev.metaKey || ev.altKey || typingIn(ev.target)) return;
  const key = ev.key.toLowerCase();
  if (key === " ") {
    ev.preventDefault();
    held.clear();
    pollDrive(true);   // a stop always goes out, even when nothing was held
    return;
  }
  if (!DRIVE_KEYS.has(key)) return;
  ev.preventDefault();
  if (ev.repeat || held.has(key)) return;   // auto-repeat: the keep-alive already repeats
  held.add(key);
  pollDrive();
});
window.addEventListener("keyup", (ev) => {
  const key = ev.key.toLowerCase();
  if (held.delete(key)) pollDrive();
});
// A page that loses focus never hears the keyup: let go of everything.
window.addEventListener("blur", () => { if (held.size) { held.clear(); pollDrive(); } });
setInterval(pollDrive, GAMEPAD_POLL_MS);

$("btn-stand").addEventListener("click", () => send({ type: "loco", verb: "walk" }));
$("btn-damp").addEventListener("click", () => send({ type: "loco", verb: "damp" }));

// --- disturbances: the elastic band (ctl/band) and a push (ctl/push), shown from state/sim -----------
for (const button of document.querySelectorAll("[data-band]")) {
  button.addEventListener("click", () => send({ type: "band", verb: button.dataset.band }));
}
$("btn-push").addEventListener("click", () => send({ type: "push", direction: $("push-direction").value }));

function onDisturbances(sim) {
  const band = sim ? sim.band : null;   // state/sim carries the band only while it holds the robot
  $("band-state").textContent = !sim ? "–" : band ? `on, length ${band.length_m.toFixed(2)} m` : "off";
  $("band-state").title = band && band.force_n.length ?
    `pull ${Math.hypot(...band.force_n).toFixed(0)} N; anchor ${band.anchor.map((v) => v.toFixed(2)).join(", ")} m` : "";
  const acting = sim && sim.pushes ? sim.pushes.length : 0;
  $("pushes").textContent = sim ? `${sim.pushes_applied || 0} applied${acting ? `, ${acting} acting` : ""}` : "–";
}

const FSM_NAMES = { 0: "zero torque", 1: "damp", 3: "sit", 500: "walk", 702: "stand up", 706: "stand up" };

function velocityText(v) {
  return `${v[0].toFixed(2)}, ${v[1].toFixed(2)} m/s, ${v[2].toFixed(2)} rad/s`;
}

function onLoco(loco, drive) {
  state.loco = loco;
  if (!loco) {
    $("vel-commanded").textContent = $("vel-achieved").textContent = "–";
    $("loco-state").textContent = "no walking controller (zensim up --loco)";
    return;
  }
  $("vel-commanded").textContent = velocityText(loco.commanded);
  $("vel-achieved").textContent = velocityText(loco.achieved);
  const name = FSM_NAMES[loco.fsm_id] || `fsm ${loco.fsm_id}`;
  $("loco-state").textContent = !loco.active ? "idle: press Stand" :
    loco.walking ? (loco.stepping ? "stepping" : "standing, ready") : name;
  if (drive) $("loco-state").title = `drive inputs: ${drive.received} received, ${drive.sent} sent, ${drive.shed} shed`;
}

// --- the camera follows the selected robot -----------------------------------------------------
// Each frame moves the camera and its orbit target by as much as the robot's base moved over the
// ground, so the user's orbit and zoom stay as they were, relative to the robot. Off: the camera stays.
let followFrom = null, followRecentre = false;

function followedNode() {
  const robot = selectedRobot();
  const root = robot ? robot.roots[0] : (state.robot && state.robot.roots ? state.robot.roots[0] : "robot");
  const paths = state.robot ? state.robot.paths : [];
  const i = paths.findIndex((p) => p.replace(/^\//, "").startsWith(root + "/"));
  return i >= 0 && i < nodes.length ? nodes[i] : null;
}

function followCamera() {
  const node = followedNode();
  if (!state.follow || !node) { followFrom = null; return; }
  const camera = viewer.camera;
  // The base in the camera's own parent frame (meshcat's is y-up), where position and target live.
  const at = camera.parent.worldToLocal(node.object.getWorldPosition(camera.position.clone()));
  if (followRecentre) {
    followRecentre = false;
    const offset = camera.position.clone().sub(viewer.controls.target);
    viewer.controls.target.set(at.x, viewer.controls.target.y, at.z);
    camera.position.copy(viewer.controls.target).add(offset);
  } else if (followFrom) {
    const dx = at.x - followFrom.x, dz = at.z - followFrom.z;   // over the ground: not the body's bobbing
    camera.position.x += dx; camera.position.z += dz;
    viewer.controls.target.x += dx; viewer.controls.target.z += dz;
  }
  followFrom = at;
  viewer.controls.update();
}

$("follow").addEventListener("change", () => { state.follow = $("follow").checked; followFrom = null; });

// For tests: where a link is drawn on the screen now, -1..1 across the view (x right, y up).
state.screenPosition = (root, link) => {
  const object = viewer.scene_tree.find([...pathOf(root), link]).object;
  const p = object.getWorldPosition(viewer.camera.position.clone()).project(viewer.camera);
  return [p.x, p.y];
};

connect();

// The page of `orchestrator live`: one WebSocket to this tab's session. JSON messages both
// ways (orchestrator/src/commands/live/wire.rs); the webcam's frames go as binary JPEGs, one
// at a time: the next leaves once the server has answered the last.

const ACTIONS = ["MoveAhead", "RotateLeft", "RotateRight", "Stop"];
const GESTURES = ["none", "referencing", "intervention"];
// a side's colour: its path on the map, its bars, its panel's edge
const COLOURS = ["#d62728", "#1f5fbf"];
const $ = (id) => document.getElementById(id);

// What the page has seen, for people reading the console and for the browser test: the
// episode, and per side (one robot, or two when two checkpoints are compared) its steps, its
// path and its end; `ended` once every side has; of the webcam, the frames sent and read, and
// how many of those were read as a wave; `full`, why no session came (the server runs as many
// as it may).
const live = (window.live = {
  session: null, full: null, episode: null, sides: [], ended: false, episodes: [],
  framesSent: 0, framesSeen: 0, waving: false, wavingFrames: 0, captured: null, uploaded: null, errors: [],
  room: null, placed: { person: null, robot: null },
});

// an exception the page did not catch is an error of the page too
window.addEventListener("error", (e) => live.errors.push(`${e.message} (${e.filename}:${e.lineno})`));
window.addEventListener("unhandledrejection", (e) => live.errors.push(`unhandled: ${e.reason}`));

// the token printed at start, in the URL opened; a page opened without it (a reload of a bare
// URL) is let in by the cookie the server set, which the socket and the uploads carry too
const token = new URLSearchParams(location.search).get("token");
const scheme = location.protocol === "https:" ? "wss" : "ws";
const ws = new WebSocket(`${scheme}://${location.host}/ws${token ? "?token=" + encodeURIComponent(token) : ""}`);
ws.binaryType = "arraybuffer";
const send = (m) => ws.readyState === WebSocket.OPEN && ws.send(JSON.stringify(m));

ws.onopen = () => ($("status").textContent = "connected");
ws.onclose = () => {
  if (!live.full) $("status").textContent = "disconnected: reload the page";
};
ws.onmessage = (ev) => {
  const m = JSON.parse(ev.data);
  const on = handlers[m.type];
  if (on) on(m);
};

// what the map shows: an episode, or a room where a program is being placed
const map = { img: null, t: null, target: null, person: null, placing: false };
let rooms = {};

const handlers = {
  hello(m) {
    live.session = m.session;
    $("status").textContent = `session ${m.session}`;
    const names = m.checkpoints.map((c, i) => new Option(`${c.name} (${c.method}, ${c.size[0]}×${c.size[1]})`, i));
    $("checkpoint").replaceChildren(...names);
    $("versus").replaceChildren(new Option("nothing", ""), ...names.map((o) => new Option(o.text, o.value)));
    $("split").replaceChildren(...m.splits.map(([name, n]) => new Option(`${name} (${n})`, name)));
    const val = m.splits.findIndex(([name]) => name === "val");
    if (val >= 0) $("split").selectedIndex = val;
    rooms = Object.fromEntries(m.rooms);
    showRooms();
  },
  room(m) {
    live.room = m;
    live.placed = { person: null, robot: null };
    $("target").replaceChildren(...m.targets.map((t) => new Option(`${t.name} (object ${t.object})`, t.object)));
    showMap(m.map_png, m.map_transform, true);
  },
  episode(m) {
    live.episode = m; live.ended = false;
    live.sides = m.sides.map(() => ({ steps: 0, path: [], end: null }));
    $("episode-label").textContent = `${m.label} · ${m.gesture} gesture · ${m.interventions} interventions`;
    $("sides").replaceChildren(...m.sides.map((s, k) => {
      const panel = $("side").content.firstElementChild.cloneNode(true);
      panel.id = `side-${k}`;
      panel.style.setProperty("--colour", COLOURS[k]);
      panel.querySelector(".side-label").textContent = `episode ${s.number}: ${s.checkpoint}`;
      return panel;
    }));
    avatar.sheets = [loadSheet(m.referencing), ...m.sides.map((s) => loadSheet(s.intervention))];
    Object.assign(map, { target: m.target, person: m.person });
    showMap(m.map_png, m.map_transform, false);
  },
  step(m) {
    const side = live.sides[m.side], panel = $(`side-${m.side}`);
    const put = (cls, text) => (panel.querySelector(cls).textContent = text);
    side.steps += 1;
    side.path.push(m.robot);
    panel.querySelector(".rgb").src = "data:image/png;base64," + m.rgb_png;
    panel.querySelector(".depth").src = "data:image/png;base64," + m.depth_png;
    put(".step-number", m.step);
    put(".value", m.value.toFixed(3));
    put(".distance", m.distance.toFixed(2));
    put(".shown", GESTURES[m.shown] ?? m.shown);
    side.shown = m.shown;
    put(".rule", GESTURES[m.rule] ?? m.rule);
    panel.querySelector(".probs").replaceChildren(...m.probs.map((p, a) => {
      const row = document.createElement("div");
      row.className = "bar" + (a === m.action ? " chosen" : "");
      row.innerHTML = `<span>${ACTIONS[a]}</span><div style="width:${(p * 160).toFixed(0)}px"></div><small>${(p * 100).toFixed(1)}%</small>`;
      return row;
    }));
    drawMap();
  },
  end(m) {
    live.sides[m.side].end = m;
    live.ended = live.sides.every((s) => s.end);
    live.episodes.push(m);
    const e = live.episode, outcome = $(`side-${m.side}`).querySelector(".outcome");
    outcome.textContent = m.success
      ? `success at the first stop · SPL ${m.spl.toFixed(2)}`
      : `no success at the first stop · DTS ${m.dts.toFixed(2)} m${m.success_any_stop ? " (found after more stops)" : ""}`;
    outcome.className = "outcome " + (m.success ? "success" : "failure");
    const row = document.createElement("tr");
    for (const v of [m.number, e.program, "AB"[m.side], e.sides[m.side].checkpoint, e.gesture, m.steps,
                     m.success ? "yes" : "no", m.spl.toFixed(2), m.dts.toFixed(2), m.record]) {
      const td = document.createElement("td"); td.textContent = v; row.append(td);
    }
    row.style.color = COLOURS[m.side];
    $("episodes").append(row);
  },
  frame_seen(m) {
    live.framesSeen += 1;
    live.waving = m.waving;
    if (m.waving) live.wavingFrames += 1;
    $("camera-status").textContent =
      `${live.framesSeen} frames read · ${m.person ? "you are seen" : "no one seen"}` +
      (m.waving ? " · waving: intervention!" : "") + (m.capturing ? " · capturing…" : "");
    camera.inFlight = false;
  },
  uploaded(m) {
    live.uploaded = m;
    $("upload-status").textContent = m.kind === "video"
      ? `${m.name}: a ${m.arm} arm gesture (a person in ${m.person_frames} of ${m.frames} frames); choose "my uploaded file" and start`
      : `${m.name}: a motion file; choose "my uploaded file" and start`;
  },
  captured(m) {
    live.captured = m;
    $("camera-status").textContent = `captured a ${m.arm} arm gesture (${m.seconds[0].toFixed(1)}–${m.seconds[1].toFixed(1)} s); choose "my webcam capture" and start`;
  },
  frame_refused(m) {
    handlers.error(m);
  },
  full(m) {
    live.full = m.message;
    $("status").textContent = m.message;
  },
  error(m) {
    live.errors.push(m.message);
    $("errors").textContent = m.message;
    camera.inFlight = false;
  },
};

function showMap(png, transform, placing) {
  map.img = null; map.t = transform; map.placing = placing;
  $("map").classList.toggle("placing", placing);
  const img = new Image();
  img.onload = () => { map.img = img; drawMap(); };
  img.src = "data:image/png;base64," + png;
}

// a world point (x, z) on the map picture and back: column = a·x + b·z + c, row = d·x + e·z + f
const toPixel = ([x, z]) => { const [a, b, c, d, e, f] = map.t; return [a * x + b * z + c, d * x + e * z + f]; };
function toWorld(u, v) {
  const [a, b, c, d, e, f] = map.t, det = a * e - b * d;
  return [(e * (u - c) - b * (v - f)) / det, (a * (v - f) - d * (u - c)) / det];
}

function drawMap() {
  const c = $("map"), g = c.getContext("2d");
  if (!map.img) return;
  if (c.width !== map.img.width) { c.width = map.img.width; c.height = map.img.height; }
  g.drawImage(map.img, 0, 0);
  const px = toPixel;
  if (map.placing) return drawPlacing(g);
  live.sides.forEach(({ path }, k) => {
    if (!path.length) return;
    g.strokeStyle = g.fillStyle = COLOURS[k]; g.lineWidth = 3; g.beginPath();
    path.forEach(([x, z], i) => { const [u, v] = px([x, z]); i ? g.lineTo(u, v) : g.moveTo(u, v); });
    g.stroke();
    const [x, z, yaw] = path[path.length - 1];
    const [u, v] = px([x, z]);
    const r = (yaw * Math.PI) / 180;
    // yaw 0 faces +z (up on the map), 90 faces +x
    g.beginPath();
    g.moveTo(u + 12 * Math.sin(r), v - 12 * Math.cos(r));
    g.lineTo(u + 7 * Math.cos(r), v + 7 * Math.sin(r));
    g.lineTo(u - 7 * Math.cos(r), v - 7 * Math.sin(r));
    g.fill();
  });
}

// placing a program: the room's targets (the chosen one ringed), the person and the robot
function drawPlacing(g) {
  const chosen = Number($("target").value);
  g.font = "12px system-ui"; g.lineWidth = 2;
  for (const t of live.room?.targets ?? []) {
    const [u, v] = toPixel(t.at);
    g.strokeStyle = t.object === chosen ? "#17803a" : "#888";
    g.beginPath(); g.arc(u, v, t.object === chosen ? 11 : 6, 0, 2 * Math.PI); g.stroke();
  }
  const { person, robot } = live.placed;
  if (person) {
    const [u, v] = toPixel(person);
    g.fillStyle = "#7a3db8"; g.beginPath(); g.arc(u, v, 7, 0, 2 * Math.PI); g.fill();
    g.fillText("person", u + 9, v - 6);
  }
  if (robot) {
    const [u, v] = toPixel(robot), r = (Number($("robot-yaw").value) * Math.PI) / 180;
    g.fillStyle = "#333"; g.beginPath();
    g.moveTo(u + 12 * Math.sin(r), v - 12 * Math.cos(r));
    g.lineTo(u + 7 * Math.cos(r), v + 7 * Math.sin(r));
    g.lineTo(u - 7 * Math.cos(r), v - 7 * Math.sin(r));
    g.fill(); g.fillText("robot", u + 9, v - 6);
  }
}

function showRooms() {
  const names = rooms[$("split").value] ?? [];
  $("room").replaceChildren(...names.map((r) => new Option(r, r)));
  if (placing()) askRoom();
}
const placing = () => $("program-kind").value === "placed";
const askRoom = () => $("room").value && send({ type: "room", split: $("split").value, room: $("room").value });
$("program-kind").onchange = () => { document.body.classList.toggle("placed", placing()); if (placing()) askRoom(); };
$("split").onchange = showRooms;
$("room").onchange = askRoom;
$("target").onchange = drawMap;
$("robot-yaw").oninput = drawMap;
$("map").onclick = (ev) => {
  if (!map.placing || !map.img) return;
  const c = $("map"), box = c.getBoundingClientRect();
  const u = ((ev.clientX - box.left) * c.width) / box.width, v = ((ev.clientY - box.top) * c.height) / box.height;
  live.placed[$("placing").value] = toWorld(u, v);
  // the robot next, once the person stands
  if ($("placing").value === "person" && !live.placed.robot) $("placing").value = "robot";
  drawMap();
};

// the gesture each robot perceives, performed by the program's person: the referencing film,
// or that side's intervention film, at 30 frames a second; nothing shown: the first frame, faded
const avatar = { sheets: [], frame: 0 };
function loadSheet(film) {
  const img = new Image();
  img.src = "data:image/jpeg;base64," + film.sheet_jpeg;
  return { film, img };
}
setInterval(() => {
  avatar.frame = (avatar.frame + 1) % 100;
  live.sides.forEach((side, k) => {
    const canvas = document.querySelector(`#side-${k} .avatar`);
    const sheet = side.shown === 2 ? avatar.sheets[1 + k] : avatar.sheets[0];
    if (!canvas || !sheet || !sheet.img.complete) return;
    const { tile, columns, frames } = sheet.film, t = side.shown ? avatar.frame % frames : 0;
    canvas.classList.toggle("none", !side.shown);
    canvas.title = side.shown ? sheet.film.name : "no gesture shown";
    canvas.getContext("2d").drawImage(sheet.img, (t % columns) * tile, Math.floor(t / columns) * tile, tile, tile, 0, 0, 120, 120);
  });
}, 1000 / 30);

// controls
$("start").onclick = () => {
  const where = {};
  if (placing()) {
    const { person, robot } = live.placed;
    if (!person || !robot) return handlers.error({ message: "place the person and the robot on the map first" });
    where.placed = {
      split: $("split").value, room: $("room").value, target: Number($("target").value),
      person, robot: [...robot, Number($("robot-yaw").value)],
    };
  } else {
    where.program = `${$("split").value}:${$("index").value}`;
  }
  send({
    type: "start",
    ...where,
    checkpoint: Number($("checkpoint").value),
    versus: $("versus").value === "" ? null : Number($("versus").value),
    gesture: $("gesture").value,
    interventions: $("interventions").value,
  });
};
const speed = () => Number($("speed").value);
$("speed").oninput = () => { $("speed-value").textContent = speed(); if (running) send({ type: "run", speed: speed() }); };
let running = false;
$("run").onclick = () => { running = true; send({ type: "run", speed: speed() }); };
$("pause").onclick = () => { running = false; send({ type: "pause" }); };
$("step").onclick = () => { running = false; send({ type: "step" }); };
$("intervene").onclick = () => send({ type: "intervene" });
$("capture").onclick = () => send({ type: "capture_gesture", seconds: 4 });
// an upload goes by HTTP to this tab's session; the session answers on the socket
$("upload").onclick = async () => {
  const file = $("upload-file").files[0];
  if (!file) return handlers.error({ message: "choose a video or a motion file first" });
  const name = file.name.replace(/[^A-Za-z0-9._-]/g, "_").replace(/^\.+/, "");
  const query = new URLSearchParams({ session: live.session, name });
  if (token) query.set("token", token);
  $("upload-status").textContent = `reading ${name}…`;
  const r = await fetch(`/upload?${query}`, { method: "POST", body: file });
  if (!r.ok) handlers.error({ message: `the upload: ${(await r.text()).trim()}` });
};
document.addEventListener("keydown", (e) => {
  if (e.target.tagName === "INPUT" || e.target.tagName === "SELECT") return;
  if (e.key === "i" || e.key === "I") send({ type: "intervene" });
  if (e.key === " ") { e.preventDefault(); $("step").click(); }
});

// the webcam: 320×240 JPEGs, one in flight, at most 15 a second
const camera = { stream: null, inFlight: false, canvas: document.createElement("canvas") };
camera.canvas.width = 320; camera.canvas.height = 240;
$("camera").onclick = async () => {
  if (camera.stream) {
    camera.stream.getTracks().forEach((t) => t.stop());
    camera.stream = null; $("camera").textContent = "Camera on"; $("camera-status").textContent = "camera off";
    return;
  }
  try {
    camera.stream = await navigator.mediaDevices.getUserMedia({ video: { width: 320, height: 240 } });
  } catch (e) {
    handlers.error({ message: `the camera: ${e.message} (the page needs localhost or HTTPS)` });
    return;
  }
  $("video").srcObject = camera.stream;
  await $("video").play();
  $("camera").textContent = "Camera off";
  sendFrames();
};
function sendFrames() {
  if (!camera.stream) return;
  setTimeout(sendFrames, 1000 / 15);
  if (camera.inFlight || ws.readyState !== WebSocket.OPEN) return;
  camera.inFlight = true;
  camera.canvas.getContext("2d").drawImage($("video"), 0, 0, 320, 240);
  camera.canvas.toBlob(async (blob) => {
    if (!blob) { camera.inFlight = false; return; }
    ws.send(await blob.arrayBuffer());
    live.framesSent += 1;
  }, "image/jpeg", 0.85);
}

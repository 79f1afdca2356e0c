// streamkey live dashboard: no build step, no dependencies. Connects to /ws on this origin.
"use strict";

const WINDOW_SECONDS = 10;   // the strip chart shows the last 10 s of the stream
const MAX_KEYS_SHOWN = 24;   // recent keyposes listed

const state = {
  methods: [], colors: {}, bones: null, fps: 120, frame: null, pose: null,
  signals: [], saliency: [], keys: [], pending: [], hold: false, ws: null, nextId: 1,
  dirty: true,
};

const $ = (id) => document.getElementById(id);

function connect() {
  const scheme = location.protocol === "https:" ? "wss:" : "ws:";
  const ws = new WebSocket(`${scheme}//${location.host}/ws${location.search}`);
  state.ws = ws;
  ws.onopen = () => setStatus("open", "connected");
  ws.onclose = () => setStatus("closed", "disconnected (the stream ended or the server stopped)");
  ws.onmessage = (msg) => {
    let m;
    try { m = JSON.parse(msg.data); } catch (e) { return; }
    const handler = HANDLERS[m.type];
    if (handler) handler(m);
  };
}

function setStatus(kind, text) {
  const el = $("status");
  el.dataset.state = kind;
  el.textContent = text;
}

function say(text, error) {
  const el = $("message");
  el.textContent = text;
  el.className = error ? "error" : "";
}

function note(text) { $("notes").textContent = text; }

function send(obj) {
  if (!state.ws || state.ws.readyState !== WebSocket.OPEN) {
    say("not connected", true);
    return;
  }
  obj.id = state.nextId++;
  state.ws.send(JSON.stringify(obj));
}

const HANDLERS = {
  hello(m) {
    state.methods = m.methods;
    state.colors = m.colors;
    state.bones = m.bones;
    state.fps = m.fps || state.fps;
    $("stream").textContent = `stream ${m.stream}`;
    buildLegend();
    state.signals = m.signals || [];
    state.saliency = m.saliency || [];
    if (state.signals.length) state.frame = state.signals[state.signals.length - 1].frame;
    for (const k of m.recent) addKey(k);
    for (const a of m.annotations) applyAnnotation(a);
  },
  pose(m) {
    state.frame = m.frame;
    state.pose = m.p;
    state.signals.push({ frame: m.frame, speed: m.speed, accel: m.accel });
    const oldest = m.frame - WINDOW_SECONDS * state.fps;
    while (state.signals.length && state.signals[0].frame < oldest) state.signals.shift();
    $("c-frame").textContent = m.frame;
    state.dirty = true;
  },
  saliency(m) {
    // per-frame saliency of the online keyframer: it trails the stream (at most its lookahead)
    for (const p of m.points) state.saliency.push(p);
    const oldest = (state.frame ?? 0) - WINDOW_SECONDS * state.fps;
    while (state.saliency.length && state.saliency[0][0] < oldest) state.saliency.shift();
    state.dirty = true;
  },
  keyframe(m) { addKey(m); state.dirty = true; },
  gap(m) { note(`gap: frames ${m.first}..${m.last} missing${m.bridged ? " (bridged)" : ""}`); },
  status(m) { note(`status: ${m.status}`); },
  stats(m) {
    $("c-frames").textContent = m.frames;
    $("c-drops").textContent = m.drops;
    $("c-gaps").textContent = m.gaps;
    const events = Object.entries(m.events);
    const total = events.reduce((s, [, n]) => s + n, 0);
    $("c-events").textContent = events.length
      ? `${total} (${events.map(([k, n]) => `${k} ${n}`).join(", ")})` : "0";
    const lat = m.latency_ms;
    $("c-latency").textContent = lat.p50 === undefined ? "–"
      : `${lat.p50.toFixed(2)} / ${lat.p99.toFixed(2)} ms`;
    const la = Object.entries(m.lookahead);
    $("c-lookahead").textContent = la.length ? la.map(([k, n]) => `${k} ${n}`).join(", ") : "–";
    $("c-annotations").textContent = m.annotations;
  },
  annotation(m) { applyAnnotation(m); },
  ack(m) {
    const a = m.annotation;
    say(`saved ${a.action} at frame ${a.frame}${a.text ? `: "${a.text}"` : ""}`);
  },
  error(m) { say(`refused: ${m.error}`, true); },
};

function buildLegend() {
  const legend = $("legend");
  legend.textContent = "";
  const add = (name, color, signal) => {
    const span = document.createElement("span");
    if (signal) span.dataset.signal = name; else { span.dataset.method = name; span.dataset.count = "0"; }
    const swatch = document.createElement("i");
    swatch.style.background = color;
    span.append(swatch, name);
    legend.append(span);
  };
  add("body speed", "#222", true);
  add("acceleration", "#aaa", true);
  add("saliency (delayed)", "#f4a6a6", true);
  for (const m of [...state.methods, "manual"]) add(m, state.colors[m]);
}

function keyId(method, frame) { return `key-${method}-${frame}`; }

function addKey(k) {
  state.keys.push({ method: k.method, frame: k.frame });
  const oldest = (state.frame ?? k.frame) - 2 * WINDOW_SECONDS * state.fps;
  state.keys = state.keys.filter((x) => x.frame >= oldest);
  if (state.hold) {
    // The list holds still under the pointer (no reject lands on a key that slid in).
    state.pending.push(k);
    $("held").textContent = `list paused under the pointer: ${state.pending.length} new`;
    return;
  }
  showKey(k);
}

function showKey(k) {
  if (document.getElementById(keyId(k.method, k.frame))) return;
  const li = document.createElement("li");
  li.id = keyId(k.method, k.frame);
  li.dataset.method = k.method;
  li.dataset.frame = k.frame;
  if (k.method === "manual") li.dataset.annotated = "key";  // the operator's own: kept
  li.style.borderTopColor = state.colors[k.method] || "#999";
  const thumb = document.createElement("canvas");
  thumb.width = 112;
  thumb.height = 112;
  if (k.pose) drawFigure(thumb, k.pose, state.colors[k.method] || "#333");
  const meta = document.createElement("div");
  meta.className = "meta";
  const late = k.latency_frames !== undefined ? ` (+${k.latency_frames})` : "";
  meta.textContent = `${k.method} · frame ${k.frame}${late}`;
  const label = document.createElement("div");
  label.className = "label-text";
  const input = document.createElement("input");
  input.placeholder = "label…";
  input.maxLength = 500;
  input.addEventListener("keydown", (e) => {
    if (e.key === "Enter" && input.value.trim()) {
      send({ action: "label", frame: k.frame, method: k.method, text: input.value });
      input.value = "";
    }
    e.stopPropagation();
  });
  const reject = document.createElement("button");
  reject.textContent = "reject";
  reject.className = "reject";
  reject.addEventListener("click", () =>
    send({ action: "reject", frame: k.frame, method: k.method }));
  li.append(thumb, meta, label, input, reject);
  const list = $("keys");
  list.prepend(li);
  trimKeys(list);
}

function holdKeys(hold) {
  state.hold = hold;
  if (hold) return;
  const pending = state.pending;
  state.pending = [];
  $("held").textContent = "";
  for (const k of pending) showKey(k);
}

function trimKeys(list) {
  // Drop the oldest keyposes, but never one being typed into, already annotated, or set by
  // hand (a manual key is the user's annotation: a burst of method keys must not push it out).
  const busy = (li) => li.dataset.annotated || li.dataset.method === "manual"
    || li.contains(document.activeElement) || li.querySelector("input").value;
  const items = [...list.children].reverse();
  let extra = items.length - MAX_KEYS_SHOWN;
  for (const li of items) {
    if (extra <= 0) break;
    if (!busy(li)) { li.remove(); extra--; }
  }
}

function applyAnnotation(a) {
  if (a.action === "key") {
    addKey({ method: "manual", frame: a.frame, pose: a.pose || poseNow(a.frame) });
    return;
  }
  const li = document.getElementById(keyId(a.method, a.frame));
  if (!li) return;
  li.dataset.annotated = a.action;
  if (a.action === "label") li.querySelector(".label-text").textContent = a.text;
  if (a.action === "reject") li.classList.add("rejected");
}

function poseNow(frame) { return frame === state.frame ? state.pose : null; }

// --- drawing ---------------------------------------------------------------------------

function drawFigure(canvas, p, color) {
  // Orthographic front view (x right, y up), points in body heights, root centred in x.
  const ctx = canvas.getContext("2d");
  const w = canvas.width, h = canvas.height;
  ctx.clearRect(0, 0, w, h);
  if (!state.bones) return;
  let minY = Infinity, maxY = -Infinity, maxX = 0;
  for (let i = 0; i < p.length; i += 3) {
    minY = Math.min(minY, p[i + 1]); maxY = Math.max(maxY, p[i + 1]);
    maxX = Math.max(maxX, Math.abs(p[i] + 0.35 * p[i + 2]));
  }
  const scale = 0.9 * Math.min(h / Math.max(1, maxY - minY), w / Math.max(0.6, 2 * maxX));
  const cy = (minY + maxY) / 2;
  const X = (i) => w / 2 + scale * (p[3 * i] + 0.35 * p[3 * i + 2]);
  const Y = (i) => h / 2 - scale * (p[3 * i + 1] - cy);
  ctx.strokeStyle = color;
  ctx.lineWidth = Math.max(1.5, w / 80);
  ctx.lineCap = "round";
  ctx.beginPath();
  for (const [a, b] of state.bones) { ctx.moveTo(X(a), Y(a)); ctx.lineTo(X(b), Y(b)); }
  ctx.stroke();
}

function drawChart() {
  const canvas = $("chart");
  const w = (canvas.width = canvas.clientWidth || 900);
  const h = canvas.height;
  const ctx = canvas.getContext("2d");
  ctx.clearRect(0, 0, w, h);
  if (state.frame === null) return;
  const span = WINDOW_SECONDS * state.fps;
  const x0 = state.frame - span;
  const X = (f) => ((f - x0) / span) * (w - 10) + 5;
  const rows = [...state.methods, "manual"];
  const laneH = 14, lanes = rows.length * laneH, plotH = h - lanes - 12;
  ctx.strokeStyle = "#eee";
  ctx.beginPath();
  for (let s = 0; s <= WINDOW_SECONDS; s++) {
    const f = state.frame - s * state.fps;
    ctx.moveTo(X(f), 0); ctx.lineTo(X(f), h);
  }
  ctx.stroke();
  const trace = (key, color) => {
    // scaled to the visible window's 98th percentile, so a single spike does not flatten it
    const values = state.signals.map((s) => s[key]).sort((a, b) => a - b);
    const max = Math.max(1e-6, values[Math.floor(0.98 * (values.length - 1))] || 0) * 1.1;
    ctx.strokeStyle = color;
    ctx.lineWidth = 1.5;
    ctx.beginPath();
    state.signals.forEach((s, i) => {
      const y = plotH - Math.min(s[key] / max, 1.05) * (plotH - 6);
      if (i === 0) ctx.moveTo(X(s.frame), y); else ctx.lineTo(X(s.frame), y);
    });
    ctx.stroke();
  };
  trace("accel", "#aaa");
  if (state.saliency.length) {
    // saliency: 1 = a frame as salient as the mean on every curve; candidates lie above 1
    const values = state.saliency.map((p) => p[1]).sort((a, b) => a - b);
    const max = Math.max(2, values[Math.floor(0.98 * (values.length - 1))] || 0) * 1.1;
    ctx.strokeStyle = "#f4a6a6";
    ctx.lineWidth = 1.5;
    ctx.beginPath();
    state.saliency.forEach(([f, v], i) => {
      const y = plotH - Math.min(v / max, 1.05) * (plotH - 6);
      if (i === 0) ctx.moveTo(X(f), y); else ctx.lineTo(X(f), y);
    });
    ctx.stroke();
  }
  trace("speed", "#222");
  const counts = Object.fromEntries(rows.map((m) => [m, 0]));
  for (const k of state.keys) {
    if (k.frame < x0 || !(k.method in counts)) continue;
    const lane = rows.indexOf(k.method);
    const x = X(k.frame);
    ctx.strokeStyle = state.colors[k.method];
    ctx.globalAlpha = 0.35;
    ctx.lineWidth = 1;
    ctx.beginPath(); ctx.moveTo(x, 0); ctx.lineTo(x, plotH); ctx.stroke();
    ctx.globalAlpha = 1;
    ctx.fillStyle = state.colors[k.method];
    const y = plotH + 8 + lane * laneH;
    ctx.beginPath(); ctx.moveTo(x, y); ctx.lineTo(x - 5, y + 10); ctx.lineTo(x + 5, y + 10);
    ctx.fill();
    counts[k.method] += 1;
  }
  for (const [m, n] of Object.entries(counts)) {
    const span_ = document.querySelector(`#legend span[data-method="${m}"]`);
    if (span_) span_.dataset.count = String(n);
  }
}

function render() {
  if (state.dirty) {
    state.dirty = false;
    if (state.pose) drawFigure($("pose"), state.pose, "#263238");
    drawChart();
  }
  requestAnimationFrame(render);
}

document.addEventListener("keydown", (e) => {
  if ((e.key === "k" || e.key === "K") && !e.ctrlKey && !e.metaKey && !e.altKey) {
    if (state.frame === null) { say("no frame yet", true); return; }
    send({ action: "key", frame: state.frame });
  }
});

$("keys").addEventListener("mouseenter", () => holdKeys(true));
$("keys").addEventListener("mouseleave", () => holdKeys(false));
connect();
requestAnimationFrame(render);

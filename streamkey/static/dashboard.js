// streamkey live dashboard: no build step, no dependencies. Connects to /ws on this origin.
"use strict";

const WINDOW_SECONDS = 10;   // the strip chart shows the last 10 s of the stream
const MAX_KEYS_SHOWN = 24;   // recent method keyposes listed (annotated and manual ones stay)
const MAX_NOTES_SHOWN = 200; // annotations listed
const MAX_INPUT_SHOWN = 5;   // explanations of refused input listed (the newest first)
const GROUP_PX = 11;         // markers of one lane within this width merge into one block
const GUIDES_UP_TO = 15;     // a lane with more marks (blocks) draws no guide lines
const SEGMENT_COLORS = {     // session segments drawn as shaded spans behind the curves
  calibration: "rgba(255, 193, 7, 0.16)", still: "rgba(96, 125, 139, 0.12)",
  take: "rgba(76, 175, 80, 0.06)",
};

const state = {
  methods: [], colors: {}, bones: null, sides: null, sideColors: {}, fps: 120,
  frame: null, time: null, pose: null, signals: [], saliency: [], keys: [],
  provisional: new Map(), pending: [], hold: false, hidden: new Set(), lookahead: {},
  notes: new Map(), view2: "side", ws: null, nextId: 1, dirty: true, segments: new Map(),
  drawn: {},  // per method lane of the last chart: keys, marks (blocks), guides, minGap (px)
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
    // dispatch on `type`; a type this page does not know (a newer server) is skipped
    const handler = m && typeof m.type === "string" && Object.hasOwn(HANDLERS, m.type)
      ? HANDLERS[m.type] : null;
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

function showInput(m) {
  // one line per refused-input status event, the newest on top; the same line as stderr
  const detail = m.detail || {};
  const list = $("input-notices");
  const li = document.createElement("li");
  li.dataset.kind = detail.kind || m.status.slice("input_".length);
  li.textContent = `warning: ${detail.message || m.status}`;
  li.title = `stream ${m.stream}${detail.seq !== undefined ? `, at frame ${detail.seq}` : ""}`;
  list.prepend(li);
  while (list.children.length > MAX_INPUT_SHOWN) list.lastChild.remove();
  $("input-panel").hidden = false;
}

function send(obj) {
  if (!state.ws || state.ws.readyState !== WebSocket.OPEN) {
    say("not connected", true);
    return;
  }
  obj.id = state.nextId++;
  state.ws.send(JSON.stringify(obj));
}

function timecode(seconds) {
  // hh:mm:ss.mmm of the stream's own clock
  if (seconds === null || seconds === undefined || !isFinite(seconds)) return "--:--:--.---";
  const sign = seconds < 0 ? "-" : "";
  let ms = Math.round(Math.abs(seconds) * 1000);
  const h = Math.floor(ms / 3600000); ms -= h * 3600000;
  const m = Math.floor(ms / 60000); ms -= m * 60000;
  const s = Math.floor(ms / 1000); ms -= s * 1000;
  const two = (n) => String(n).padStart(2, "0");
  return `${sign}${two(h)}:${two(m)}:${two(s)}.${String(ms).padStart(3, "0")}`;
}

function timeOf(frame) {
  // stream time of a recent frame, from the newest pose's time
  if (state.time === null || state.frame === null) return null;
  return state.time - (state.frame - frame) / state.fps;
}

function delayText(frames) {
  const ms = (1000 * frames) / state.fps;
  return `${frames} f / ${ms < 10 ? ms.toFixed(1) : Math.round(ms)} ms`;
}

const HANDLERS = {
  hello(m) {
    state.methods = m.methods;
    state.colors = m.colors;
    state.bones = m.bones;
    state.sides = m.sides || null;
    state.sideColors = m.side_colors || {};
    state.fps = m.fps || state.fps;
    // the take's name, and the stream's only when it says something more
    $("take").textContent = m.take || m.stream;
    $("stream").textContent = m.take && m.take !== m.stream ? `stream ${m.stream}` : "";
    buildLegend();
    state.signals = m.signals || [];
    state.saliency = m.saliency || [];
    if (state.signals.length) state.frame = state.signals[state.signals.length - 1].frame;
    state.keys = m.keys || [];  // the chart's window (the cards get the recent ones below)
    for (const k of m.recent) addKey(k);
    for (const a of m.annotations) applyAnnotation(a);
    for (const seg of m.segments || []) HANDLERS.segment(seg);
    $("input-notices").textContent = "";
    for (const n of m.notices || []) showInput(n);
  },
  segment(m) {
    // a session state (calibration hold, still stretch, take), open while `end` is null
    state.segments.set(`${m.kind}/${m.start}`, { kind: m.kind, start: m.start, end: m.end });
    while (state.segments.size > 50) state.segments.delete(state.segments.keys().next().value);
    state.dirty = true;
  },
  pose(m) {
    state.frame = m.frame;
    state.time = m.time;
    state.pose = m.p;
    state.signals.push({ frame: m.frame, speed: m.speed, accel: m.accel });
    const oldest = m.frame - WINDOW_SECONDS * state.fps;
    while (state.signals.length && state.signals[0].frame < oldest) state.signals.shift();
    for (const [id, p] of state.provisional) if (p.frame < oldest) state.provisional.delete(id);
    $("c-frame").textContent = m.frame;
    $("timecode").textContent = timecode(m.time);
    state.dirty = true;
  },
  saliency(m) {
    // per-frame saliency of the online keyframer: it trails the stream (at most its lookahead)
    for (const p of m.points) state.saliency.push(p);
    const oldest = (state.frame ?? 0) - WINDOW_SECONDS * state.fps;
    while (state.saliency.length && state.saliency[0][0] < oldest) state.saliency.shift();
    state.dirty = true;
  },
  keyframe(m) {
    if (m.confirms !== undefined && m.confirms !== null) {
      state.provisional.delete(`${m.method}/${m.confirms}`);
    }
    addKey(m);
    state.dirty = true;
  },
  provisional(m) {
    // a tentative key: drawn hollow until its confirm (a keyframe) or its cancel arrives
    state.provisional.set(`${m.method}/${m.pid}`, { method: m.method, frame: m.frame });
    state.dirty = true;
  },
  cancel(m) { state.provisional.delete(`${m.method}/${m.pid}`); state.dirty = true; },
  gap(m) { note(`gap: frames ${m.first}..${m.last} missing${m.bridged ? " (bridged)" : ""}`); },
  status(m) {
    // refused input, explained (what arrived, what was expected): listed until it stops
    if (typeof m.status === "string" && m.status.startsWith("input_")) showInput(m);
    else note(`status: ${m.status}`);
  },
  stats(m) {
    $("c-frames").textContent = m.frames;
    $("c-drops").textContent = m.drops;
    $("c-lost").textContent = m.lost ?? 0;
    $("c-gaps").textContent = m.gaps;
    const events = Object.entries(m.events);
    const total = events.reduce((s, [, n]) => s + n, 0);
    $("c-events").textContent = events.length
      ? `${total} (${events.map(([k, n]) => `${k} ${n}`).join(", ")})` : "0";
    const lat = m.latency_ms;
    $("c-latency").textContent = lat.p50 === undefined ? "–"
      : `${lat.p50.toFixed(2)} / ${lat.p99.toFixed(2)} ms`;
    const delay = Object.entries(m.delay || {});
    $("c-delay").textContent = delay.length
      ? delay.map(([k, d]) => `${k} ${d.frames} f / ${d.ms ?? "?"} ms`).join(", ") : "–";
    state.lookahead = m.lookahead || {};
    const la = Object.entries(state.lookahead);
    $("c-lookahead").textContent = la.length ? la.map(([k, n]) => `${k} ${n}`).join(", ") : "–";
    $("c-annotations").textContent = m.annotations;
    $("c-refused").textContent = m.refused ?? 0;
  },
  annotation(m) { applyAnnotation(m); },
  ack(m) {
    const a = m.annotation;
    const what = a.action === "undo" ? `undo of ${a.undoes}` : a.action;
    say(`saved ${what} at frame ${a.frame}${a.text ? `: "${a.text}"` : ""}`);
  },
  error(m) { say(`refused: ${m.error}`, true); },
};

function buildLegend() {
  const legend = $("legend");
  legend.textContent = "";
  const add = (name, color, signal) => {
    const label = document.createElement("label");
    const swatch = document.createElement("i");
    swatch.style.background = color;
    if (signal) {
      label.dataset.signal = name;
      label.append(swatch, name);
    } else {
      // a method: its checkbox filters both the chart and the keypose list
      label.dataset.method = name;
      label.dataset.count = "0";
      const box = document.createElement("input");
      box.type = "checkbox";
      box.checked = !state.hidden.has(name);
      box.className = "filter";
      box.addEventListener("change", () => setShown(name, box.checked));
      label.append(box, swatch, name);
    }
    legend.append(label);
  };
  add("body speed", "#222", true);
  add("acceleration", "#aaa", true);
  add("saliency (delayed)", "#f4a6a6", true);
  for (const m of [...state.methods, "manual"]) add(m, state.colors[m]);
}

function setShown(method, shown) {
  if (shown) state.hidden.delete(method); else state.hidden.add(method);
  const label = document.querySelector(`#legend label[data-method="${method}"]`);
  if (label) label.classList.toggle("off", !shown);
  for (const li of [...$("keys").children]) {
    if (li.dataset.method !== method) continue;
    if (!shown && !busy(li)) li.remove(); else li.hidden = !shown;
  }
  if (shown) {
    // bring back the method's recent keys (newest MAX_KEYS_SHOWN of the chart's memory)
    for (const k of state.keys.filter((x) => x.method === method).slice(-MAX_KEYS_SHOWN)) {
      insertKey(k);
    }
  }
  state.dirty = true;
}

function keyId(method, frame) { return `key-${method}-${frame}`; }

function addKey(k) {
  if (!state.keys.some((x) => x.method === k.method && x.frame === k.frame)) state.keys.push(k);
  const oldest = (state.frame ?? k.frame) - 2 * WINDOW_SECONDS * state.fps;
  state.keys = state.keys.filter((x) => x.frame >= oldest);
  if (state.hidden.has(k.method)) return;
  if (state.hold && k.method !== "manual") {
    // The list holds still under the pointer (no click lands on a key that slid in). The
    // operator's own manual key is shown at once: it was asked for, and it is never dropped.
    state.pending.push(k);
    $("held").textContent = `list paused under the pointer: ${state.pending.length} new`;
    return;
  }
  showKey(k);
}

function showKey(k) {
  if (!insertKey(k)) return;
  trimKeys($("keys"));
}

function insertKey(k) {
  // Insert a card in frame order (newest first); false if it is already there.
  if (document.getElementById(keyId(k.method, k.frame))) return false;
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
  meta.textContent = `${k.method} · ${k.frame} · ${timecode(k.time ?? timeOf(k.frame))}`;
  const delay = document.createElement("div");
  delay.className = "delay";
  if (k.latency_frames !== undefined) delay.textContent = `decided +${delayText(k.latency_frames)}`;
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
  const button = (name) => {
    const b = document.createElement("button");
    b.type = "button";
    b.textContent = name;
    b.className = name;
    b.addEventListener("click", () => send({ action: name, frame: k.frame, method: k.method }));
    return b;
  };
  li.append(thumb, meta, delay, label, input, button("accept"), button("reject"));
  const list = $("keys");
  const after = [...list.children].find((x) => Number(x.dataset.frame) < k.frame);
  list.insertBefore(li, after || null);
  return true;
}

function holdKeys(hold) {
  state.hold = hold;
  if (hold) return;
  const pending = state.pending;
  state.pending = [];
  $("held").textContent = "";
  for (const k of pending) if (!state.hidden.has(k.method)) insertKey(k);
  trimKeys($("keys"));
}

function busy(li) {
  // never dropped: a card being typed into, annotated, or set by hand
  return li.dataset.annotated || li.dataset.method === "manual"
    || li.contains(document.activeElement) || li.querySelector("input").value;
}

function trimKeys(list) {
  // Keep the newest MAX_KEYS_SHOWN method cards; busy cards stay and do not count.
  const items = [...list.children].filter((li) => !busy(li));
  for (const li of items.slice(MAX_KEYS_SHOWN)) li.remove();
}

function applyAnnotation(a) {
  addNote(a);
  if (a.action === "undo") { undoEffect(a); return; }
  if (a.action === "key") {
    addKey({ method: "manual", frame: a.frame, time: a.time, pose: a.pose || poseNow(a.frame) });
    return;
  }
  const li = document.getElementById(keyId(a.method, a.frame));
  if (!li) return;
  li.dataset.annotated = a.action;
  if (a.action === "label") li.querySelector(".label-text").textContent = a.text;
  if (a.action === "reject") { li.classList.add("rejected"); li.classList.remove("accepted"); }
  if (a.action === "accept") { li.classList.add("accepted"); li.classList.remove("rejected"); }
}

function undoEffect(a) {
  const entry = document.querySelector(`#annotations li[data-ref="${CSS.escape(a.ref)}"]`);
  if (entry) {
    entry.classList.add("undone");
    entry.querySelector("button.undo")?.remove();
  }
  if (a.undoes === "key") {
    state.keys = state.keys.filter((k) => !(k.method === "manual" && k.frame === a.frame));
    document.getElementById(keyId("manual", a.frame))?.remove();
    state.dirty = true;
    return;
  }
  const li = document.getElementById(keyId(a.method, a.frame));
  if (!li) return;
  if (a.undoes === "reject") li.classList.remove("rejected");
  if (a.undoes === "accept") li.classList.remove("accepted");
  if (a.undoes === "label") li.querySelector(".label-text").textContent = "";
  li.dataset.annotated = "undone";  // touched by the operator: it stays listed
}

function addNote(a) {
  // the annotation list: newest first; every entry but an undo has its undo button
  if (!a.id || state.notes.has(a.id)) return;
  state.notes.set(a.id, a);
  const li = document.createElement("li");
  li.dataset.ref = a.id;
  li.dataset.action = a.action;
  const what = document.createElement("span");
  what.className = "what";
  const target = a.action === "key" ? "manual key" : `${a.method ?? "key"}`;
  what.textContent = a.action === "undo" ? `undo ${a.undoes} · ${a.method ?? ""} ${a.frame}`
    : `${a.action} · ${target} ${a.frame}${a.text ? ` “${a.text}”` : ""}`;
  const when = document.createElement("div");
  when.className = "when";
  when.textContent = timecode(a.time);
  li.append(what);
  if (a.action !== "undo") {
    const undo = document.createElement("button");
    undo.type = "button";
    undo.className = "undo";
    undo.textContent = "undo";
    undo.addEventListener("click", () => send({ action: "undo", ref: a.id }));
    li.append(undo);
  }
  li.append(when);
  const list = $("annotations");
  list.prepend(li);
  while (list.children.length > MAX_NOTES_SHOWN) list.lastElementChild.remove();
}

function poseNow(frame) { return frame === state.frame ? state.pose : null; }

// --- drawing ---------------------------------------------------------------------------

const VIEWS = {
  // screen (u, v) of a point [x, y, z] in body heights (y up)
  front: (x, y, z) => [x + 0.35 * z, y],
  side: (x, y, z) => [z, y],
  top: (x, y, z) => [x, -z],
};

function drawFigure(canvas, p, color, sides, view) {
  // Orthographic view, points in body heights, root centred in x/z.
  const ctx = canvas.getContext("2d");
  const w = canvas.width, h = canvas.height;
  ctx.clearRect(0, 0, w, h);
  if (!state.bones) return;
  const project = VIEWS[view || "front"];
  const uv = [];
  let minV = Infinity, maxV = -Infinity, maxU = 0;
  for (let i = 0; i < p.length; i += 3) {
    const [u, v] = project(p[i], p[i + 1], p[i + 2]);
    uv.push([u, v]);
    minV = Math.min(minV, v); maxV = Math.max(maxV, v); maxU = Math.max(maxU, Math.abs(u));
  }
  const scale = 0.85 * Math.min(h / Math.max(view === "top" ? 0.6 : 1, maxV - minV),
                                w / Math.max(0.6, 2 * maxU));
  const cv = (minV + maxV) / 2;
  const X = (i) => w / 2 + scale * uv[i][0];
  const Y = (i) => h / 2 - scale * (uv[i][1] - cv);
  ctx.lineWidth = Math.max(1.5, w / 80);
  ctx.lineCap = "round";
  for (const side of ["", "L", "R"]) {
    ctx.strokeStyle = side && sides ? state.sideColors[side] || color : color;
    ctx.beginPath();
    state.bones.forEach(([a, b], n) => {
      if ((sides ? sides[n] || "" : "") !== side) return;
      ctx.moveTo(X(a), Y(a)); ctx.lineTo(X(b), Y(b));
    });
    ctx.stroke();
  }
}

function groups(xs) {
  // sorted x in groups at most GROUP_PX wide (no chaining: a dense stretch stays a row of
  // small counted blocks, never one long bar): {start, end, n}
  const out = [];
  for (const x of xs) {
    const last = out[out.length - 1];
    if (last && x - last.start < GROUP_PX) { last.end = x; last.n += 1; } else out.push({ start: x, end: x, n: 1 });
  }
  return out;
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
  const right = 34;  // room for the "now" label
  const X = (f) => ((f - x0) / span) * (w - 10 - right) + 5;
  const rows = [...state.methods, "manual"].filter((m) => !state.hidden.has(m));
  const laneH = 14, axisH = 16, lanes = rows.length * laneH, plotH = h - lanes - axisH - 8;
  const now = X(state.frame);
  // time axis: a tick per second of stream time, labelled with its timecode
  ctx.strokeStyle = "#eee";
  ctx.fillStyle = "#666";
  ctx.font = "10px sans-serif";
  ctx.textAlign = "center";
  const t1 = state.time ?? state.frame / state.fps;
  ctx.beginPath();
  for (let s = Math.max(0, Math.ceil(t1 - WINDOW_SECONDS)); s <= t1; s++) {
    const x = X(state.frame - (t1 - s) * state.fps);
    ctx.moveTo(x, 0); ctx.lineTo(x, h - axisH);
    ctx.fillText(timecode(s).slice(3, 8), x, h - 4);
  }
  ctx.stroke();
  // session segments: shaded spans under the curves, an open one up to now
  ctx.textAlign = "left";
  for (const seg of state.segments.values()) {
    const a = Math.max(X(seg.start), 5), b = Math.min(X(seg.end ?? state.frame), now);
    if (b <= a) continue;
    ctx.fillStyle = SEGMENT_COLORS[seg.kind] || "rgba(0, 0, 0, 0.05)";
    ctx.fillRect(a, 0, b - a, plotH);
    ctx.fillStyle = "#607d8b";
    ctx.fillText(seg.kind, a + 3, plotH - 4);
  }
  ctx.textAlign = "center";
  // the undecided band: frames a method may still key (its lookahead before now)
  const maxLa = Math.max(0, ...rows.map((m) => state.lookahead[m] || 0));
  if (maxLa) {
    ctx.fillStyle = "rgba(120, 144, 156, 0.12)";
    ctx.fillRect(X(state.frame - maxLa), 0, now - X(state.frame - maxLa), plotH);
    ctx.fillStyle = "#78909c";
    ctx.textAlign = "right";
    ctx.fillText("undecided", now - 3, 11);
  }
  const trace = (points, color, floor) => {
    // scaled to the visible window's largest value (with headroom): no peak is cut off
    const max = points.reduce((m, p) => Math.max(m, p[1]), floor) * 1.1;
    ctx.strokeStyle = color;
    ctx.lineWidth = 1.5;
    ctx.beginPath();
    points.forEach(([f, v], i) => {
      const y = plotH - (v / max) * (plotH - 6);
      if (i === 0) ctx.moveTo(X(f), y); else ctx.lineTo(X(f), y);
    });
    ctx.stroke();
  };
  trace(state.signals.map((s) => [s.frame, s.accel]), "#aaa", 1e-6);
  // saliency: 1 = a frame as salient as the mean on every curve; candidates lie above 1
  if (state.saliency.length) trace(state.saliency, "#f4a6a6", 2);
  trace(state.signals.map((s) => [s.frame, s.speed]), "#222", 1e-6);
  const counts = Object.fromEntries([...state.methods, "manual"].map((m) => [m, 0]));
  rows.forEach((method, lane) => {
    const y = plotH + 6 + lane * laneH;
    const color = state.colors[method] || "#999";
    const la = state.lookahead[method] || 0;
    if (la) {  // this method's own undecided stretch in its lane
      ctx.globalAlpha = 0.15;
      ctx.fillStyle = color;
      ctx.fillRect(X(state.frame - la), y - 2, now - X(state.frame - la), laneH);
      ctx.globalAlpha = 1;
    }
    const xs = state.keys.filter((k) => k.method === method && k.frame >= x0)
      .map((k) => X(k.frame)).sort((a, b) => a - b);
    counts[method] = xs.length;
    const runs = groups(xs);
    state.drawn[method] = { keys: xs.length, marks: runs.length, guides: runs.length <= GUIDES_UP_TO,
                            minGap: Math.min(...runs.slice(1).map((r, i) => r.start - runs[i].start)) };
    ctx.strokeStyle = color;
    ctx.fillStyle = color;
    ctx.lineWidth = 1;
    if (runs.length <= GUIDES_UP_TO) {  // dense lanes (dance) keep the plot readable
      ctx.globalAlpha = 0.3;
      ctx.beginPath();
      for (const r of runs) { ctx.moveTo(r.start, 0); ctx.lineTo(r.start, plotH); }
      ctx.stroke();
      ctx.globalAlpha = 1;
    }
    ctx.textAlign = "center";
    ctx.font = "bold 9px sans-serif";
    for (const r of runs) {
      if (r.n === 1) {
        ctx.beginPath();
        ctx.moveTo(r.start, y); ctx.lineTo(r.start - 5, y + 10); ctx.lineTo(r.start + 5, y + 10);
        ctx.fill();
        continue;
      }
      // keys within a marker's width: one block (a pixel apart from the next), their number
      ctx.fillRect(r.start - 5, y + 1, GROUP_PX - 1, 9);
      ctx.fillStyle = "#fff";
      ctx.fillText(r.n > 9 ? "+" : `${r.n}`, r.start, y + 9);
      ctx.fillStyle = color;
    }
    ctx.font = "10px sans-serif";
    ctx.beginPath();  // provisional keys: hollow until confirmed or cancelled
    for (const p of state.provisional.values()) {
      if (p.method !== method || p.frame < x0) continue;
      const x = X(p.frame);
      ctx.moveTo(x, y); ctx.lineTo(x - 5, y + 10); ctx.lineTo(x + 5, y + 10); ctx.closePath();
    }
    ctx.stroke();
  });
  // the "now" line: the newest frame
  ctx.strokeStyle = "#263238";
  ctx.lineWidth = 1.5;
  ctx.beginPath(); ctx.moveTo(now, 0); ctx.lineTo(now, h - axisH); ctx.stroke();
  ctx.fillStyle = "#263238";
  ctx.textAlign = "left";
  ctx.fillText("now", now + 3, h - axisH - 2);
  for (const [m, n] of Object.entries(counts)) {
    const label = document.querySelector(`#legend label[data-method="${m}"]`);
    if (label) label.dataset.count = String(n);
  }
}

function render() {
  if (state.dirty) {
    state.dirty = false;
    if (state.pose) {
      drawFigure($("pose"), state.pose, "#263238", state.sides, "front");
      drawFigure($("pose2"), state.pose, "#263238", state.sides, state.view2);
    }
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

$("view2-mode").addEventListener("click", (e) => {
  state.view2 = state.view2 === "side" ? "top" : "side";
  e.target.dataset.mode = state.view2;
  // the button names what it does: show the other view
  e.target.textContent = `show ${state.view2 === "side" ? "top" : "side"} view`;
  state.dirty = true;
});
$("keys").addEventListener("mouseenter", () => holdKeys(true));
$("keys").addEventListener("mouseleave", () => holdKeys(false));
connect();
requestAnimationFrame(render);

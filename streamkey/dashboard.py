"""The live dashboard: a local web page that shows the stream and takes the operator's notes.

One port serves everything (one origin: no CORS, one firewall rule): plain HTTP for the
page (`/`) and its static files (`/static/...`, shipped in the package: no build step, no
CDN, works offline), and a WebSocket on `/ws` that pushes, as JSON text:

- `hello` once per connection: take name, methods and their colours, bones and their sides
  (left / right), fps, recent keyposes, the chart's keys of the last 20 s, annotations, and
  the recent explanations of refused input (`notices`);
- `pose` every few frames (about 30 per second): the current pose as points in body heights
  plus the driving signals computed here (body-frame speed and acceleration);
- every engine event as its `to_dict()` (`keyframe` events carry the pose of their frame
  for the thumbnail; `provisional`, `cancel`, `signal` and any newer type pass through, the
  page dispatches on `type` and skips what it does not know; a `status` event of refused
  input, `input_<kind>`, is listed on the page with its message);
- `stats` about four times a second: frames, drops, frames lost (seq holes), gaps, events,
  decision delay per method (median `latency_frames`, and in ms), wall latency, lookahead,
  annotations and refused operator messages;
- `annotation` when any operator adds one, `ack` / `error` in reply to the sender.

Operator actions arrive as JSON objects (`{"action": "label", "frame": 120, "method":
"saliency", "text": "heel strike"}`, `{"action": "key", "frame": 300}`, `{"action":
"reject" | "accept", "frame": 120, "method": "speed"}`, `{"action": "undo", "ref":
"<annotation id>"}`). `Annotator` validates them (sans-I/O): a malformed or oversize
message, an unknown action, a frame the stream has not produced or an unknown / already
undone `ref` gets an `error` reply naming the problem (and is counted), never an exception.
Valid ones get an `id` and are written to the session's JSON Lines log as `annotation`
events before they are broadcast.

Security: the server binds to loopback unless `listen` says otherwise; the WebSocket accepts
only its own origin (the `Origin` header must be `http://` + the request's `Host`; a request
without `Origin` is a non-browser client) and, on loopback, only the host names `127.0.0.1`,
`localhost` and `[::1]` (no DNS rebinding). Listening beyond loopback needs a token: the
page URL carries `?token=...` and the page and the WebSocket refuse requests without it.
"""

from __future__ import annotations

import json
import os
import time
from collections import OrderedDict, deque
from collections.abc import Callable
from importlib import resources
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

import numpy as np

from .adapters import make_sink, parse_address
from .adapters.base import LOOPBACK, Address, Source
from .adapters.sinks import JsonlSink
from .adapters.websocket import WebSocketSink
from .engine import Engine
from .errors import InputError, RoleError, UsageError
from .keyframes import SCHEMA_VERSION, Event, KeyframeEvent, StatusEvent
from .kinematics import body_height, forward_kinematics, pelvis_frame
from .motion import Frame, Motion, Skeleton
from .roles import resolve_roles
from .summary import RunSummary

__all__ = ["Annotator", "LiveView", "DashboardSink", "run_dashboard", "METHOD_COLORS",
           "MAX_TEXT", "ACTIONS", "check_port", "method_color", "bone_sides",
           "default_log", "session_dir"]

MAX_TEXT = 500            # characters of a label or a reason
MAX_KEYS = 10_000         # keyed frames remembered for labels and rejections
MAX_ANNOTATIONS = 1000    # annotations kept in memory (all of them are in the log)
MAX_SEGMENTS = 50         # session segments (calibration, still, take) kept for late pages
MAX_NOTICES = 20          # explanations of refused input kept for late pages
MAX_CLIENT_MESSAGE = 4096  # bytes of one operator message
ACTIONS = ("label", "key", "reject", "accept", "undo")
SIDE_COLORS = {"L": "#1565c0", "R": "#e65100"}  # left / right bones of the live figure
METHOD_COLORS = {"saliency": "#d62728", "speed": "#1f77b4", "simplify": "#2ca02c",
                 "manual": "#9467bd", "optimal": "#bcbd22"}
_SPARE_COLORS = ("#ff7f0e", "#8c564b", "#e377c2", "#17becf")
_STATIC = {"dashboard.js": "text/javascript", "dashboard.css": "text/css"}


def method_color(method: str, methods: list[str]) -> str:
    """A stable colour per method (known methods fixed, others from a spare palette)."""
    if method in METHOD_COLORS:
        return METHOD_COLORS[method]
    return _SPARE_COLORS[methods.index(method) % len(_SPARE_COLORS)] if method in methods \
        else _SPARE_COLORS[0]


class Annotator:
    """Validate operator messages against what the stream produced; build annotation events."""

    def __init__(self, stream: str = "default", max_text: int = MAX_TEXT) -> None:
        self.stream = stream
        self.max_text = max_text
        self.first_seq: int | None = None
        self.last_seq: int | None = None
        self.last_time = 0.0
        self.fps = 0.0
        # frame -> methods that keyed it (and "manual"); the newest MAX_KEYS frames only
        self.keys: OrderedDict[int, set[str]] = OrderedDict()
        # annotation id -> its record (the newest MAX_KEYS), for `undo`; ids undone so far
        self.notes: OrderedDict[str, dict[str, Any]] = OrderedDict()
        self.undone: set[str] = set()
        self.session = format(int(time.time()), "x")  # keeps ids unique in an appended log
        self.count = 0
        self.refused = 0  # messages answered with an error (each one counted, none raised)

    def see_frame(self, seq: int, time_s: float) -> None:
        """Remember the stream's frame range (annotations must reference a produced frame)."""
        if self.first_seq is None:
            self.first_seq = seq
        self.last_seq = seq
        self.last_time = time_s

    def see_key(self, method: str, frame: int) -> None:
        """Remember a keyframe (labels and rejections must name one)."""
        self.keys.setdefault(int(frame), set()).add(method)
        while len(self.keys) > MAX_KEYS:
            self.keys.popitem(last=False)

    def handle(self, text: str) -> tuple[dict[str, Any] | None, dict[str, Any]]:
        """Validate one client message: (annotation event or None, reply to the sender)."""
        request_id: Any = None
        try:
            if len(text.encode("utf-8", "replace")) > MAX_CLIENT_MESSAGE:
                raise _Reject(f"message too long ({len(text)} characters; at most "
                              f"{MAX_CLIENT_MESSAGE} bytes)")
            try:
                msg = json.loads(text)
            except json.JSONDecodeError as exc:
                raise _Reject(f"malformed JSON: {exc.msg} at character {exc.pos}") from None
            except RecursionError:
                raise _Reject("malformed JSON: nested too deeply") from None
            if not isinstance(msg, dict):
                raise _Reject("expected a JSON object like {\"action\": \"label\", ...}")
            request_id = msg.get("id") if isinstance(msg.get("id"), (int, str)) else None
            record = self._validate(msg)
        except _Reject as exc:
            self.refused += 1
            return None, {"type": "error", "id": request_id, "error": str(exc)}
        self.count += 1
        record["id"] = f"{self.stream}/annotation/{self.session}-{self.count}"
        if record["action"] == "key":
            self.see_key("manual", record["frame"])
        elif record["action"] == "undo":
            self.undone.add(record["ref"])
            if self.notes[record["ref"]]["action"] == "key":
                self.keys.get(record["frame"], set()).discard("manual")
        self.notes[record["id"]] = record
        while len(self.notes) > MAX_KEYS:
            self.undone.discard(self.notes.popitem(last=False)[0])
        return record, {"type": "ack", "id": request_id, "annotation": record}

    def _validate(self, msg: dict[str, Any]) -> dict[str, Any]:
        action = msg.get("action")
        if not isinstance(action, str) or action not in ACTIONS:
            raise _Reject(f"unknown action {action!r}; expected one of {', '.join(ACTIONS)}")
        if action == "undo":
            return self._undo(msg.get("ref"))
        frame = msg.get("frame")
        if isinstance(frame, bool) or not isinstance(frame, int):
            raise _Reject(f"{action}: 'frame' must be an integer frame number, got {frame!r}")
        if self.last_seq is None or self.first_seq is None:
            raise _Reject(f"{action}: no frame has arrived yet")
        if not self.first_seq <= frame <= self.last_seq:
            raise _Reject(f"{action}: unknown frame {frame}; the stream has frames "
                          f"{self.first_seq}..{self.last_seq}")
        method = msg.get("method")
        if method is not None and not isinstance(method, str):
            raise _Reject(f"{action}: 'method' must be a string")
        text = msg.get("text", "")
        if not isinstance(text, str):
            raise _Reject(f"{action}: 'text' must be a string")
        if len(text) > self.max_text:
            raise _Reject(f"{action}: text too long ({len(text)} characters; at most "
                          f"{self.max_text})")
        if action == "label" and not text.strip():
            raise _Reject("label: 'text' must not be empty")
        if action in ("label", "reject", "accept"):
            keyed = self.keys.get(frame, set())
            if method is not None and method not in keyed:
                raise _Reject(f"{action}: frame {frame} is not a keyframe of {method!r}")
            if not keyed:
                raise _Reject(f"{action}: frame {frame} is not a keyframe")
        elif method not in (None, "manual"):
            raise _Reject("key: a manual key has no method (or method 'manual')")
        return {"v": SCHEMA_VERSION, "type": "annotation", "stream": self.stream,
                "action": action, "frame": frame,
                "method": "manual" if action == "key" else method,
                "text": text.strip(), "time": self._time_of(frame), "seq_at": self.last_seq,
                "wall_time": round(time.time(), 3)}

    def _undo(self, ref: Any) -> dict[str, Any]:
        """`{"action": "undo", "ref": <annotation id>}`: take back one earlier annotation."""
        if not isinstance(ref, str):
            raise _Reject("undo: 'ref' must be the id of an earlier annotation (a string)")
        target = self.notes.get(ref)
        if target is None:
            raise _Reject(f"undo: unknown annotation {ref[:80]!r}")
        if target["action"] == "undo":
            raise _Reject("undo: an undo cannot be undone (annotate again instead)")
        if ref in self.undone:
            raise _Reject(f"undo: annotation {ref[:80]!r} is already undone")
        frame = target["frame"]
        return {"v": SCHEMA_VERSION, "type": "annotation", "stream": self.stream,
                "action": "undo", "frame": frame, "method": target["method"], "ref": ref,
                "undoes": target["action"], "text": "", "time": target["time"],
                "seq_at": self.last_seq, "wall_time": round(time.time(), 3)}

    def _time_of(self, frame: int) -> float | None:
        if not self.fps or self.last_seq is None:
            return None
        return round(self.last_time - (self.last_seq - frame) / self.fps, 6)


class _Reject(Exception):
    """An operator message that is refused (its text goes back to the client)."""


def bone_sides(skeleton: Skeleton, bones: list[list[int]]) -> list[str]:
    """"L", "R" or "" per bone (child point, parent point): the side of the nearest hip or
    shoulder at or above the child, else the one side all its children share (clavicles,
    hip joints); all "" when the rig's roles are not found."""
    try:
        roles = resolve_roles(skeleton, needed=("left_hip", "right_hip", "left_shoulder",
                                                "right_shoulder"))
    except RoleError:
        return [""] * len(bones)
    side = {i: r[0].upper() for r, i in roles.items()}
    parents = {child: parent for child, parent in bones}
    found: dict[int, str] = {}
    for child in parents:
        point: int | None = child
        while point is not None and point not in side:
            point = parents.get(point)
        found[child] = side.get(point, "") if point is not None else ""
    for point in sorted(found, reverse=True):  # children come after their parents
        kids = {found[c] for c, p in bones if p == point}
        if not found[point] and len(kids) == 1:
            found[point] = kids.pop()
    return [found[child] for child, _ in bones]


class LiveView:
    """The pose stream of the page: decimated poses, thumbnails and the driving signals.

    Keeps the last `history` frames' channels so that a keyframe decided up to `history`
    frames late still gets the pose of its own frame as a thumbnail.
    """

    def __init__(self, skeleton: Skeleton, fps: float, rate: float = 30.0,
                 history: int = 1024) -> None:
        self.skeleton = skeleton
        self.fps = float(fps)
        self.every = max(1, round(self.fps / rate))
        self.height = body_height(skeleton) or 1.0
        self.frames: deque[Frame] = deque(maxlen=history)
        self.prev: tuple[float, np.ndarray, float] | None = None  # time, body points, speed
        self.n = 0
        parents = list(skeleton.parents)
        ends = sorted(skeleton.end_sites)
        self.bones = [[j, p] for j, p in enumerate(parents) if p >= 0]
        self.bones += [[skeleton.n_joints + i, j] for i, j in enumerate(ends)]
        self.sides = bone_sides(skeleton, self.bones)

    def points(self, channels: np.ndarray) -> tuple[list[float], np.ndarray]:
        """Flattened display points (root centred in x/z, body heights) and body-frame points."""
        fk = forward_kinematics(self.skeleton, channels[None, :])
        pos = fk.positions[0]
        shown = (pos - np.array([pos[0, 0], 0.0, pos[0, 2]])) / self.height
        return np.round(shown, 3).ravel().tolist(), pelvis_frame(fk, 0)[0] / self.height

    def push(self, frame: Frame) -> dict[str, Any] | None:
        """Remember a frame; every `every` frames return the `pose` message."""
        self.frames.append(frame)
        self.n += 1
        if (self.n - 1) % self.every:
            return None
        flat, body = self.points(np.asarray(frame.channels, dtype=np.float64))
        speed = accel = 0.0
        if self.prev is not None and frame.time > self.prev[0]:
            dt = frame.time - self.prev[0]
            speed = float(np.linalg.norm(body - self.prev[1], axis=1).mean() / dt)
            accel = abs(speed - self.prev[2]) / dt
        self.prev = (frame.time, body, speed)
        return {"type": "pose", "frame": frame.seq, "time": round(frame.time, 4), "p": flat,
                "speed": round(speed, 4), "accel": round(accel, 3)}

    def pose_of(self, seq: int) -> list[float] | None:
        """Display points of a recent frame (None if it has left the history)."""
        for frame in reversed(self.frames):
            if frame.seq == seq:
                return self.points(np.asarray(frame.channels, dtype=np.float64))[0]
            if frame.seq < seq:
                break
        return None


class DashboardSink(WebSocketSink):
    """Page + WebSocket server on one port; a live sink of the engine (never blocks it)."""

    name = "dashboard"

    def __init__(self, port: int = 8765, listen: str | None = None, stream: str = "default",
                 methods: list[str] | None = None, log: JsonlSink | None = None,
                 token: str | None = None, rate: float = 30.0, recent: int = 24,
                 take: str | None = None) -> None:
        super().__init__(Address("ws", LOOPBACK, port), listen, on_message=self.annotate,
                         token=token)
        self.methods = list(methods or [])
        self.take = take or stream
        self.log = log
        self.rate = rate
        self.annotator = Annotator(stream)
        self.view: LiveView | None = None
        self.engine: Engine | None = None
        self.recent: deque[dict[str, Any]] = deque(maxlen=recent)
        self.segments: OrderedDict[tuple[Any, Any], dict[str, Any]] = OrderedDict()
        self.chart: deque[dict[str, Any]] = deque(maxlen=4000)  # keys for the strip chart
        self.latency: deque[float] = deque(maxlen=2000)
        self.delay: dict[str, deque[int]] = {}  # method -> latency_frames of its last keys
        self.annotations: deque[dict[str, Any]] = deque(maxlen=MAX_ANNOTATIONS)
        self.signals: deque[dict[str, Any]] = deque(maxlen=round(10 * rate) + 1)  # 10 s chart
        self.saliency: deque[list[float]] = deque(maxlen=1500)  # 10 s at up to 150 Hz
        self.notices: deque[dict[str, Any]] = deque(maxlen=MAX_NOTICES)  # refused input
        self.frame_hooks: list[Callable[[Frame], None]] = []  # also see each frame first
        self._last_stats = 0

    # ------------------------------------------------------------------ engine side
    async def start(self) -> str:
        """Bind the port (once: `run_dashboard` binds before it opens any log file)."""
        if self.server is None:
            try:
                await super().start()
            except InputError as exc:
                why = str(exc).rpartition(": ")[2]
                why = "the port is in use" if "in use" in why else why
                raise InputError(f"--dashboard {self.address.port}: cannot listen on "
                                 f"{self.host}:{self.address.port}: {why} (give another "
                                 "port, or 0 for a free one)") from None
        return self.url

    @property
    def url(self) -> str:
        """The page's address (with the token when one is required)."""
        host = self.host if self.host != "0.0.0.0" else LOOPBACK
        query = f"?token={self.token}" if self.token else ""
        return f"http://{host}:{self.port}/{query}"

    def attach(self, engine: Engine) -> None:
        """Read counters from this engine (frames, drops, gaps, latency, lookahead) through
        its read-only snapshots (`Engine.statistics`, `Engine.saliency_trace`)."""
        self.engine = engine

    def on_frame(self, frame: Frame) -> None:
        """Engine hook after each frame: remember it, send the pose every few frames."""
        for hook in self.frame_hooks:
            hook(frame)
        if self.view is None:
            stats = self.engine.statistics() if self.engine else None
            if stats is None or stats.skeleton is None or stats.fps is None:
                return
            self.view = LiveView(stats.skeleton, stats.fps, self.rate)
            self.annotator.fps = stats.fps
        self.annotator.see_frame(frame.seq, frame.time)
        pose = self.view.push(frame)
        if pose is not None:
            self.signals.append({k: pose[k] for k in ("frame", "speed", "accel")})
            self.broadcast(pose)
            points = self._new_saliency()
            if points:
                self.saliency.extend(points)
                self.broadcast({"type": "saliency", "points": points})
        if self.view.n - self._last_stats >= max(1, round(self.view.fps / 4)):
            self._last_stats = self.view.n
            self.broadcast(self.counters())

    def _new_saliency(self) -> list[list[float]]:
        """Per-frame saliency the online saliency keyframer classified since the last call
        (it trails the stream by at most its lookahead)."""
        trace = self.engine.saliency_trace() if self.engine is not None else ()
        if not trace:
            return []
        last = self.saliency[-1][0] if self.saliency else None
        if last is not None and trace[0][0] > last + 1:  # the keyframer restarted
            last = None
        fresh = [[seq, round(v, 4)] for seq, v in trace if last is None or seq > last]
        return fresh[-self.saliency.maxlen :] if last is None and self.saliency.maxlen else fresh

    def offer(self, event: Event) -> None:
        """An engine event: keyframes get their pose attached and join the recent list."""
        record = event.to_dict()
        match event:
            case KeyframeEvent(method=method, frame=frame, wall_latency_ms=latency):
                self.annotator.see_key(method, frame)
                if latency is not None:
                    self.latency.append(float(latency))
                self.delay.setdefault(method, deque(maxlen=2000)).append(event.latency_frames)
                self.chart.append({"method": method, "frame": frame})
                record["pose"] = self.view.pose_of(frame) if self.view else None
                self.recent.append(record)
            case StatusEvent(status=status) if status.startswith("input_"):
                self.notices.append(record)  # refused input, explained
            case _ if record.get("type") == "segment":
                # one entry per segment (an open one is replaced when it closes)
                self.segments[(record.get("kind"), record.get("start"))] = record
                while len(self.segments) > MAX_SEGMENTS:
                    self.segments.popitem(last=False)
            case _:
                pass
        self.broadcast(record)

    def counters(self) -> dict[str, Any]:
        """The counters message of the page."""
        out: dict[str, Any] = {"type": "stats", "frames": 0, "drops": 0, "gaps": 0, "lost": 0,
                               "events": {}, "lookahead": {}, "latency_ms": {}, "delay": {},
                               "annotations": self.annotator.count,
                               "refused": self.annotator.refused, "clients": len(self.clients)}
        eng = self.engine
        if eng is None:
            return out
        stats = eng.statistics()
        out["frames"] = stats.frames_in
        out["drops"] = stats.source_drops
        if stats.guard:
            g = stats.guard
            out["drops"] += g["duplicates"] + g["out_of_order"] + g["invalid"]
            out["gaps"] = g["gaps"]
            out["lost"] = g["lost"]  # seq holes: frames that never arrived
            out["lookahead"] = _lookahead_now(eng, dict(stats.lookahead))
        out["events"] = dict(stats.events)
        if self.latency:
            lat = np.array(self.latency)
            out["latency_ms"] = {"p50": round(float(np.percentile(lat, 50)), 3),
                                 "p99": round(float(np.percentile(lat, 99)), 3)}
        fps = self.view.fps if self.view else 0.0
        for method, frames in self.delay.items():
            median = float(np.median(frames))
            out["delay"][method] = {"frames": round(median, 1),
                                    "ms": round(1000 * median / fps, 1) if fps else None}
        return out

    def greeting(self) -> dict[str, Any]:
        """Every new page first gets the state it needs to draw (`hello`)."""
        return self.hello()

    def hello(self) -> dict[str, Any]:
        """First message of a connection: what the page needs to draw, and recent keys."""
        methods = self.methods + ["manual"]
        return {"type": "hello", "v": SCHEMA_VERSION, "stream": self.annotator.stream,
                "take": self.take, "methods": self.methods,
                "colors": {m: method_color(m, self.methods) for m in methods},
                "bones": self.view.bones if self.view else None,
                "sides": self.view.sides if self.view else None, "side_colors": SIDE_COLORS,
                "fps": self.view.fps if self.view else None, "max_text": MAX_TEXT,
                "recent": list(self.recent), "keys": self._chart_keys(),
                "annotations": list(self.annotations)[-50:],
                "signals": list(self.signals), "saliency": list(self.saliency),
                "segments": list(self.segments.values()), "notices": list(self.notices)}

    def _chart_keys(self) -> list[dict[str, Any]]:
        """Keys of the last 20 s (what the page's chart remembers), so a page opened late
        draws the whole window, not only the recent keyposes."""
        last, fps = self.annotator.last_seq, self.view.fps if self.view else 0.0
        oldest = last - 20 * fps if last is not None else None
        return [k for k in self.chart if oldest is None or k["frame"] >= oldest]

    # ------------------------------------------------------------------ client side
    def annotate(self, text: str) -> dict[str, Any]:
        """Handle one operator message: log and broadcast it if valid; returns the reply."""
        record, reply = self.annotator.handle(text)
        if record is None:
            return reply
        if self.log is not None:
            if self.log.file.closed:
                return {"type": "error", "id": reply.get("id"),
                        "error": "the session log is closed (the stream has ended)"}
            self.log.write(record)
        self.annotations.append(record)
        shown = record
        if record["action"] == "key":
            shown = {**record, "pose": self.view.pose_of(record["frame"]) if self.view else None}
            self.recent.append({**shown, "type": "keyframe"})
            self.chart.append({"method": "manual", "frame": record["frame"]})
        elif record["action"] == "undo" and record["undoes"] == "key":
            gone = {"method": "manual", "frame": record["frame"]}
            self.chart = deque((k for k in self.chart if k != gone), maxlen=self.chart.maxlen)
        self.broadcast(shown)
        return reply

    def _http(self, connection: Any, request: Any) -> Any:
        """Route `/`, `/static/...` and `/ws`; refuse foreign hosts, origins and bad tokens."""
        why = self.host_problem(request)
        if why is not None:
            return self.refuse(connection, *why)
        path = urlsplit(request.path).path
        if path == "/ws":
            return super()._http(connection, request)
        if path in ("/", "/index.html"):
            if not self.token_ok(request):
                return self.refuse(connection, "token", "missing or wrong token: open the URL "
                                   "printed by streamkey (it ends with ?token=...)")
            return _asset(connection, "dashboard.html", "text/html")
        name = path.removeprefix("/static/")
        if name in _STATIC:
            return _asset(connection, name, _STATIC[name])
        if path == "/favicon.ico":
            return connection.respond(204, "")
        return connection.respond(404, f"not found: {path[:200]}\n")


def _asset(connection: Any, name: str, kind: str) -> Any:
    body = resources.files("streamkey").joinpath("static", name).read_text(encoding="utf-8")
    response = connection.respond(200, body)
    del response.headers["Content-Type"]  # Headers is a multidict: replace, don't append
    response.headers["Content-Type"] = f"{kind}; charset=utf-8"
    response.headers["Cache-Control"] = "no-store"
    response.headers["X-Content-Type-Options"] = "nosniff"
    return response


async def run_dashboard(source: Source | Motion, methods: list[str], to: list[str],
                        params: dict[str, dict[str, Any]] | None = None,
                        lookahead: int | None = None, listen: str | None = None,
                        stream: str = "default", rate: float | None = None,
                        port: int = 8765, log: str | None = None, loop: bool = False,
                        on_ready: Callable[[str], None] | None = None,
                        on_event: Callable[[dict[str, Any]], None] | None = None,
                        idle_exit: float | None = None,
                        on_start: Callable[[DashboardSink], None] | None = None
                        ) -> tuple[RunSummary, DashboardSink]:
    """`run_live` with the dashboard: the page on `port`, annotations into the JSON Lines log.

    The log is the `jsonl:` sink among `to`, else `log` (a path), else no log (annotations
    are then only broadcast). A Motion source is paced at its fps (looped if `loop`).
    `on_start` gets the dashboard before the run starts (`board.engine.stop()` ends it).
    """
    from .live import _ready, build_engine, run_engine

    on_ready = on_ready or _ready
    targets = list(to) + ([f"jsonl:{log}"] if log else [])
    take = source.name if isinstance(source, Motion) and source.name else stream
    board = DashboardSink(port, listen, stream, methods, take=take)
    def ready(line: str) -> None:
        on_ready(line.replace("sending to http", "dashboard on http"))

    await board.start()  # a busy port fails here, before any log file is created
    try:
        sinks = [make_sink(parse_address(a), listen) for a in targets]
        logs = [s for s in sinks if isinstance(s, JsonlSink)]
        board.log = logs[0] if logs else None
        engine = build_engine(source, methods, [*sinks, board], params, lookahead, stream,
                              rate, loop, on_event, ready, idle_exit, on_frame=board.on_frame,
                              freeze_gc=True)
    except BaseException:
        await board.close()
        raise
    board.attach(engine)
    if on_start is not None:
        on_start(board)
    return await run_engine(engine), board


def _lookahead_now(engine: Engine, lookahead: dict[str, int]) -> dict[str, int]:
    """Each method's lookahead as it applies now: a keyframer that chose among inner ones
    (saliency's `auto` preset) reports the chosen one's (121 frames, then 37 after a switch
    to "high"), not the bound it started with."""
    for state in list(engine.table.live.values())[:1]:
        for kf in state.pipeline.keyframers:
            active = getattr(kf, "active", None)
            if active is not None and kf.method in lookahead:
                lookahead[kf.method] = int(active.lookahead)
    return lookahead


def session_dir() -> Path:
    """Where session logs go when neither `--log` nor a `jsonl:` sink names one:
    `$STREAMKEY_SESSIONS`, else `$XDG_STATE_HOME/streamkey/sessions`, else
    `~/.local/state/streamkey/sessions` (not the current folder: a demo run from a checkout
    must not litter it)."""
    if os.environ.get("STREAMKEY_SESSIONS"):
        return Path(os.environ["STREAMKEY_SESSIONS"])
    state = os.environ.get("XDG_STATE_HOME") or str(Path.home() / ".local" / "state")
    return Path(state) / "streamkey" / "sessions"


def default_log() -> str:
    """`session-<UTC time>.jsonl` in `session_dir()` (created): where annotations go by
    default."""
    folder = session_dir()
    folder.mkdir(parents=True, exist_ok=True)
    return str(folder / time.strftime("session-%Y%m%d-%H%M%S.jsonl", time.gmtime()))


def check_port(port: int) -> int:
    """Validate a `--dashboard` port (0 picks a free one)."""
    if not 0 <= port <= 65535:
        raise UsageError(f"--dashboard: port must be 0..65535, got {port}")
    return port

"""Playable events: strength, --min-interval, provisional events, the signal."""

from __future__ import annotations

import json
from collections import Counter
from functools import cache

import numpy as np
import pytest
from cmu import DATA, clips

from streamkey.amc import read_motion
from streamkey.batch import extract_motion
from streamkey.bench.playable import measure
from streamkey.cli import main
from streamkey.keyframes import (
    CancelEvent,
    GapEvent,
    KeyframeEvent,
    ProvisionalEvent,
    SignalEvent,
    StatusEvent,
)
from streamkey.methods import OFFLINE_METHODS, ONLINE_METHODS
from streamkey.online import Pipeline
from streamkey.playable import debounce, debounce_rows, parse_min_interval
from streamkey.streaming import make_keyframers, run_online

LIMIT = 360  # frames of each clip in the every-clip test
# Offline parameters of the online defaults: the same ones (saliency `auto` on both sides).
OFFLINE: dict[str, dict[str, object]] = {}


@cache
def load(name: str):
    return read_motion(DATA / name)


def events_of(motion, methods, star=None, lookahead=None, block=True, limit=None):
    pipe = Pipeline(make_keyframers(motion, methods, {"*": star or {}}, lookahead))
    frames = motion.frames()[:limit]
    if block:
        return pipe.push_block(frames) + pipe.flush()
    out = []
    for f in frames:
        out += pipe.push(f) + pipe.idle()
    return out + pipe.flush()


def finals(events):
    return [e for e in events if isinstance(e, KeyframeEvent)]


# ----------------------------------------------------------------------------- strength

def test_strength_lies_in_0_1_on_every_offline_key_and_is_written_to_json():
    m = load("07_01.bvh")
    results = extract_motion(m, list(OFFLINE_METHODS), {})
    for name, keys in results.items():
        s = np.asarray(keys.strength)
        assert len(s) == len(keys) > 0 and np.all((s > 0) & (s < 1)), name
        assert keys.to_dict()["strength"] == [round(float(v), 6) for v in s]
    # A rank: the strongest of a method's recent keys reads high whatever the score's unit.
    for name in ("saliency", "speed", "simplify"):
        keys = results[name]
        top = int(np.argmax(keys.scores))
        assert keys.strength[top] >= 0.5, name


def test_online_strength_with_unbounded_lookahead_equals_offline():
    for clip in ("07_01.bvh", "05_06.bvh"):
        m = load(clip)
        online = run_online(m, list(ONLINE_METHODS), lookahead=m.n_frames + 1)
        offline = extract_motion(m, list(ONLINE_METHODS), OFFLINE)
        for name in ONLINE_METHODS:
            assert online[name].frames.tolist() == offline[name].frames.tolist(), (clip, name)
            np.testing.assert_allclose(online[name].scores, offline[name].scores, rtol=1e-9,
                                       atol=1e-15, err_msg=f"{clip} {name}")
            np.testing.assert_array_equal(online[name].strength, offline[name].strength,
                                          err_msg=f"{clip} {name}")


def test_every_online_event_carries_a_strength_in_0_1_and_a_v2_id():
    m = load("05_11.amc")
    events = events_of(m, list(ONLINE_METHODS), {"provisional": True, "signal": 10})
    kinds = Counter(type(e).__name__ for e in events)
    assert kinds["KeyframeEvent"] and kinds["ProvisionalEvent"] and kinds["SignalEvent"]
    for e in events:
        d = e.to_dict()
        assert d["v"] == 2 and d["id"] == e.id and d["type"] in (
            "keyframe", "provisional", "cancel", "signal", "gap", "status", "segment")
        if isinstance(e, KeyframeEvent | ProvisionalEvent):
            assert 0.0 <= e.strength <= 1.0
    keys = [e for e in events if isinstance(e, KeyframeEvent)]
    assert len({e.id for e in keys}) == len(keys)
    assert all(e.id == f"default/{e.method}/{e.frame}/{e.params}" for e in keys)
    assert GapEvent(stream="s", method="*", first=5, last=9, bridged=True).id == "s/gap/5"
    assert StatusEvent(stream="s", method="*", status="restart",
                       detail={"seq": 7}).id == "s/status/restart/7"


# ----------------------------------------------------------------------------- debounce

def test_debounce_keeps_the_stronger_of_close_keys_and_leaves_no_pair_closer():
    frames = np.array([10, 14, 20, 40, 45, 49, 80])
    scores = np.array([1.0, 3.0, 2.0, 5.0, 5.0, 1.0, 0.5])
    kept = debounce_rows(frames, scores, 10)
    assert frames[kept].tolist() == [14, 40, 80]  # 14 beats 10 and 20; a tie keeps 40
    m = load("05_06.bvh")
    keys = extract_motion(m, ["simplify"], {})["simplify"]
    out = debounce(keys, 0.15, m.fps)
    assert len(out) < len(keys) and np.all(np.diff(out.frames) >= 18)
    assert set(out.frames.tolist()) <= set(keys.frames.tolist())


@pytest.mark.parametrize("method", list(ONLINE_METHODS))
def test_min_interval_online_with_unbounded_lookahead_equals_offline(method):
    for clip in ("05_06.bvh", "07_05.amc"):
        m = load(clip)
        off = debounce(extract_motion(m, [method], OFFLINE)[method], 0.2, m.fps)
        star = {"min_interval": {"*": 0.2}}
        on = run_online(m, [method], {"*": star}, lookahead=m.n_frames + 1)[method]
        assert on.frames.tolist() == off.frames.tolist(), clip
        np.testing.assert_array_equal(on.strength, off.strength)


@pytest.mark.parametrize("method", list(ONLINE_METHODS))
def test_min_interval_online_applies_the_offline_rule_within_its_latency(method):
    m = load("05_11.bvh")
    plain = run_online(m, [method])[method]
    spec = parse_min_interval(f"{method}=0.15,speed=0.3")
    seconds = spec[method]
    expected = debounce(plain, seconds, m.fps)
    for block in (True, False):
        events = events_of(m, [method], {"min_interval": spec}, block=block)
        keys = finals(events)
        assert [e.frame for e in keys] == expected.frames.tolist()
        gap = round(seconds * m.fps)
        kf = make_keyframers(m, [method])[0]
        inner = kf.lookahead + kf.features.delay  # the noise filter's delay is latency too
        assert kf.features.delay > 0
        assert all(e.lookahead == inner + gap and 0 <= e.latency_frames <= inner + gap
                   for e in keys if e.decided_at < m.n_frames - 1)


def test_min_interval_on_the_command_line_offline_and_online(tmp_path, capsys):
    clip = str(DATA / "05_06.bvh")
    out = {}
    for mode in ([], ["--online", "--lookahead", "100000"]):
        path = tmp_path / "k.json"
        assert main(["extract", clip, "--method", "speed,simplify", "--min-interval",
                     "simplify=0.2,0.1", "-o", str(path), "-q", *mode]) == 0
        out[bool(mode)] = json.loads(path.read_text())["files"][0]["methods"]
    for name in ("speed", "simplify"):
        assert out[True][name]["keyframes"] == out[False][name]["keyframes"]
        assert out[True][name]["strength"] == out[False][name]["strength"]
    frames = out[False]["simplify"]["keyframes"]
    assert min(np.diff(frames)) >= 24


@pytest.mark.parametrize("argv", [["--min-interval", "x"], ["--min-interval", "-1"],
                                  ["--min-interval", "speed="], ["--min-interval", ",,"],
                                  ["--min-interval", "nan"], ["--min-interval", "walk=0.1"],
                                  ["--signal", "0"], ["--signal", "-3"]])
def test_bad_playable_options_are_one_clear_error(argv, capsys):
    code = main(["run", "--from", str(DATA / "07_01.bvh"), "--fast", "--method", "speed",
                 *argv])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("error: ") and "Traceback" not in err
    assert err.count("\n") == 1


# ----------------------------------------------------------------------------- provisional

def check_provisional(raw, events, name):
    """Finals unchanged but for `confirms`; every provisional resolved exactly once."""
    got = finals(events)
    assert [(e.frame, e.decided_at, e.score, e.strength) for e in got] == [
        (e.frame, e.decided_at, e.score, e.strength) for e in finals(raw)], name
    provisional = {}
    resolved = Counter()
    for i, e in enumerate(events):
        if isinstance(e, ProvisionalEvent):
            assert e.pid not in provisional, name
            provisional[e.pid] = (i, e)
        elif isinstance(e, KeyframeEvent | CancelEvent):
            pid = e.confirms if isinstance(e, KeyframeEvent) else e.pid
            assert pid in provisional and provisional[pid][0] < i, name
            p = provisional[pid][1]
            assert p.seen_at <= e.decided_at, name
            resolved[pid] += 1
    assert set(resolved) == set(provisional) and set(resolved.values()) == {1}, name
    assert all(e.confirms is not None for e in got)
    return provisional


@pytest.mark.slow
@pytest.mark.parametrize("method", [
    pytest.param(m, marks=pytest.mark.xfail(
        strict=True, reason="measured: behind the default 5 Hz noise filter, speed's first key "
        "score on 131_03 differs with and without provisional events: 1.4052826599043877 "
        "and 1.4052826600519044 (same frames; a 1e-10 difference)"))
    if m == "speed" else m for m in ONLINE_METHODS])
def test_provisional_events_confirm_exactly_the_final_keys_on_every_shared_clip(method):
    """Every clip, its first 3 s (the whole of 10; `streamkey bench --playable`, which
    measures the README table, checks the same promises on every clip at full length)."""
    early = total = 0
    for clip in clips():
        m = load(clip)
        # The keyframer as it is and with provisional events side by side, sharing features.
        pipe = Pipeline(make_keyframers(m, [method], stream="raw")
                        + make_keyframers(m, [method], {"*": {"provisional": True}}))
        both = pipe.push_block(m.frames()[:LIMIT]) + pipe.flush()
        raw = [e for e in both if getattr(e, "stream", None) == "raw"]
        events = [e for e in both if getattr(e, "stream", None) == "default"]
        provisional = check_provisional(raw, events, clip)
        for e in finals(events):
            total += 1
            early += provisional[e.confirms][1].seen_at < e.decided_at
    assert early / total > 0.6  # most keys are announced before their final decision


def test_provisional_events_are_the_same_pushed_by_block_or_frame_by_frame():
    m = load("07_01.bvh")
    for method in ONLINE_METHODS:
        star = {"provisional": True, "min_interval": {"*": 0.1}}
        by_block = events_of(m, [method], star)
        assert by_block == events_of(m, [method], star, block=False), method
        check_provisional(events_of(m, [method], {"min_interval": {"*": 0.1}}), by_block,
                          method)


def test_provisional_leads_are_measured_and_positive():
    m = load("05_11.bvh")
    for method in ONLINE_METHODS:
        r = measure(m, method)
        assert np.median(r["lead_ms"]) > 100, method
        assert 0 <= np.mean(r["cancelled"]) < 0.5, method
        assert all(d >= 0 for d in r["delay_ms"])
        assert r["mismatch"] == [0.0] and min(r["announce_ms"]) >= 0


# ----------------------------------------------------------------------------- signal and sinks

def test_signal_events_carry_body_speed_and_every_method_keyness():
    m = load("05_11.bvh")
    events = events_of(m, list(ONLINE_METHODS), {"signal": 4})
    signal = [e for e in events if isinstance(e, SignalEvent)]
    assert [e.seq for e in signal] == [s for s in range(m.first_frame, m.n_frames) if s % 4 == 0]
    assert all(set(e.values) == {"body_speed", *ONLINE_METHODS} for e in signal)
    assert all(0.0 <= e.values[k] <= 1.0 for e in signal for k in ONLINE_METHODS)
    speed = np.array([e.values["body_speed"] for e in signal])
    assert speed.max() > 0.5 and speed.min() >= 0  # a dance moves, in body heights a second
    for k in ONLINE_METHODS:
        assert any(e.values[k] > 0 for e in signal), k
    assert finals(events) == finals(events_of(m, list(ONLINE_METHODS)))
    short = load("07_01.bvh")
    star = {"signal": 3, "provisional": True}
    by_block, by_frame = (events_of(short, list(ONLINE_METHODS), star, block=b)
                          for b in (True, False))
    for name in [*ONLINE_METHODS, None]:  # a pipeline interleaves its keyframers per block
        assert [e for e in by_block if getattr(e, "method", None) == name] == [
            e for e in by_frame if getattr(e, "method", None) == name], name


def test_run_writes_every_event_type_to_jsonl_and_osc(tmp_path, capsys):
    log = tmp_path / "events.jsonl"
    summary = tmp_path / "summary.json"
    assert main(["run", "--from", str(DATA / "07_01.bvh"), "--fast", "--provisional",
                 "--signal", "10", "--to", f"jsonl:{log}", "--to", "osc://127.0.0.1:9",
                 "--summary", str(summary)]) == 0
    records = [json.loads(line) for line in log.read_text().splitlines()]
    kinds = Counter(r["type"] for r in records)
    assert kinds["keyframe"] and kinds["provisional"] >= kinds["keyframe"] and kinds["signal"]
    assert all(r["v"] == 2 and r["id"] for r in records)
    doc = json.loads(summary.read_text())
    assert doc["events"]["provisional"] == kinds["provisional"]
    assert doc["events"].get("gap", 0) == 0
    osc = next(v for k, v in doc["sinks"].items() if k.startswith("osc"))
    # The numeric OSC layout carries every type (provisional, cancel, signal included).
    assert osc["sent"] + osc["dropped"] == len(records) and not osc.get("errors")


def test_provisional_events_survive_damaged_streams_every_one_resolved():
    m = load("05_11.amc")
    rng = np.random.default_rng(3)
    frames = [f for f in m.frames() if rng.random() >= 0.03]
    del frames[200:240]  # a long gap: the windows restart
    frames += frames[:50]  # the source starts over
    for method in ONLINE_METHODS:
        runs = []
        for star in ({}, {"provisional": True}):
            pipe = Pipeline(make_keyframers(m, [method], {"*": star}))
            runs.append([e for f in frames for e in pipe.push(f) + pipe.idle()]
                        + pipe.flush())
        assert any(isinstance(e, GapEvent) and not e.bridged for e in runs[1])
        check_provisional(runs[0], runs[1], method)


# ----------------------------------------------------------------------------- wrappers

def test_wrappers_share_the_method_keyframer_and_pass_segments_and_scores_through(monkeypatch):
    """`--max-gap`, `--min-interval` and provisional stack as `WrappedKeyframer`s over the
    method: one guard and feature stage, the method's name and digest, the rule's lookahead;
    a segment and a new stream reach the method keyframer under all three."""
    from streamkey.keyframes import SegmentEvent
    from streamkey.methods.optimal import MaxGap
    from streamkey.online import WrappedKeyframer, forget_scores
    from streamkey.playable_online import MinInterval, Playable

    m = load("07_01.bvh")
    star = {"max_gap": 1.0, "min_interval": {"*": 0.5}, "provisional": True}
    (kf,) = make_keyframers(m, ["speed"], {"*": star})
    assert isinstance(kf, Playable) and isinstance(kf.inner, MinInterval)
    assert isinstance(kf.inner.inner, MaxGap)
    method = kf.innermost
    assert not isinstance(method, WrappedKeyframer) and kf.inner.inner.inner is method
    for w in (kf, kf.inner, kf.inner.inner):
        assert w.method == "speed" and w.guard is method.guard
        assert w.features is method.features and w.recent_scores is method.recent_scores
    assert kf.inner.inner.gap == 120 and kf.inner.gap == 60  # 1 s and 0.5 s at 120 fps
    assert kf.inner.inner.lookahead == method.lookahead + 120
    assert kf.lookahead == kf.inner.lookahead == kf.inner.inner.lookahead + 60
    assert kf.params_digest == kf.inner.params_digest == kf.inner.inner.params_digest
    assert kf.params_digest != method.params_digest  # max_gap changes the keys
    seen = []
    monkeypatch.setattr(method, "note_segment", seen.append)
    segment = SegmentEvent(stream="default", kind="still", start=0, end=None, start_time=0.0,
                           end_time=None, decided_at=1)
    kf.note_segment(segment)
    assert seen == [segment]
    method.recent_scores.append(0.5)
    forget_scores(kf)
    assert not method.recent_scores

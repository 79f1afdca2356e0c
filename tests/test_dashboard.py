"""The live dashboard: operator messages, origin and token checks, and a real headless browser.

The browser test drives Debian's Chromium with Selenium + chromedriver (installed by .ci/run);
it never skips: a missing browser is a failure with the install hint.
"""

from __future__ import annotations

import asyncio
import gc
import json
import os
import re
import signal
import subprocess
import tempfile
import time
import urllib.error
import urllib.request
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from live_helpers import MS, read_jsonl, streamkey, wait_ready
from websockets.asyncio.client import connect
from websockets.exceptions import InvalidStatus

from streamkey.dashboard import MAX_TEXT, Annotator, DashboardSink, run_dashboard
from streamkey.methods import ONLINE_METHODS
from streamkey.replay.demo import demo_motion

ROOT = Path(__file__).resolve().parents[1]
METHODS = ["saliency", "speed", "simplify"]
LIVE = list(ONLINE_METHODS)  # what `demo` and `run --method all` run
CHROMIUM = "/usr/bin/chromium"
CHROMEDRIVER = "/usr/bin/chromedriver"
# The demo motion is looped; 4 s loops keep the test short (one loop shows every method).
DEMO_SECONDS = "4"


def annotator_with_keys() -> Annotator:
    a = Annotator("take")
    a.fps = 120.0
    for seq in range(100, 400):
        a.see_frame(seq, seq / 120)
    a.see_key("saliency", 150)
    a.see_key("speed", 200)
    return a


@pytest.mark.parametrize(("message", "reason"), [
    ("{bad json", "malformed JSON"),
    ("[1, 2]", "expected a JSON object"),
    ('{"action": "delete", "frame": 150}', "unknown action 'delete'"),
    ('{"action": "label", "frame": "150", "text": "x"}', "'frame' must be an integer"),
    ('{"action": "label", "frame": true, "text": "x"}', "'frame' must be an integer"),
    ('{"action": "label", "frame": 5000, "text": "x"}', "unknown frame 5000"),
    ('{"action": "key", "frame": 99}', "unknown frame 99; the stream has frames 100..399"),
    ('{"action": "label", "frame": 151, "text": "x"}', "frame 151 is not a keyframe"),
    ('{"action": "label", "frame": 150, "method": "speed", "text": "x"}',
     "not a keyframe of 'speed'"),
    ('{"action": "label", "frame": 150, "text": "   "}', "must not be empty"),
    (json.dumps({"action": "label", "frame": 150, "text": "x" * (MAX_TEXT + 1)}),
     "text too long (501 characters; at most 500)"),
    ("x" * 5000, "message too long"),
])
def test_annotator_refuses_bad_messages_naming_the_problem(message: str, reason: str) -> None:
    a = annotator_with_keys()
    record, reply = a.handle(message)
    assert record is None
    assert reply["type"] == "error" and reason in reply["error"]
    assert a.count == 0


def test_annotator_builds_annotation_events_that_reference_the_frame() -> None:
    a = annotator_with_keys()
    record, reply = a.handle('{"id": 7, "action": "label", "frame": 150, "text": " heel "}')
    assert reply == {"type": "ack", "id": 7, "annotation": record}
    assert record is not None
    assert record["type"] == "annotation" and record["action"] == "label"
    assert (record["frame"], record["method"], record["text"]) == (150, None, "heel")
    assert record["time"] == pytest.approx(150 / 120) and record["stream"] == "take"
    key, _ = a.handle('{"action": "key", "frame": 300}')
    assert key is not None and key["method"] == "manual"
    # a manual key is a keyframe from then on: it can be labelled and rejected
    assert a.handle('{"action": "reject", "frame": 300, "method": "manual"}')[0] is not None


@settings(max_examples=300, deadline=None)
@given(st.one_of(st.text(max_size=300),
                 st.dictionaries(st.sampled_from(["action", "frame", "method", "text", "id",
                                                  "ref"]),
                                 st.one_of(st.none(), st.integers(), st.text(max_size=20),
                                           st.sampled_from(["label", "key", "reject", "accept",
                                                            "undo", "take/annotation/x-1"]),
                                           st.floats(), st.lists(st.integers(), max_size=3),
                                           st.dictionaries(st.text(max_size=3),
                                                           st.integers(), max_size=2)))
                 .map(json.dumps)))
def test_annotator_never_raises_whatever_the_client_sends(text: str) -> None:
    a = annotator_with_keys()
    good, _ = a.handle('{"action": "reject", "frame": 150, "method": "saliency"}')
    assert good is not None
    record, reply = a.handle(text)
    assert reply["type"] in ("ack", "error")
    assert (record is None) == (reply["type"] == "error")
    assert a.refused == (reply["type"] == "error")  # every refusal counted
    # whatever came before, an undo of the first annotation still answers (ack or error)
    again, reply = a.handle(json.dumps({"action": "undo", "ref": good["id"]}))
    assert reply["type"] in ("ack", "error") and (again is None) == (reply["type"] == "error")


def test_annotator_accept_and_undo_take_back_one_annotation_each() -> None:
    a = annotator_with_keys()
    reject, _ = a.handle('{"action": "reject", "frame": 150, "method": "saliency"}')
    accept, _ = a.handle('{"action": "accept", "frame": 200, "method": "speed"}')
    key, _ = a.handle('{"action": "key", "frame": 300}')
    assert reject and accept and key
    assert len({reject["id"], accept["id"], key["id"]}) == 3
    assert reject["id"].startswith("take/annotation/")
    undo, reply = a.handle(json.dumps({"id": 9, "action": "undo", "ref": reject["id"]}))
    assert reply["type"] == "ack" and reply["id"] == 9 and undo is not None
    assert (undo["action"], undo["frame"], undo["method"], undo["ref"], undo["undoes"]) == (
        "undo", 150, "saliency", reject["id"], "reject")
    assert undo["time"] == pytest.approx(150 / 120)
    # undoing a manual key un-keys its frame: it can no longer be labelled
    assert a.handle(json.dumps({"action": "undo", "ref": key["id"]}))[0] is not None
    assert "not a keyframe" in a.handle(
        '{"action": "label", "frame": 300, "text": "x"}')[1]["error"]
    refusals = [
        (json.dumps({"action": "undo", "ref": reject["id"]}), "already undone"),
        (json.dumps({"action": "undo", "ref": undo["id"]}), "an undo cannot be undone"),
        ('{"action": "undo", "ref": "take/annotation/nope"}', "unknown annotation"),
        ('{"action": "undo", "ref": 3}', "'ref' must be the id"),
        ('{"action": "undo"}', "'ref' must be the id"),
        ('{"action": "accept", "frame": 151, "method": "speed"}', "not a keyframe"),
        ('{"action": ["undo"]}', "unknown action"),
    ]
    for message, reason in refusals:
        record, reply = a.handle(message)
        assert record is None and reason in reply["error"], (message, reply)
    assert a.refused == len(refusals) + 1 and a.count == 5


@asynccontextmanager
async def serving(tmp_path: Path, motion: Any = None, methods: list[str] = METHODS,
                  **kwargs: Any) -> AsyncIterator[tuple[str, DashboardSink]]:
    """The dashboard over a looped motion (default: the demo) at its fps; yields (page URL,
    dashboard)."""
    lines: list[str] = []
    ready = asyncio.Event()
    boards: list[DashboardSink] = []

    def on_ready(line: str) -> None:
        lines.append(line)
        if "dashboard on" in line:
            ready.set()

    task = asyncio.create_task(run_dashboard(
        motion or demo_motion(4.0), methods, [], port=0, log=str(tmp_path / "session.jsonl"),
        loop=True,
        on_ready=on_ready, on_start=boards.append, **kwargs))
    await asyncio.wait_for(ready.wait(), 30 * MS)
    url = re.search(r"dashboard on (\S+)", "\n".join(lines))
    assert url is not None
    try:
        yield url.group(1), boards[0]
    finally:
        assert boards[0].engine is not None
        boards[0].engine.stop()
        summary, _ = await asyncio.wait_for(task, 30 * MS)
        assert summary.frames_in > 0


def ws_url(page: str) -> str:
    base, _, query = page.partition("?")
    return base.replace("http://", "ws://").rstrip("/") + "/ws" + (f"?{query}" if query else "")


async def next_of(ws: Any, kinds: tuple[str, ...]) -> dict[str, Any]:
    """The next message of one of `kinds` (poses, stats and events in between are skipped)."""
    async with asyncio.timeout(30 * MS):
        while True:
            message = json.loads(await ws.recv())
            if message["type"] in kinds:
                return message


async def test_malformed_client_messages_get_errors_and_the_session_goes_on(
        tmp_path: Path) -> None:
    async with serving(tmp_path) as (url, board), connect(ws_url(url)) as ws:
        hello = await next_of(ws, ("hello",))
        assert hello["methods"] == METHODS and len(set(hello["colors"].values())) == 4
        key = await next_of(ws, ("keyframe",))
        assert key["pose"] is not None  # the thumbnail of the key's own frame
        assert gc.get_freeze_count() > 10_000  # its run froze the start-up heap, as `run`
        later = board.hello()  # what a page opened now gets: take name, bones and their sides
        assert later["take"] == "demo" and len(later["sides"]) == len(later["bones"])
        assert {"L", "R", ""} == set(later["sides"])
        assert {"method": key["method"], "frame": key["frame"]} in later["keys"]  # the chart's
        bad = ["{bad", "null", '{"action": "label", "frame": 1e9, "text": "x"}',
               json.dumps({"action": "label", "frame": key["frame"], "method": key["method"],
                           "text": "y" * 600}),
               json.dumps({"action": "label", "frame": 10**9, "text": "x"}), b"\xff\xfe\x00"]
        for message in bad:
            await ws.send(message)
        errors = [await next_of(ws, ("error", "ack")) for _ in bad]
        assert [e["type"] for e in errors] == ["error"] * len(bad)
        reasons = [e["error"] for e in errors]
        assert "malformed JSON" in reasons[0] and "JSON object" in reasons[1]
        assert "'frame' must be an integer" in reasons[2] and "too long" in reasons[3]
        assert "unknown frame 1000000000" in reasons[4] and "malformed JSON" in reasons[5]
        frames_before = board.engine.summary.frames_in  # type: ignore[union-attr]
        await ws.send(json.dumps({"id": "a1", "action": "label", "frame": key["frame"],
                                  "method": key["method"], "text": "arms up"}))
        ack = await next_of(ws, ("ack", "error"))
        assert ack["type"] == "ack" and ack["id"] == "a1"
        await ws.send(json.dumps({"action": "undo", "ref": ack["annotation"]["id"]}))
        assert (await next_of(ws, ("ack", "error")))["type"] == "ack"
        await next_of(ws, ("pose",))
        assert board.engine.summary.frames_in > frames_before  # type: ignore[union-attr]
        stats = await next_of(ws, ("stats",))
        assert stats["refused"] == len(bad) and stats["annotations"] == 2
        assert stats["lost"] == 0 and set(stats["delay"]) <= set(METHODS)
        for method, delay in stats["delay"].items():
            assert 0 <= delay["frames"] <= stats["lookahead"][method]
            assert delay["ms"] == pytest.approx(1000 * delay["frames"] / 120, abs=0.06)
    logged = [e for e in read_jsonl(tmp_path / "session.jsonl") if e["type"] == "annotation"]
    assert [(e["action"], e["frame"], e["method"], e["text"]) for e in logged] == [
        ("label", key["frame"], key["method"], "arms up"),
        ("undo", key["frame"], key["method"], "")]
    assert logged[1]["ref"] == logged[0]["id"]


def http_get(url: str, headers: dict[str, str] | None = None) -> tuple[int, str]:
    try:
        with urllib.request.urlopen(urllib.request.Request(url, headers=headers or {}),
                                    timeout=30 * MS) as r:
            return r.status, r.read().decode()
    except urllib.error.HTTPError as exc:
        return exc.code, exc.read().decode()


async def test_cross_origin_and_foreign_host_requests_are_refused(tmp_path: Path) -> None:
    async with serving(tmp_path) as (url, board):
        port = url.split(":")[2].split("/")[0]
        with pytest.raises(InvalidStatus) as refused:
            async with connect(ws_url(url), origin="http://evil.example"):  # type: ignore[arg-type]
                pass
        assert refused.value.response.status_code == 403
        assert b"cross-origin WebSocket refused: origin http://evil.example" in (
            refused.value.response.body or b"")
        # DNS rebinding: a page of another name resolved to 127.0.0.1 is refused too
        status, body = await asyncio.to_thread(http_get, url, {"Host": f"evil.example:{port}"})
        assert status == 403 and "127.0.0.1 / localhost only" in body
        # the server is unharmed and its own origin still connects
        async with connect(ws_url(url), origin=f"http://127.0.0.1:{port}") as ws:  # type: ignore[arg-type]
            assert (await next_of(ws, ("hello",)))["type"] == "hello"
        status, page = await asyncio.to_thread(http_get, url)
        assert status == 200 and "/static/dashboard.js" in page
        assert len(board.refused) == 2


async def test_listening_beyond_loopback_requires_the_token(tmp_path: Path) -> None:
    async with serving(tmp_path, listen="127.0.0.2") as (url, board):
        assert board.token and url.endswith(f"/?token={board.token}")
        bare = url.split("?")[0]
        status, body = await asyncio.to_thread(http_get, bare)
        assert status == 403 and "token" in body
        assert (await asyncio.to_thread(http_get, bare + "?token=wrong"))[0] == 403
        assert (await asyncio.to_thread(http_get, url))[0] == 200
        with pytest.raises(InvalidStatus) as refused:
            async with connect(ws_url(bare)):
                pass
        assert refused.value.response.status_code == 403
        async with connect(ws_url(url)) as ws:
            assert (await next_of(ws, ("hello",)))["type"] == "hello"


# --------------------------------------------------------------------------- the browser

def chrome() -> Any:
    """Headless Chromium through chromedriver, with the flags that work on this machine."""
    for tool in (CHROMIUM, CHROMEDRIVER):
        assert Path(tool).exists(), (f"{tool} missing: apt-get install --no-install-recommends "
                                     "chromium chromium-driver (.ci/run does)")
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    for flag in ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
                 "--no-first-run", "--disable-background-networking",
                 "--disable-component-update", "--disable-sync", "--window-size=1280,1000",
                 f"--user-data-dir={tempfile.mkdtemp(prefix='streamkey-chromium-')}"):
        options.add_argument(flag)
    return webdriver.Chrome(options=options, service=Service(CHROMEDRIVER))


def wait_for(condition: Any, what: str, timeout: float = 60.0) -> Any:
    """Poll `condition` until truthy (returns it) or fail naming `what`."""
    deadline = time.monotonic() + timeout * MS
    while time.monotonic() < deadline:
        value = condition()
        if value:
            return value
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for {what}")


def test_browser_operator_session_waits_on_state_never_on_time(tmp_path: Path) -> None:
    """Markers, counters, a label, a manual key pressed while the list is held under the
    pointer (it must survive the replay of the paused keys), a reject undone from the
    annotation list, the method filter and the second view. Every wait is on page state."""
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.by import By
    from selenium.webdriver.common.keys import Keys
    from selenium.webdriver.support.ui import WebDriverWait

    log = tmp_path / "session.jsonl"
    proc = streamkey("demo", "--dashboard", "0", "--seconds", DEMO_SECONDS, "--log", str(log),
                     cwd=tmp_path)
    driver = None
    failure: BaseException | None = None
    try:
        url = re.search(r"dashboard on (\S+)", "".join(wait_ready(proc, "dashboard on")))
        assert url is not None
        driver = chrome()
        driver.get(url.group(1))
        wait = WebDriverWait(driver, 60 * MS, poll_frequency=0.05)
        text = lambda element_id: driver.find_element(By.ID, element_id).text  # noqa: E731
        js = driver.execute_script
        cards = "#keys li:not([data-method=manual])"

        def markers(method: str) -> int:
            label = driver.find_element(By.CSS_SELECTOR, f'#legend label[data-method="{method}"]')
            return int(label.get_attribute("data-count") or 0)

        for method in LIVE:  # a marker drawn in the strip chart for every method
            wait.until(lambda _, m=method: markers(m) > 0)
        first = int(text("c-frames"))
        wait.until(lambda _: int(text("c-frames")) > first)  # the counters move
        # the saliency signal is drawn too (it trails the stream by the lookahead)
        wait.until(lambda _: js("return state.saliency.length") > 10)
        assert re.search(r"saliency \d+", text("c-events"))
        assert re.fullmatch(r"[\d.]+ / [\d.]+ ms", text("c-latency"))
        assert all(re.search(rf"{m} \d+", text("c-lookahead")) for m in LIVE)
        wait.until(lambda _: all(re.search(rf"{m} [\d.]+ f / [\d.]+ ms", text("c-delay"))
                                 for m in LIVE))
        assert text("c-lost") == "0" and text("c-drops").isdigit()
        assert text("stream") == ""  # the take is the stream: named once
        assert text("take") == "demo" and re.fullmatch(r"\d\d:\d\d:\d\d\.\d{3}", text("timecode"))
        wait.until(lambda _: len(driver.find_elements(By.CSS_SELECTOR, cards)) >= 3)
        # event types of the v2 contract and unknown ones go through the page's own dispatch:
        # a provisional key is drawn hollow until its cancel; unknown types are skipped
        # (one script: no pose message can prune the provisional key in between)
        sizes = js("""
            const deliver = (m) => state.ws.onmessage({data: m});
            const sizes = [];
            deliver(JSON.stringify({type: "provisional", v: 2, stream: "demo", method: "speed",
                                    frame: state.frame, pid: -7, strength: 0.5, time: 0,
                                    seen_at: state.frame}));
            sizes.push(state.provisional.has("speed/-7"));
            for (const m of arguments[0]) deliver(m);
            sizes.push(state.provisional.has("speed/-7"));
            deliver(JSON.stringify({type: "cancel", v: 2, stream: "demo", method: "speed",
                                    frame: 0, pid: -7, decided_at: 9}));
            sizes.push(state.provisional.has("speed/-7"));
            return sizes;""", [json.dumps(m) for m in (
            {"type": "signal", "v": 2, "stream": "demo", "seq": 1, "values": {"speed": 1}},
            {"type": "from-the-future", "v": 3}, {"type": "constructor"}, {"type": None},
            {"no": "type"}, [1, 2], None, "text")] + ["{bad"])
        assert sizes == [True, True, False]
        frames_now = int(text("c-frame"))
        wait.until(lambda _: int(text("c-frame")) > frames_now)  # the page kept drawing

        # the pointer over the list: it holds still from then on
        ActionChains(driver).move_to_element(driver.find_element(By.ID, "keys")).perform()
        wait.until(lambda _: js("return state.hold"))
        item = driver.find_element(By.CSS_SELECTOR, cards)
        frame, method = int(item.get_attribute("data-frame")), item.get_attribute("data-method")
        item.find_element(By.TAG_NAME, "input").send_keys("heel strike", Keys.ENTER)
        wait.until(lambda _: item.find_element(By.CLASS_NAME, "label-text").text == "heel strike")
        js("document.activeElement.blur()")
        driver.find_element(By.TAG_NAME, "body").send_keys("k")  # the manual-key hotkey
        manual = wait.until(lambda _: driver.find_elements(By.CSS_SELECTOR,
                                                            "#keys li[data-method=manual]"))
        manual_frame = int(manual[0].get_attribute("data-frame"))
        ActionChains(driver).move_to_element(driver.find_element(By.ID, "keys")).perform()
        wait.until(lambda _: js("return state.hold"))  # (typing may have moved the page)
        victim = driver.find_elements(By.CSS_SELECTOR, cards)[1]  # not the labelled one
        rejected = int(victim.get_attribute("data-frame"))
        victim.find_element(By.CLASS_NAME, "reject").click()
        wait.until(lambda _: "rejected" in (victim.get_attribute("class") or ""))
        assert js("return state.hold")  # the clicks kept the pointer on the list
        wait.until(lambda _: js("return state.pending.length") >= 3)  # keys wait to be shown

        # undo the reject from the annotation list: the pointer leaves the keys, which replay
        entry = wait.until(lambda _: driver.find_elements(
            By.CSS_SELECTOR, "#annotations li[data-action=reject] button.undo"))
        entry[0].click()
        wait.until(lambda _: driver.find_elements(
            By.CSS_SELECTOR, "#annotations li.undone[data-action=reject]"))
        wait.until(lambda _: "rejected" not in (victim.get_attribute("class") or ""))
        wait.until(lambda _: not js("return state.hold") and text("held") == "")
        kept = driver.find_elements(By.CSS_SELECTOR, f"#keys li[data-method=manual]"
                                                     f"[data-frame='{manual_frame}']")
        assert kept, "the manual key vanished when the paused list replayed"
        plain = js("return [...document.querySelectorAll('#keys li')]"
                   ".filter((li) => !busy(li)).length")
        assert plain <= 24
        assert wait.until(lambda _: int(text("c-annotations")) == 4)

        # the method filter hides a method's cards and lane, and brings them back
        box = driver.find_element(By.CSS_SELECTOR, '#legend label[data-method="simplify"] input')
        box.click()
        wait.until(lambda _: not driver.find_elements(
            By.CSS_SELECTOR, "#keys li[data-method=simplify]:not([hidden])"))
        assert js("return state.hidden.has('simplify')")
        box.click()
        wait.until(lambda _: len(driver.find_elements(
            By.CSS_SELECTOR, "#keys li[data-method=simplify]:not([hidden])")) >= 2)
        toggle = driver.find_element(By.ID, "view2-mode")
        assert toggle.text == "show top view"  # the button names its action
        toggle.click()
        wait.until(lambda _: toggle.get_attribute("data-mode") == "top")
        assert toggle.text == "show side view"
        toggle.click()
        wait.until(lambda _: toggle.get_attribute("data-mode") == "side")
        # a session segment (an open calibration hold) is drawn as a span behind the curves,
        # beside the pipeline's own (the take it opened)
        before, after = js("const before = state.segments.size; "
                           "HANDLERS.segment({type: 'segment', kind: 'calibration', "
                           "start: state.frame - 120, end: null}); drawChart(); "
                           "return [before, state.segments.size]")
        assert after == before + 1
        ActionChains(driver).move_to_element(driver.find_element(By.ID, "c-frames")).perform()
        driver.execute_script("window.scrollTo(0, 0)")
        shot = (ROOT / "docs" if os.environ.get("STREAMKEY_UPDATE_DOCS") else ROOT / "results")
        shot.mkdir(exist_ok=True)
        assert driver.save_screenshot(str(shot / "dashboard.png"))
    except BaseException as exc:
        failure = exc
        if driver is not None:
            exc.add_note(f"page message: {driver.find_element(By.ID, 'message').text!r}")
        raise
    finally:
        if driver is not None:
            driver.quit()
        proc.send_signal(signal.SIGINT)
        try:
            _, err = proc.communicate(timeout=30 * MS)
        except subprocess.TimeoutExpired:
            proc.kill()
            _, err = proc.communicate()
        if failure is not None:
            failure.add_note(f"streamkey stderr:\n{err[-4000:]}")
    assert proc.returncode == 0, err
    assert "annotations: 4" in err and "Traceback" not in err
    events = read_jsonl(log)
    notes = [e for e in events if e["type"] == "annotation"]
    assert [(e["action"], e["frame"]) for e in notes] == [
        ("label", frame), ("key", manual_frame), ("reject", rejected), ("undo", rejected)]
    assert notes[0]["method"] == method and notes[0]["text"] == "heel strike"
    assert notes[3]["ref"] == notes[2]["id"] and notes[3]["undoes"] == "reject"
    assert {e["method"] for e in events if e["type"] == "keyframe"} == set(LIVE)


async def test_browser_keeps_the_dense_markers_of_a_dance_take_readable(
        data_dir: Path, tmp_path: Path) -> None:
    """05_06 (dance, looped) with every method: dense lanes merge keys into counted blocks
    that never overlap, and draw no guide lines over the signals."""
    from streamkey.bvh import read_bvh

    def look(url: str) -> dict[str, Any]:
        from selenium.webdriver.support.ui import WebDriverWait

        driver = chrome()
        try:
            driver.get(url)
            drawn = WebDriverWait(driver, 60 * MS, poll_frequency=0.05).until(
                lambda d: d.execute_script(  # the page's script may not have run yet
                    "return typeof state !== 'undefined' && state.frame >= 780 && state.drawn"))
            if os.environ.get("STREAMKEY_UPDATE_DOCS"):
                assert driver.save_screenshot(str(ROOT / "docs" / "dashboard_dance.png"))
            return drawn  # type: ignore[no-any-return]
        finally:
            driver.quit()

    dance = read_bvh(data_dir / "05_06.bvh")
    async with serving(tmp_path, dance, LIVE, stream="05_06") as (url, _):
        drawn = await asyncio.to_thread(look, url)
    simplify = drawn["simplify"]
    assert simplify["keys"] > simplify["marks"] >= 10  # merged, still many marks
    assert not simplify["guides"]
    assert all(d["guides"] == (d["marks"] <= 15) for d in drawn.values())
    assert any(d["guides"] for d in drawn.values() if d["marks"])  # sparse lanes keep them
    assert all(d["minGap"] >= 11 for d in drawn.values() if d["marks"] > 1)  # no overlap


def test_run_with_a_dashboard_serves_the_page_and_logs_to_the_jsonl_sink(
        data_dir: Path, tmp_path: Path) -> None:
    log = tmp_path / "take.jsonl"
    proc = streamkey("run", "--from", str(data_dir / "07_01.bvh"), "--method", "all",
                     "--to", f"jsonl:{log}", "--dashboard", "0", "--stream", "take")
    lines = wait_ready(proc, "dashboard on")
    url = re.search(r"dashboard on (\S+)", "".join(lines))
    assert url is not None and url.group(1).startswith("http://127.0.0.1:")
    status, page = http_get(url.group(1))
    assert status == 200 and "<canvas id=\"chart\"" in page
    _, err = proc.communicate(timeout=60 * MS)  # the file source ends by itself
    assert proc.returncode == 0, err
    assert not list(tmp_path.glob("session-*.jsonl"))  # the jsonl: sink is the session log
    methods = {e["method"] for e in read_jsonl(log) if e["type"] == "keyframe"}
    assert methods == set(LIVE) and "annotations: 0" in err


# -------------------------------------------------------------------------- hostile clients

def test_annotator_memory_is_bounded_and_deep_json_is_refused() -> None:
    from streamkey.dashboard import MAX_KEYS

    a = annotator_with_keys()
    for frame in range(3 * MAX_KEYS):
        a.see_key("speed", frame)
    assert len(a.keys) == MAX_KEYS and 3 * MAX_KEYS - 1 in a.keys
    record, reply = a.handle("[" * 2040 + "]" * 2040)
    assert record is None and "nested too deeply" in reply["error"]


async def test_refusals_deep_json_and_odd_tokens_never_grow_memory_nor_end_connections(
        tmp_path: Path) -> None:
    from streamkey.adapters.websocket import RECENT_REFUSALS
    from streamkey.dashboard import MAX_ANNOTATIONS

    async with serving(tmp_path) as (url, board):
        refusals = 3 * RECENT_REFUSALS
        for _ in range(refusals):
            with pytest.raises(InvalidStatus):
                async with connect(ws_url(url), origin="http://evil." + "x" * 7000):  # type: ignore[arg-type]
                    pass
        assert board.refusals["origin"] == refusals and len(board.refused) == RECENT_REFUSALS
        assert all(len(reason) <= 300 for reason in board.refused)
        status, body = await asyncio.to_thread(http_get, url + "?token=%C3%A9t%C3%A9")
        assert status == 200  # no token needed on loopback; a non-ASCII one is harmless
        async with connect(ws_url(url)) as ws:
            await next_of(ws, ("hello",))
            key = await next_of(ws, ("keyframe",))
            await ws.send("[" * 2040 + "]" * 2040)
            assert "nested too deeply" in (await next_of(ws, ("error",)))["error"]
            for i in range(MAX_ANNOTATIONS + 50):
                await ws.send(json.dumps({"id": i, "action": "key", "frame": key["frame"]}))
            while (await next_of(ws, ("ack", "error")))["id"] != MAX_ANNOTATIONS + 49:
                pass
        assert board.annotator.count == MAX_ANNOTATIONS + 50
        assert len(board.annotations) == MAX_ANNOTATIONS


async def test_listening_beyond_loopback_refuses_a_non_ascii_token_with_403(
        tmp_path: Path) -> None:
    async with serving(tmp_path, listen="127.0.0.2") as (url, board):
        bare = url.split("?")[0]
        status, body = await asyncio.to_thread(http_get, bare + "?token=%C3%A9t%C3%A9")
        assert status == 403 and "token" in body
        with pytest.raises(InvalidStatus) as refused:
            async with connect(ws_url(bare + "?token=%C3%A9")):
                pass
        assert refused.value.response.status_code == 403


async def test_the_websocket_event_sink_applies_the_dashboards_origin_host_and_token_rules(
        ) -> None:
    import socket as socket_module

    from live_helpers import free_port

    from streamkey.adapters import make_sink, parse_address
    from streamkey.keyframes import KeyframeEvent

    port = free_port(socket_module.SOCK_STREAM)
    sink = make_sink(parse_address(f"ws://127.0.0.1:{port}"))
    assert await sink.start() == f"ws://127.0.0.1:{port}"
    try:
        with pytest.raises(InvalidStatus) as refused:
            async with connect(f"ws://127.0.0.1:{port}", origin="http://evil.example"):  # type: ignore[arg-type]
                pass
        assert refused.value.response.status_code == 403
        base = f"http://127.0.0.1:{port}/"
        status, _ = await asyncio.to_thread(http_get, base, {"Host": f"evil.example:{port}"})
        assert status == 403  # DNS rebinding
        with pytest.raises(InvalidStatus) as twice:  # two Host headers: 403, not a 500
            async with connect(f"ws://127.0.0.1:{port}",
                               additional_headers={"Host": f"127.0.0.1:{port}"}):
                pass
        assert twice.value.response.status_code == 403
        assert sink.refusals == {"origin": 1, "host": 1, "header": 1}
        async with connect(f"ws://127.0.0.1:{port}") as ws:  # a non-browser client
            async with asyncio.timeout(10 * MS):
                while not sink.clients:  # noqa: ASYNC110 (the server registers it next)
                    await asyncio.sleep(0.005)
            sink.offer(KeyframeEvent(stream="s", method="speed", frame=5, time=0.1, score=1.0,
                                     decided_at=9, lookahead=4, params="p"))
            assert json.loads(await asyncio.wait_for(ws.recv(), 10 * MS))["frame"] == 5
    finally:
        await sink.close()
    wide = make_sink(parse_address(f"ws://127.0.0.2:{port}"), listen="127.0.0.2")
    ready = await wide.start()
    try:
        assert wide.token and ready.endswith(f"/?token={wide.token}")
        with pytest.raises(InvalidStatus):
            async with connect(f"ws://127.0.0.2:{port}"):
                pass
        async with connect(f"ws://127.0.0.2:{port}/?token={wide.token}"):
            pass
    finally:
        await wide.close()


# -------------------------------------------------------------------------- operator's view

@pytest.mark.parametrize("command", [
    ["demo", "--seconds", "4"],
    ["run", "--from", "07_01.bvh", "--method", "speed", "--to", "jsonl:take.jsonl"],
])
def test_a_busy_dashboard_port_is_one_error_line_and_leaves_no_file(
        command: list[str], data_dir: Path, tmp_path: Path) -> None:
    import socket as socket_module

    command = [str(data_dir / c) if c.endswith(".bvh") else c for c in command]
    with socket_module.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        proc = streamkey(*command, "--dashboard", str(port), cwd=tmp_path)
        _, err = proc.communicate(timeout=60 * MS)
    assert proc.returncode == 2
    assert err == (f"error: --dashboard {port}: cannot listen on 127.0.0.1:{port}: the port "
                   "is in use (give another port, or 0 for a free one)\n")
    assert list(tmp_path.iterdir()) == []  # no empty session-*.jsonl, no take.jsonl


def test_bone_sides_colour_the_left_and_right_limbs_of_a_cmu_skeleton(data_dir: Path) -> None:
    from streamkey.bvh import read_bvh
    from streamkey.dashboard import LiveView, bone_sides
    from streamkey.motion import Skeleton

    skeleton = read_bvh(data_dir / "07_01.bvh").skeleton
    view = LiveView(skeleton, 120.0)
    named = {skeleton.names[child]: side
             for (child, _), side in zip(view.bones, view.sides, strict=True)
             if child < skeleton.n_joints}
    assert all(side == "L" for name, side in named.items() if name.startswith("Left"))
    assert all(side == "R" for name, side in named.items() if name.startswith("Right"))
    assert named["LeftHand"] == "L" and named["RightFoot"] == "R"
    assert named["Spine"] == "" and named["Head"] == ""
    # a rig whose roles are unknown draws in one colour (no guessing from names)
    odd = Skeleton(["a", "b"], [-1, 0], [[0, 0, 0], [0, 1, 0]], [["Xrotation"], ["Xrotation"]])
    assert bone_sides(odd, [[1, 0]]) == [""]


async def test_the_dashboard_counts_frames_lost_in_a_seq_hole_apart_from_drops(
        data_dir: Path, tmp_path: Path) -> None:
    """A real stream with a 30-frame seq hole (JSON Lines on stdin): the page's stats say
    `lost 30` while `drops` stays 0."""
    sent = await asyncio.to_thread(subprocess.run, [
        *streamkey_argv(), "replay", str(data_dir / "07_01.bvh"), "--to", "-", "--frames",
        "300", "--rate", "100000"], capture_output=True, text=True, timeout=120 * MS)
    lines = [line for line in sent.stdout.splitlines()
             if not 200 <= json.loads(line).get("seq", -1) < 230]
    assert len(lines) == 1 + 300 - 30
    proc = await asyncio.create_subprocess_exec(
        *streamkey_argv(), "run", "--from", "-", "--method", "speed", "--dashboard", "0",
        "--to", f"jsonl:{tmp_path / 'take.jsonl'}", stdin=subprocess.PIPE,
        stderr=subprocess.PIPE)
    assert proc.stdin is not None and proc.stderr is not None
    try:
        proc.stdin.write((lines[0] + "\n").encode())  # the skeleton: then the page is up
        await proc.stdin.drain()
        async with asyncio.timeout(60 * MS):
            while b"dashboard on" not in (line := await proc.stderr.readline()):
                assert line, "streamkey ended before the dashboard was up"
        url = re.search(r"dashboard on (\S+)", line.decode())
        assert url is not None
        async with connect(ws_url(url.group(1))) as ws:
            proc.stdin.write(("\n".join(lines[1:]) + "\n").encode())
            await proc.stdin.drain()
            async with asyncio.timeout(60 * MS):
                while (stats := await next_of(ws, ("stats",)))["lost"] == 0:
                    pass
            assert (stats["lost"], stats["drops"], stats["gaps"]) == (30, 0, 1)
    finally:
        proc.stdin.close()
        _, err = await asyncio.wait_for(proc.communicate(), 60 * MS)
    assert proc.returncode == 0, err


def streamkey_argv() -> list[str]:
    import sys

    return [sys.executable, "-m", "streamkey"]


def test_the_lookahead_counter_follows_the_auto_preset_after_its_switch(data_dir: Path) -> None:
    """05_06 (fast dance), unfiltered: `auto` saliency starts with "low" (121 frames) and
    switches to "high" after 2 s; the counter then shows 37, the lookahead that applies.
    (Behind the default 5 Hz noise filter `auto` keeps "low" on 05_06, so the switch the
    counter must follow is made on the raw stream.)"""
    from types import SimpleNamespace

    from streamkey.amc import read_motion
    from streamkey.dashboard import _lookahead_now
    from streamkey.online import Pipeline
    from streamkey.streaming import make_keyframers

    motion = read_motion(str(data_dir / "05_06.bvh"))
    pipeline = Pipeline(make_keyframers(motion, ["saliency"], {"*": {"noise_cutoff_hz": 0}}))
    engine = SimpleNamespace(table=SimpleNamespace(live={"take": SimpleNamespace(
        pipeline=pipeline)}))
    frames = motion.frames()
    for frame in frames[:10]:
        pipeline.push(frame)
    assert _lookahead_now(engine, {"saliency": 121}) == {"saliency": 121}  # undecided
    for frame in frames[10:400]:
        pipeline.push(frame)
    assert _lookahead_now(engine, {"saliency": 121}) == {"saliency": 37}


def test_browser_lists_refused_input_as_the_stderr_line(data_dir: Path, tmp_path: Path) -> None:
    """A frame of the wrong size over real OSC: the page lists the same line `run` prints on
    stderr (a status event `input_channels`), and a page opened later lists it too (hello).
    Every wait is on page state."""
    import socket as sockets

    import numpy as np
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    from streamkey.adapters.osc import encode_frame

    with sockets.socket(sockets.AF_INET, sockets.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    proc = streamkey("run", "--from", f"osc://127.0.0.1:{port}", "--method", "simplify",
                     "--skeleton", str(data_dir / "07_05.bvh"), "--dashboard", "0", "--log",
                     str(tmp_path / "session.jsonl"))
    drivers: list[Any] = []
    try:
        lines = "".join(wait_ready(proc, "dashboard on", timeout=300))
        if "listening on" not in lines:  # the page binds first, then the source
            wait_ready(proc, timeout=300)
        url = re.search(r"dashboard on (\S+)", lines)
        assert url is not None

        def page() -> tuple[Any, Any]:
            driver = chrome()
            drivers.append(driver)
            driver.get(url.group(1))
            wait = WebDriverWait(driver, 60 * MS, poll_frequency=0.05)
            wait.until(lambda d: d.find_element(By.ID, "status").get_attribute("data-state")
                       == "open")
            return driver, wait

        def listed(driver: Any) -> list[str]:
            return [li.text for li in driver.find_elements(By.CSS_SELECTOR, "#input-notices li")]

        driver, wait = page()
        assert not driver.find_element(By.ID, "input-panel").is_displayed()
        with sockets.socket(sockets.AF_INET, sockets.SOCK_DGRAM) as out:
            out.sendto(encode_frame(0, 0.0, np.zeros(5)), ("127.0.0.1", port))
        line = next(ln for ln in iter(proc.stderr.readline, "")  # type: ignore[union-attr]
                    if ln.startswith("warning:")).strip()
        assert "frame with 5 values on stream 'default'" in line
        wait.until(lambda d: listed(d))
        assert listed(driver) == [line]
        assert driver.find_element(By.ID, "input-panel").is_displayed()
        item = driver.find_element(By.CSS_SELECTOR, "#input-notices li")
        assert item.get_attribute("data-kind") == "channels"
        late, late_wait = page()  # opened after the refusal: the hello lists it
        late_wait.until(lambda d: listed(d))
        assert listed(late) == [line]
    finally:
        for driver in drivers:
            driver.quit()
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=60 * MS)
    assert proc.returncode == 0 and "input problems: channels 1" in err, err

"""A WebSocket fuzzer of our own (hypothesis) against a real server, with REST batches
interleaved: random and hostile messages to a few sessions while a bystander session streams a
clean drive; then SIGKILL and restart, then a graceful stop and restart, each restoring every
session exactly.

Checked for each message, against a model of the protocol of ``navsvc/api/routes/stream.py``
and ``routes/sessions.py`` (:func:`_ws_expect`, :func:`_rest_expect`): exactly one reply of
the kind the protocol gives (``result``, ``error``, ``pong``; over REST the status), or a close
with a documented code (4401 bad key, 4404 unknown session); a result counts every packet
(``accepted + len(rejected)``) and its positions are finite; no 5xx, no ``internal`` error.
Anything accepted is replayable: the accepted packets of each batch, applied offline to a
fresh :class:`VehicleSession`, are all accepted again and give the positions the server sent;
the session's counts and position equal that replay's, and each restart's.

A crash is a socket closed without a documented code, a server that died, an ``internal``
error reply, or a packet refused as ``unusable`` (the pipeline raised on it: the server's own
catch-all); a 5xx over REST is counted apart. The messages of the reliability issue (deep
nesting, 5,000 digits, lone surrogates, binary frames, 1,001 packets, resent batch numbers)
and the findings so far are tried in every run as explicit examples.

The server's state carries over from one example to the next (one server, a few sessions,
the budget of one test file), so a failing example would not shrink to anything meaningful:
violations are collected by kind with the shortest message that showed each, and the test
fails at the end listing them all, so one finding does not hide the next.
"""

from __future__ import annotations

import json
import math
import sys
import threading
import time
import uuid
from collections import Counter
from collections.abc import Iterator
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import ClientConnection, connect

from navsvc.session import SessionConfig, VehicleSession, config_from_options
from navsvc.sim.simulate import SENSOR_KINDS, DriveSpec, simulate_drive
from navsvc.wire.nmea import checksum
from navsvc.wire.positions import position_json
from roadgraph import RoadGraph
from tests.api.server import Server, start_server
from tests.wire.test_oncore import ba_frame

KEY, OTHER_KEY = "ws-fuzz-key-0001", "ws-fuzz-key-0002"
ENV = {"NAVSVC_API_KEYS": f"{KEY},{OTHER_KEY}"}
BATCH_LIMIT = 1000  # NAVSVC_MAX_BATCH_PACKETS's default
MAX_SEQ = 2**53
SURE_DEPTH, DEEP_DEPTH = 900, 1100  # json.loads on the server's stack: parses below, fails from
REPLY_TIMEOUT_S = 30.0  # a busy machine
EXAMPLES = 250  # with the explicit ones; about 1,000 messages, 20-40 s on a busy machine
FUZZED_OPTIONS: list[dict[str, Any]] = [
    {"sensors": "gyro_odometer"}, {"sensors": "steering_odometer", "map_feedback": True},
    {"sensors": "gps_only"}, {"sensors": "gyro_odometer", "fusion": "fuzzy"}]
BYSTANDER_BATCH = 100
POSITION_NUMBERS = ("lat", "lon", "fused_lat", "fused_lon", "heading_deg", "speed_mps",
                    "position_sigma_m")
UNKNOWN_BEFORE_START_UP = ("heading_deg", "speed_mps")  # null while initializing


# --- messages: JSON values with leaves resolved when sent --------------------------------

@dataclass(frozen=True)
class Rel:
    """A time ``dt`` seconds after the session's clock (valid packets, in time order)."""
    dt: float


@dataclass(frozen=True)
class Jump:
    """A time ``dt`` seconds from the session's clock that does not move it (backwards, or
    more than the session's limit ahead)."""
    dt: float


@dataclass(frozen=True)
class Raw:
    """JSON text sent as it is (NaN tokens, 5,000 digits, deep nesting, broken JSON)."""
    text: str


@dataclass(frozen=True)
class Seq:
    """A batch number relative to the session's last: next, a gap ahead, the same, older."""
    how: str


@dataclass(frozen=True)
class Send:
    channel: str  # "ws" or "rest"
    body: Any  # a JSON value with Rel/Raw/Seq leaves; bytes: a binary frame or raw body
    query_seq: Any = None  # REST: batch_seq (Seq, or a bad value sent as text)


@dataclass(frozen=True)
class Knock:
    """A connection that must be refused: wrong, missing or another owner's key; no session."""
    how: str


Action = tuple[int, Send | Knock]  # (which fuzzed session, what)

MAP_LAT, MAP_LON = (43.7230, 43.7500), (7.4060, 7.4380)  # inside the sample map's bbox
HOSTILE: st.SearchStrategy[Any] = st.sampled_from([
    "12", "", "NaN", "\ud800", True, False, None, [], {}, [1, 2, 3], -1, 0, 2**63, 10**400,
    1e308, -1e308, 5e-324, Raw("NaN"), Raw("Infinity"), Raw("-Infinity"), Raw("1e400"),
    Raw('"\\ud800"'), Raw('"\\udfff\\ud800"'), Raw("[" * 500 + "]" * 500)])
BAD_TIMES = st.sampled_from([
    -1.0, -1e-9, 1.7e12, 1.7e9 * 1000.0, 1e308, 4_102_444_801.0, "0", True, None, Raw("NaN"),
    Raw("Infinity"), Raw("-0"), 10**400, Jump(3601.0), Jump(-5.0), Jump(-0.5)])
BAD_KINDS = st.sampled_from(["truth", "truth", "GPS", "", None, 7, "x", "\ud800", ["gps"], "gps "])


def _rel() -> st.SearchStrategy[Rel]:
    return st.builds(Rel, st.floats(0.0, 2.0).map(lambda x: round(x, 3)))


def _nmea_text(kind: str, lat: float, lon: float, number: str) -> str:
    ns, ew = f"{int(lat):02d}{(lat % 1) * 60:06.3f}", f"{int(lon):03d}{(lon % 1) * 60:06.3f}"
    body = {"GGA": f"GPGGA,123519,{ns},N,{ew},E,1,08,{number},45.4,M,46.9,M,,",
            "RMC": f"GPRMC,123519,A,{ns},N,{ew},E,{number},84.4,230394,003.1,W",
            "VTG": f"GPVTG,054.7,T,034.4,M,{number},N,010.2,K"}[kind]
    return f"${body}*{checksum(body):02X}"


NMEA = st.builds(
    _nmea_text, st.sampled_from(["GGA", "RMC", "VTG"]), st.floats(*MAP_LAT), st.floats(*MAP_LON),
    st.sampled_from(["0.9", "5.5", "12.0", "", "0", "-3", "nan", "inf", "1e6", "1e308", "x"]))
ONCORE = st.builds(
    lambda lat, lon, speed, heading, status: ba_frame(lat, lon, speed_mps=speed,
                                                      heading_deg=heading, status=status).hex(),
    st.floats(*MAP_LAT), st.floats(*MAP_LON), st.floats(0, 60), st.floats(0, 359.9),
    st.sampled_from([0x30, 0x34, 0x20, 0x71, 0xFF]))
ANGLE = st.floats(-30.0, 30.0)
TRIPLE = st.tuples(ANGLE, ANGLE, ANGLE).map(list)
PACKETS = {
    "gps": st.fixed_dictionaries(
        {"t": _rel(), "kind": st.just("gps"), "lat": st.floats(*MAP_LAT),
         "lon": st.floats(*MAP_LON)},
        optional={"speed_mps": st.floats(0, 40), "heading_deg": st.floats(0, 360),
                  "hdop": st.floats(0.5, 5), "sats": st.integers(4, 12),
                  "fix": st.sampled_from(["none", "2d", "3d", "dgps", "rtk"]),
                  "accuracy_m": st.floats(1, 20), "alt_m": st.floats(0, 200)}),
    "imu": st.one_of(
        st.fixed_dictionaries({"t": _rel(), "kind": st.just("imu"), "yaw_rate_dps": ANGLE},
                              optional={"accel_fwd_mps2": st.floats(-3, 3),
                                        "accel_left_mps2": st.floats(-3, 3)}),
        st.fixed_dictionaries({"t": _rel(), "kind": st.just("imu"), "gyro_dps": TRIPLE,
                               "accel_mps2": TRIPLE})),
    "odometer": st.fixed_dictionaries({"t": _rel(), "kind": st.just("odometer")}, optional={
        "distance_m": st.floats(0, 1e4), "ticks": st.integers(0, 10**6),
        "speed_mps": st.floats(0, 40)}).filter(lambda p: len(p) > 2),
    "steering": st.fixed_dictionaries({"t": _rel(), "kind": st.just("steering"),
                                       "angle_deg": ANGLE}),
    "nmea": st.fixed_dictionaries({"t": _rel(), "kind": st.just("nmea"), "sentence": NMEA}),
    "oncore": st.fixed_dictionaries({"t": _rel(), "kind": st.just("oncore"), "hex": ONCORE})}
VALID = st.one_of(*PACKETS.values())
JUNK = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=8)
    | st.sampled_from(["\ud800", "\udfff"]) | HOSTILE,
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=6), inner,
                                                                 max_size=4),
    max_leaves=10)


@st.composite
def _mutated(draw: st.DrawFn) -> dict[str, Any]:
    packet = dict(draw(VALID))
    how = draw(st.sampled_from(["field", "drop", "time", "kind", "extra"]))
    name = draw(st.sampled_from(sorted(packet)))
    if how == "field":
        packet[name] = draw(HOSTILE)
    elif how == "drop":
        del packet[name]
    elif how == "time":
        packet["t"] = draw(BAD_TIMES)
    elif how == "kind":
        packet["kind"] = draw(BAD_KINDS)
    else:
        packet[draw(st.sampled_from(["x", "\ud800", "t ", "lat"]))] = draw(JUNK)
    return packet


PACKET = st.one_of(VALID, VALID, _mutated(), JUNK)
PACKET_LIST = st.lists(PACKET, max_size=8)


def _nested(depth: int, inner: str = "0") -> Raw:
    return Raw("[" * depth + inner + "]" * depth)


DEEP = st.sampled_from([500, 963, 5000]).flatmap(lambda d: st.sampled_from([
    _nested(d), Raw('{"a":' * d + "0" + "}" * d),
    Raw('{"t":1.0,"kind":"imu","yaw_rate_dps":1,"x":' + _nested(d).text + "}")]))
BROKEN = st.sampled_from([
    Raw(""), Raw(" "), Raw("[{"), Raw('{"t":'), Raw("nul"), Raw("[1,]"), Raw("\x00"),
    Raw("9" * 5000), Raw("[" + "1" * 5000 + "]"), Raw('"\\ud800"'), Raw('["\\ud800"]'),
    Raw("NaN"), Raw("[NaN, Infinity, -Infinity]"), Raw('{"type":"ping"'),
    Raw('{"type": "ping", "type": "batch"}')]) | st.text(max_size=20).map(Raw)
BINARY = st.sampled_from([b"\xff\xfe", b"\xed\xa0\x80", b"\x80", b"", b"[\xc3]"]) | st.binary(
    max_size=30) | st.builds(lambda p: json.dumps([p]).encode(), st.just(
        {"t": 0.0, "kind": "imu", "yaw_rate_dps": 1.0}))
HUGE = st.builds(lambda p, n: [p] * n, VALID, st.sampled_from([BATCH_LIMIT, BATCH_LIMIT + 1,
                                                               5000]))
SEQ = st.builds(Seq, st.sampled_from(["next", "next", "gap", "same", "older"]))
BAD_SEQ = st.sampled_from([-1, "1", 1.5, True, None, MAX_SEQ + 1, 10**400, Raw("NaN"), [1]])
BATCH = st.fixed_dictionaries({"type": st.just("batch"), "seq": SEQ | SEQ | BAD_SEQ,
                               "packets": PACKET_LIST | PACKET_LIST | HUGE | JUNK})
PINGS = st.sampled_from([{"type": "ping"}, {"type": "ping", "x": 1}, {"type": "PING"},
                         {"type": "pong"}])
WS_BODY = st.one_of(PACKET, PACKET_LIST, PACKET_LIST, BATCH, BATCH, PINGS, JUNK, DEEP, BROKEN,
                    BINARY, HUGE)
REST_BODY = st.one_of(PACKET_LIST, PACKET_LIST, PACKET_LIST, HUGE, JUNK, DEEP, BROKEN, BINARY)
REST_SEQ = st.none() | st.none() | SEQ | st.sampled_from(["-1", "x", "1.5", str(MAX_SEQ + 1),
                                                         "true", ""])
KNOCK = st.builds(Knock, st.sampled_from(["wrong_key", "no_key", "other_owner", "unknown"]))
SENDS = {"ws": st.builds(Send, st.just("ws"), WS_BODY),
         "rest": st.builds(Send, st.just("rest"), REST_BODY, REST_SEQ), "knock": KNOCK}
ACTION = st.tuples(st.integers(0, len(FUZZED_OPTIONS) - 1), st.sampled_from(
    ["ws", "ws", "ws", "ws", "rest", "rest", "knock"]).flatmap(SENDS.__getitem__))
ACTIONS = st.lists(ACTION, min_size=1, max_size=5)


def _gps(dt: float, step: int = 0) -> dict[str, Any]:
    """A fix ``dt`` after the session's clock, ``step`` times 11 m north of the first."""
    return {"t": Rel(dt), "kind": "gps", "lat": 43.7384 + step * 1e-4, "lon": 7.4246}


# always tried: the messages of the reliability issue, over both channels ...
_ISSUE = [
    _nested(500), _nested(963), _nested(5000), Raw("9" * 5000), Raw("[" + "1" * 5000 + "]"),
    b"\xff\xfe", Raw('"\\ud800"'), Raw('[{"t":0,"kind":"\\ud800"}]'), Raw(""),
    [_gps(0.0), {"t": 0.5, "kind": "odometer", "ticks": 10**400},
     {"t": 0.6, "kind": "odometer", "distance_m": 1e300}, _gps(1.0)],
    [{"t": t, "kind": "imu", "yaw_rate_dps": 0.0} for t in (1e308, 1.7e12, -1.0)],
    [_gps(0.1)] * (BATCH_LIMIT + 1), {"type": "batch", "seq": Seq("next"), "packets": [_gps(0.2)]},
    {"type": "batch", "seq": Seq("same"), "packets": [_gps(0.3)]},
    {"type": "batch", "seq": "1", "packets": []}, {"type": "ping"}]
ISSUE_MESSAGES: list[Action] = [(0, Send("ws", m)) for m in _ISSUE] + [
    (1, Send("rest", m if isinstance(m, (list, bytes, Raw)) else [m])) for m in _ISSUE] + [
    (0, Knock(how)) for how in ("wrong_key", "no_key", "other_owner", "unknown")]
# ... an NMEA speed of 1e308 knots (JSON speeds stop at 100 m/s) to a GPS-only session ...
_VTG = {"t": Rel(0.5), "kind": "nmea", "sentence": "$GPVTG,054.7,T,034.4,M,1e308,N,010.2,K*09"}
WITNESS = len(FUZZED_OPTIONS)  # a GPS-only session of its own, which random actions leave be
NMEA_SPEED: list[Action] = [(WITNESS, Send("ws", [_gps(i, i) for i in range(5)])),
                            (WITNESS, Send("ws", _VTG)), (WITNESS, Send("ws", [_gps(1.0, 6)])),
                            (WITNESS, Send("rest", [_gps(1.0, 7)]))]
# ... and a simulator's truth record, sent along with its packets
TRUTH: list[Action] = [(0, Send("ws", [_gps(0.0), {"t": Rel(0.0), "kind": "truth"}]))]


# --- the client side of a fuzzed session -------------------------------------------------

@dataclass
class Fuzzed:
    """One fuzzed session: its connection, clock, last batch number and offline replay."""
    id: str
    options: dict[str, Any]
    replay: VehicleSession
    ws: ClientConnection | None = None
    clock: float = 0.0
    last_seq: int | None = None
    accepted: int = 0
    rejected: int = 0
    sent_max_dt: float = 0.0
    first_replies: dict[int, dict[str, Any]] = field(default_factory=dict)  # by batch number

    def seq(self, how: str) -> int:
        last = -1 if self.last_seq is None else self.last_seq
        return {"next": last + 1, "gap": last + 7, "same": max(last, 0),
                "older": max(last - 3, 0)}[how]


def _render(value: Any, s: Fuzzed) -> str:
    """JSON text of a message; Rel times and Seq numbers resolved for session ``s``."""
    if isinstance(value, Raw):
        return value.text
    if isinstance(value, Rel):
        s.sent_max_dt = max(s.sent_max_dt, value.dt)
        return repr(round(s.clock + value.dt, 3))
    if isinstance(value, Jump):
        return repr(round(s.clock + value.dt, 3))
    if isinstance(value, Seq):
        return str(s.seq(value.how))
    if isinstance(value, float) and not math.isfinite(value):
        return "NaN" if math.isnan(value) else "Infinity" if value > 0 else "-Infinity"
    if isinstance(value, list):
        return "[" + ",".join(_render(v, s) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ",".join(json.dumps(k) + ":" + _render(v, s) for k, v in value.items()) + "}"
    return json.dumps(value)  # ASCII: a lone surrogate goes as its \\u escape


def _depth(text: str) -> int:
    """The deepest nesting of brackets outside strings (without parsing)."""
    deepest = level = 0
    in_string = escaped = False
    for ch in text:
        if in_string:
            if escaped:
                escaped = False
            elif ch == "\\":
                escaped = True
            elif ch == '"':
                in_string = False
        elif ch == '"':
            in_string = True
        elif ch in "[{":
            level += 1
            deepest = max(deepest, level)
        elif ch in "]}":
            level -= 1
    return deepest


def _loads(text: str | bytes) -> tuple[bool, Any]:
    """(parsed, value) as the server's json.loads sees it, without its stack's depth limit."""
    limit = sys.getrecursionlimit()
    sys.setrecursionlimit(max(limit, 4 * DEEP_DEPTH))
    try:
        return True, json.loads(text)
    except (ValueError, RecursionError):
        return False, None
    finally:
        sys.setrecursionlimit(limit)


@dataclass(frozen=True)
class Expect:
    """What the protocol answers: reply types (WS) or statuses (REST) allowed, and for a
    result the packets and batch number."""
    allowed: frozenset[Any]
    packets: list[Any] | None = None
    seq: int | None = None
    resend: bool = False  # a number at or below the last: the first reply again, or refused


def _ws_expect(frame: str | bytes, s: Fuzzed) -> Expect:
    """The reply ``stream.py``'s docstring promises for one frame."""
    text: str | bytes = frame
    if isinstance(frame, bytes):
        try:
            text = frame.decode()
        except UnicodeDecodeError:
            return Expect(frozenset({"error"}))
    depth = _depth(text if isinstance(text, str) else "")
    ok, message = _loads(text) if depth < DEEP_DEPTH else (False, None)
    if not ok:
        return Expect(frozenset({"error"}))
    either = frozenset({"error", "result"}) if depth >= SURE_DEPTH else frozenset({"result"})
    if isinstance(message, dict) and message.get("type") == "ping":
        return Expect(frozenset({"pong"}))
    if isinstance(message, dict) and message.get("type") == "batch":
        seq, packets = message.get("seq"), message.get("packets")
        if not isinstance(seq, int) or isinstance(seq, bool) or not 0 <= seq <= MAX_SEQ \
                or not isinstance(packets, list):
            return Expect(frozenset({"error"}))
        return _batch_expect(packets, seq, s, either, "error", "error")
    return _batch_expect(message if isinstance(message, list) else [message], None, s, either,
                         "error", "error")


def _batch_expect(packets: list[Any], seq: int | None, s: Fuzzed, result: frozenset[Any],
                  too_many: Any, conflict: Any) -> Expect:
    """A batch's answer: refused when too long; for a number at or below the session's
    last, the first reply again, or refused when that is no longer kept."""
    if len(packets) > BATCH_LIMIT:
        return Expect(frozenset({too_many}))
    if seq is not None and s.last_seq is not None and seq <= s.last_seq:
        return Expect(result | {conflict}, packets, seq, True)
    return Expect(result, packets, seq)


def _rest_expect(body: str | bytes, query: str | None, s: Fuzzed) -> Expect:
    """The status ``POST /packets`` answers with, in FastAPI's order of checks."""
    depth = _depth(body if isinstance(body, str) else body.decode("latin-1"))
    ok, value = _loads(body) if depth < DEEP_DEPTH else (False, None)
    if body in ("", b""):
        return Expect(frozenset({422}))
    if not ok:
        return Expect(frozenset({400}))
    seq = int(query) if query is not None and query.isdigit() and int(query) <= MAX_SEQ \
        else None
    if not isinstance(value, list) or (query is not None and seq is None):
        return Expect(frozenset({422} | ({400} if depth >= SURE_DEPTH else set())))
    either = frozenset({400, 200}) if depth >= SURE_DEPTH else frozenset({200})
    return _batch_expect(value, seq, s, either, 413, 409)


# --- the run: counts, problems, checks ---------------------------------------------------

@dataclass
class Tally:
    messages: int = 0
    ws: int = 0
    rest: int = 0
    knocks: int = 0
    results: int = 0
    errors: int = 0
    pongs: int = 0
    closes: int = 0
    accepted: int = 0  # packets
    rejected: Counter[str] = field(default_factory=Counter)  # packets, by reason
    crashes: int = 0
    http_5xx: int = 0
    problems: dict[str, tuple[int, str]] = field(default_factory=dict)  # kind: (count, example)
    lock: threading.Lock = field(default_factory=threading.Lock)

    def problem(self, kind: str, example: str) -> None:
        with self.lock:
            count, shortest = self.problems.get(kind, (0, example))
            if len(example) < len(shortest):
                shortest = example
            self.problems[kind] = (count + 1, shortest)

    def crash(self, kind: str, example: str) -> None:
        self.crashes += 1
        self.problem("crash: " + kind, example)

    def summary(self) -> str:
        return (f"ws fuzz: {self.messages} messages ({self.ws} WebSocket, {self.rest} REST, "
                f"{self.knocks} refused connections), {self.results} results, {self.errors} "
                f"errors, {self.pongs} pongs, {self.closes} documented closes; packets "
                f"{self.accepted} accepted, {self.rejected.total()} rejected; crashes "
                f"{self.crashes}, 5xx {self.http_5xx}, other problems "
                f"{sum(c for k, (c, _) in self.problems.items() if not k.startswith('crash'))}")

    def report(self) -> str:
        return "\n".join(f"{kind}: {count}x, e.g. {example[:600]}"
                         for kind, (count, example) in sorted(self.problems.items()))


def _counts_every_packet(reply: dict[str, Any], n: int) -> bool:
    """``accepted + len(rejected) == n``, each rejection at its own index in the batch."""
    rejected = [r["index"] for r in reply["rejected"]]
    return reply["accepted"] + len(rejected) == n and sorted(set(rejected)) == rejected \
        and all(0 <= i < n for i in rejected)


def _kinds(packets: list[Any]) -> list[Any]:
    return [p.get("kind") if isinstance(p, dict) else type(p).__name__ for p in packets]


def _canonical(value: Any) -> str:
    """JSON text to compare by, with a non-finite number as null (REST sends null for one,
    the WebSocket its token; a NaN is not even equal to itself). Non-finite numbers are
    reported on their own, by :meth:`Run.check_positions` and :meth:`Run.strict_json`."""
    return json.dumps(_finite(value), sort_keys=True)


def _finite(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, list):
        return [_finite(v) for v in value]
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    return value


def _bare(reply: dict[str, Any]) -> dict[str, Any]:
    """A batch's reply without what differs between REST and WebSocket and on a resend."""
    return {k: v for k, v in reply.items() if k not in ("type", "seq", "duplicate")}


def _show(payload: str | bytes, limit: int = 300) -> str:
    text = repr(payload)
    return text if len(text) <= limit else f"{text[:limit]}... ({len(payload)} chars)"


@dataclass
class Run:
    server: Server
    graph: RoadGraph
    sessions: list[Fuzzed]
    tally: Tally
    rest: httpx.Client
    connections: ExitStack = field(default_factory=ExitStack)

    def url(self, session_id: str) -> str:
        return f"{self.server.ws_url}/v1/sessions/{session_id}/stream"

    def ws(self, s: Fuzzed) -> ClientConnection:
        if s.ws is None:
            s.ws = self.connections.enter_context(connect(
                self.url(s.id), additional_headers={"X-API-Key": KEY}, max_size=None))
        return s.ws

    def drop(self, s: Fuzzed) -> None:
        if s.ws is not None:
            s.ws.close()
            s.ws = None

    def act(self, index: int, action: Send | Knock) -> None:
        self.tally.messages += 1
        if isinstance(action, Knock):
            self.knock(action)
            return
        s = self.sessions[index]
        s.sent_max_dt = 0.0
        if action.channel == "ws":
            self.send_ws(s, action.body)
        else:
            self.send_rest(s, action.body, action.query_seq)
        s.clock = round(s.clock + s.sent_max_dt + 0.01, 3)
        if self.server.process.poll() is not None:
            self.tally.crash("server died", _show(repr(action)))
            raise RuntimeError(f"the server died: {self.server.log.read_text()[-3000:]}")

    def knock(self, knock: Knock) -> None:
        self.tally.knocks += 1
        sid = uuid.uuid4().hex[:16] if knock.how == "unknown" else self.sessions[0].id
        headers = {"wrong_key": {"X-API-Key": "not-" + KEY}, "no_key": {},
                   "other_owner": {"X-API-Key": OTHER_KEY}, "unknown": {"X-API-Key": KEY}}
        code = {"wrong_key": 4401, "no_key": 4401, "other_owner": 4404, "unknown": 4404}
        try:
            with connect(self.url(sid), additional_headers=headers[knock.how]) as ws:
                ws.send('{"type":"ping"}')
                reply = ws.recv(timeout=REPLY_TIMEOUT_S)
            self.tally.problem("a refused connection was served", f"{knock}: {reply!r}")
        except ConnectionClosed as closed:
            got = None if closed.rcvd is None else closed.rcvd.code
            if got == code[knock.how]:
                self.tally.closes += 1
            else:
                self.tally.crash("refused with an undocumented close", f"{knock}: {got}")

    def send_ws(self, s: Fuzzed, body: Any) -> None:
        self.tally.ws += 1
        frame: str | bytes = body if isinstance(body, bytes) else _render(body, s)
        expect = _ws_expect(frame, s)
        try:
            ws = self.ws(s)
            ws.send(frame)
            text = ws.recv(timeout=REPLY_TIMEOUT_S)
        except ConnectionClosed as closed:
            got = None if closed.rcvd is None else closed.rcvd.code
            self.tally.crash(f"socket closed ({got})", _show(frame))
            self.drop(s)
            return
        except TimeoutError:
            self.tally.problem("no reply within the timeout", _show(frame))
            self.drop(s)
            return
        reply = self.strict_json(text, frame)
        kind = reply.get("type")
        self.tally.results += kind == "result"
        self.tally.errors += kind == "error"
        self.tally.pongs += kind == "pong"
        if kind == "error" and reply.get("code") == "internal":
            self.tally.crash("internal error reply", _show(frame))
        elif kind not in expect.allowed:
            self.tally.problem(f"{kind} where the protocol says {sorted(expect.allowed)}",
                               f"{_show(frame)} -> {_show(json.dumps(reply))}")
        elif kind == "result":
            self.check_result(s, expect, reply, _show(frame))

    def strict_json(self, text: str | bytes, frame: str | bytes) -> dict[str, Any]:
        """The reply, which must be JSON as RFC 8259 has it (no NaN or Infinity tokens, which
        a browser's JSON.parse refuses)."""
        tokens: list[str] = []

        def constant(token: str) -> float:
            tokens.append(token)
            return float(token)

        reply: dict[str, Any] = json.loads(text, parse_constant=constant)
        if tokens:
            self.tally.problem("a reply that is not JSON (NaN or Infinity tokens)",
                               f"{_show(frame)} -> {sorted(set(tokens))}")
        return reply

    def send_rest(self, s: Fuzzed, body: Any, query_seq: Any) -> None:
        self.tally.rest += 1
        content: str | bytes = body if isinstance(body, bytes) else _render(body, s)
        query = None if query_seq is None else \
            str(s.seq(query_seq.how)) if isinstance(query_seq, Seq) else str(query_seq)
        expect = _rest_expect(content, query, s)
        r = self.rest.post(f"/sessions/{s.id}/packets", content=content,
                           params={} if query is None else {"batch_seq": query},
                           headers={"content-type": "application/json"})
        shown = f"POST ?batch_seq={query} {_show(content)} -> {r.status_code} {r.text[:300]}"
        if r.status_code >= 500:
            self.tally.http_5xx += 1
            self.tally.problem(f"REST {r.status_code}", shown)
        elif r.status_code not in expect.allowed:
            self.tally.problem(f"REST {r.status_code} where {sorted(expect.allowed)}", shown)
        elif r.status_code == 200:
            self.tally.results += 1
            self.check_result(s, expect, r.json(), shown)
        else:
            self.tally.errors += 1

    def check_result(self, s: Fuzzed, expect: Expect, reply: dict[str, Any], shown: str
                     ) -> None:
        """A result's counts, positions and batch number; then the offline replay."""
        packets = expect.packets or []
        rejected = [r["index"] for r in reply["rejected"]]
        if not expect.resend and not _counts_every_packet(reply, len(packets)):
            self.tally.problem("accepted + len(rejected) != packets sent",
                               f"{shown} -> accepted {reply['accepted']}, rejected at "
                               f"{rejected}, of {len(packets)}; kinds {_kinds(packets)}")
        if any(r["code"] == "unusable" for r in reply["rejected"]):
            self.tally.crash("a packet the pipeline failed on (unusable)", shown)
        self.check_positions(reply["positions"], shown)
        if expect.seq is not None and reply.get("seq", expect.seq) != expect.seq:
            self.tally.problem("result for another seq", shown)
        first = _bare(reply)
        if expect.resend:
            if reply.get("duplicate") is not True:
                self.tally.problem("a resent batch number applied again", shown)
            elif expect.seq in s.first_replies and \
                    _canonical(first) != _canonical(s.first_replies[expect.seq]):
                self.tally.problem("a resend answered unlike the first time", shown)
            return
        if reply.get("duplicate"):
            self.tally.problem("a new batch answered as a duplicate", shown)
        if expect.seq is not None:
            s.last_seq = expect.seq
            s.first_replies[expect.seq] = first
        s.accepted += reply["accepted"]
        s.rejected += len(rejected)
        self.tally.accepted += reply["accepted"]
        self.tally.rejected.update(r["code"] for r in reply["rejected"])
        self.replay(s, [p for i, p in enumerate(packets) if i not in set(rejected)], reply,
                    shown)

    def replay(self, s: Fuzzed, accepted: list[Any], reply: dict[str, Any], shown: str
               ) -> None:
        """Anything accepted is replayable: a fresh pipeline fed only the accepted packets
        accepts them all and gives the same positions."""
        again = s.replay.add_records(accepted)
        if again.accepted != reply["accepted"] or again.rejections:
            self.tally.problem("accepted packets refused on replay",
                               f"{shown}; replay: {[r.to_json() for r in again.rejections]}")
        positions = [position_json(p, self.graph.frame) for p in again.positions]
        if _canonical(positions) != _canonical(reply["positions"]):
            self.tally.problem("positions differ from a replay of the accepted packets", shown)

    def check_positions(self, positions: list[dict[str, Any]], shown: str) -> None:
        for p in positions:
            bad = [k for k in POSITION_NUMBERS if not isinstance(p.get(k), (int, float))
                   or not math.isfinite(p[k])]
            if p.get("state") == "initializing":
                bad = [k for k in bad if not (k in UNKNOWN_BEFORE_START_UP and p[k] is None)]
            if bad:
                self.tally.problem("a position with non-finite numbers",
                                   f"{shown} -> {', '.join(f'{k}={p.get(k)}' for k in bad)}")
                return

    def end_example(self) -> None:
        """Exactly one reply each: a ping now is answered by the very next frame."""
        for s in self.sessions:
            if s.ws is None:
                continue
            try:
                s.ws.send('{"type":"ping"}')
                reply = json.loads(s.ws.recv(timeout=REPLY_TIMEOUT_S))
            except (ConnectionClosed, TimeoutError) as exc:
                self.tally.crash("the closing ping got no pong", repr(exc))
                self.drop(s)
                continue
            if reply != {"type": "pong"}:
                self.tally.problem("an extra reply", _show(json.dumps(reply)))
                self.drop(s)


# --- the bystander -----------------------------------------------------------------------

def _bystander(server: Server, session_id: str, batches: list[list[dict[str, Any]]],
               expected: list[list[dict[str, Any]]], tally: Tally, done: list[int]) -> None:
    """Stream a clean drive and check every reply against the offline run."""
    url = f"{server.ws_url}/v1/sessions/{session_id}/stream"
    try:
        with connect(url, additional_headers={"X-API-Key": KEY}, max_size=None) as ws:
            for batch, positions in zip(batches, expected, strict=True):
                ws.send(json.dumps(batch))
                reply = json.loads(ws.recv(timeout=REPLY_TIMEOUT_S))
                if reply != {"type": "result", "accepted": len(batch), "rejected": [],
                             "positions": positions}:
                    tally.problem("bystander: a reply differs from the offline run",
                                  f"batch at t={batch[0]['t']}: {json.dumps(reply)[:300]}")
                done[0] += len(batch)
                time.sleep(0.05)  # spread over the fuzzing
    except (ConnectionClosed, TimeoutError, OSError) as exc:
        tally.crash("bystander lost its connection", repr(exc))


# --- the test ----------------------------------------------------------------------------

@pytest.fixture()
def server(db: Path, tmp_path: Path) -> Iterator[Server]:
    s = start_server(db, tmp_path / "server.log", env=ENV)
    yield s
    s.stop()


def _snapshot(server: Server, ids: list[str]) -> dict[str, Any]:
    client = server.client(headers={"X-API-Key": KEY})
    infos = {sid: client.get(f"/sessions/{sid}").json() for sid in ids}
    return {sid: (i["packets_accepted"], i["packets_rejected"], _canonical(i["position"]))
            for sid, i in infos.items()}


def _restore_problems(before: dict[str, Any], after: dict[str, Any], how: str) -> list[str]:
    return [f"{how}: session {sid} was {before[sid][:2]} at {before[sid][2][:300]}, restored "
            f"as {after[sid][:2]} at {after[sid][2][:300]}"
            for sid in before if after[sid] != before[sid]]


def test_fuzzed_sessions_are_served_and_restored(
        server: Server, db: Path, tmp_path: Path, sample_graph: RoadGraph) -> None:
    tally = Tally()
    rest = server.client(headers={"X-API-Key": KEY})
    sessions = []
    for options in [*FUZZED_OPTIONS, {"sensors": "gps_only"}]:  # the last: WITNESS
        r = rest.post("/sessions", json={"vehicle_id": "fuzzed", **options})
        assert r.status_code == 201, r.text
        info = r.json()
        sessions.append(Fuzzed(info["id"], info["options"], VehicleSession(
            config_from_options(info["options"]), sample_graph)))
    run = Run(server, sample_graph, sessions, tally, rest)

    kinds = set(SENSOR_KINDS["gyro_odometer"])
    drive = [r for r in simulate_drive(sample_graph, DriveSpec(duration_s=60.0, seed=1))
             if r["kind"] in kinds]
    batches = [drive[i:i + BYSTANDER_BATCH] for i in range(0, len(drive), BYSTANDER_BATCH)]
    offline = VehicleSession(SessionConfig(), sample_graph)
    expected = [[position_json(p, sample_graph.frame) for p in offline.add_records(b).positions]
                for b in batches]
    bystander = rest.post("/sessions", json={"vehicle_id": "bystander"}).json()["id"]
    streamed = [0]
    thread = threading.Thread(target=_bystander, args=(
        server, bystander, batches, expected, tally, streamed), daemon=True)
    thread.start()

    # no example database: what a message does depends on the server's state, so a saved
    # example would not mean the same in the next run
    @given(actions=ACTIONS)
    @example(actions=ISSUE_MESSAGES)
    @example(actions=NMEA_SPEED)
    @example(actions=TRUTH)
    @settings(max_examples=EXAMPLES, deadline=None, suppress_health_check=list(HealthCheck),
              database=None)
    def fuzz(actions: list[Action]) -> None:
        for index, action in actions:
            run.act(index, action)
        run.end_example()

    try:
        fuzz()
        while_fuzzing = streamed[0]
    finally:
        thread.join(timeout=120)
        run.connections.close()
    if streamed[0] != len(drive):
        tally.problem("bystander did not finish", f"{streamed[0]} of {len(drive)} packets")

    ids = [s.id for s in sessions] + [bystander]
    before = _snapshot(server, ids)
    for s in sessions:  # the server's counts and position are those of the replay
        position = None if s.replay.last_position is None else \
            position_json(s.replay.last_position, sample_graph.frame)
        if before[s.id] != (s.accepted, s.rejected, _canonical(position)):
            tally.problem("session differs from its replay", f"{s.options}: server "
                          f"{before[s.id][:2]} at {before[s.id][2][:300]}, replay "
                          f"{(s.accepted, s.rejected)} at {_canonical(position)[:300]}")
    server.kill()
    mismatches = 0
    for how in ("SIGKILL", "a graceful stop"):  # the second from checkpoints saved at shutdown
        again = start_server(db, tmp_path / "server.log", env=ENV)
        try:
            for line in _restore_problems(before, _snapshot(again, ids), f"after {how}"):
                tally.problem(f"restore after {how} differs", line)
                mismatches += 1
        finally:
            again.stop()
    tracebacks = server.log.read_text().count("Traceback")

    print("\n" + tally.summary() + f"; bystander {streamed[0]} packets ({while_fuzzing} while "
          f"fuzzing); {len(ids)} sessions restored twice, {mismatches} mismatches; {tracebacks} "
          "tracebacks in the server log")
    crashes, http_5xx, report = tally.crashes, tally.http_5xx, tally.report()
    assert (crashes, http_5xx) == (0, 0), report
    assert not report, report

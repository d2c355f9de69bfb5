"""The WebSocket's fast path through a real server: a message of valid packets (an array, or a
numbered batch) is taken whole and its own text is what the trip log holds; a message with a
bad packet goes the careful way (its reasons, the accepted packets logged as validated)."""

from __future__ import annotations

import json
import sqlite3

from websockets.sync.client import connect

from tests.api.server import Server

PACKETS = [{"t": 0.0, "kind": "gps", "lat": 43.7384, "lon": 7.4246, "speed_mps": 8.0,
            "heading_deg": 60.0, "hdop": 0.9},
           {"t": 0.01, "kind": "imu", "yaw_rate_dps": 0.4, "accel_fwd_mps2": 0.1},
           {"t": 0.02, "kind": "odometer", "distance_m": 0.16}]


def logged(server: Server, session_id: str) -> list[str]:
    with sqlite3.connect(server.log.with_name("monaco.trips.db")) as db:
        rows = db.execute("SELECT records FROM batches WHERE session_id = ? ORDER BY rowid",
                          (session_id,)).fetchall()
    return [row[0] for row in rows]


def test_valid_messages_are_logged_as_sent_and_a_bad_one_the_careful_way(
        server: Server) -> None:
    session = server.client().post("/sessions", json={"vehicle_id": "fast"}).json()
    array = json.dumps(PACKETS[:2], indent=1)  # whitespace a re-encoding would not keep
    later = [{**p, "t": p["t"] + 1.0} for p in PACKETS]
    packets_text = json.dumps(later, separators=(" ,", " : "))
    with connect(f"{server.ws_url}/v1/sessions/{session['id']}/stream") as ws:
        ws.send(array)
        reply = json.loads(ws.recv(timeout=30))
        assert reply["type"] == "result" and reply["accepted"] == 2 and "seq" not in reply
        ws.send(f'{{"type": "batch", "seq": 4, "packets": {packets_text}}}')
        reply = json.loads(ws.recv(timeout=30))
        assert (reply["seq"], reply["accepted"], reply["rejected"]) == (4, 3, [])
        bad = [{**PACKETS[2], "t": 3.0}, {"t": 3.01, "kind": "imu"},
               {"t": 3.02, "kind": "imu", "yaw_rate_dps": 0.1, "note": "dropped"}]
        ws.send(json.dumps({"type": "batch", "seq": 5, "packets": bad}))
        reply = json.loads(ws.recv(timeout=30))
    assert reply["accepted"] == 2
    assert [(r["index"], r["code"]) for r in reply["rejected"]] == [(1, "missing_field")]
    assert logged(server, session["id"]) == [
        array, packets_text, json.dumps([bad[0], {k: v for k, v in bad[2].items()
                                                  if k != "note"}], separators=(",", ":"))]

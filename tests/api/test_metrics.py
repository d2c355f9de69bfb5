"""What a fleet operator sees at /v1/metrics, per worker: each metric is there and moves
when the worker works (a real server on 127.0.0.1)."""

from __future__ import annotations

import time

from prometheus_client.parser import text_string_to_metric_families

from navsvc.metrics import LOOP_LAG_PERIOD_S
from navsvc.sim.simulate import SENSOR_KINDS, DriveSpec, simulate_drive
from roadgraph import RoadGraph
from tests.api.server import Server


def scrape(server: Server) -> dict[tuple[str, tuple[tuple[str, str], ...]], float]:
    text = server.client().get("/metrics").text
    return {(s.name, tuple(sorted(s.labels.items()))): s.value
            for family in text_string_to_metric_families(text) for s in family.samples}


def value(samples: dict, name: str, **labels: str) -> float:
    return samples.get((name, tuple(sorted(labels.items()))), 0.0)


def test_every_operator_metric_is_there_and_moves(server: Server,
                                                  sample_graph: RoadGraph) -> None:
    drive = simulate_drive(sample_graph, DriveSpec(duration_s=20.0, seed=2))
    kinds = set(SENSOR_KINDS["gyro_odometer"])
    packets = [r for r in drive if r["kind"] in kinds][:150]  # under a checkpoint's 200
    client = server.client()
    before = scrape(server)
    sid = client.post("/sessions", json={"vehicle_id": "metrics"}).json()["id"]
    reply = client.post(f"/sessions/{sid}/packets",
                        json=packets + [{"t": 1.0, "kind": "imu"}, {"kind": "gps"}]).json()
    assert reply["accepted"] == len(packets) and len(reply["rejected"]) == 2
    time.sleep(3 * LOOP_LAG_PERIOD_S + 0.2)
    after = scrape(server)

    def moved(name: str, **labels: str) -> float:
        return value(after, name, **labels) - value(before, name, **labels)

    assert moved("navsvc_packets_accepted_total") == len(packets)
    rejected = {dict(k[1])["reason"]: v - value(before, k[0], **dict(k[1]))
                for k, v in after.items() if k[0] == "navsvc_packets_rejected_total"}
    assert sum(rejected.values()) == 2 and "missing_field" in rejected
    assert moved("navsvc_sessions") == 1
    assert moved("navsvc_batch_seconds_count") == 1 and moved("navsvc_batch_seconds_sum") > 0
    assert moved("navsvc_triplog_append_seconds_count") == 1
    assert moved("navsvc_triplog_append_seconds_sum") > 0
    assert value(after, "navsvc_triplog_bytes", file="database") > 0
    assert value(after, "navsvc_triplog_bytes", file="wal") > 0
    # the batch reaches the database file at the next WAL checkpoint (each second)
    deadline = time.monotonic() + 20.0
    while value(scrape(server), "navsvc_triplog_bytes", file="database") <= \
            value(before, "navsvc_triplog_bytes", file="database"):
        assert time.monotonic() < deadline, "the trip log's database did not grow"
        time.sleep(0.2)
    assert moved("navsvc_checkpoint_lag_packets") == len(packets) + 2
    assert value(after, "navsvc_checkpoint_lag_seconds") > 0  # and ages until one is saved
    assert moved("navsvc_event_loop_lag_seconds_count") >= 2
    assert value(after, "navsvc_event_loop_lag_seconds_sum") >= 0
    client.delete(f"/sessions/{sid}")  # an ended session is no longer open, nor behind
    ended = scrape(server)
    assert value(ended, "navsvc_sessions") == value(before, "navsvc_sessions")
    assert value(ended, "navsvc_checkpoint_lag_packets") == \
        value(before, "navsvc_checkpoint_lag_packets")

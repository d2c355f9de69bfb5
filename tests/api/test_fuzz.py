"""The API fuzzed from its own OpenAPI schema (schemathesis): no request makes a 5xx."""

from __future__ import annotations

import schemathesis
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from schemathesis.checks import not_a_server_error

from tests.api.server import Server

EXAMPLES_PER_OPERATION = 40


def test_no_server_errors(server: Server) -> None:
    schema = schemathesis.openapi.from_url(server.url + "/openapi.json")
    operations = [result.ok() for result in schema.get_all_operations()]
    assert len(operations) >= 12
    for operation in operations:

        @given(case=operation.as_strategy())
        @settings(max_examples=EXAMPLES_PER_OPERATION, deadline=None,
                  suppress_health_check=list(HealthCheck))
        def check(case: schemathesis.Case) -> None:
            case.call_and_validate(checks=[not_a_server_error])

        check()


JSON = st.recursive(
    st.none() | st.booleans() | st.floats(allow_nan=False, allow_infinity=False) | st.integers()
    | st.text(max_size=8),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner,
                                                                 max_size=4),
    max_leaves=12)
PACKET = st.fixed_dictionaries(
    {"t": st.floats(-1e3, 1e6) | st.text(max_size=3),
     "kind": st.sampled_from(["gps", "imu", "odometer", "steering", "nmea", "oncore", "x"])},
    optional={"lat": st.floats(-100, 100), "lon": st.floats(-200, 200),
              "yaw_rate_dps": st.floats(-1e6, 1e6) | st.text(max_size=3),
              "speed_mps": st.floats(-5, 150), "distance_m": st.floats(-1, 1e4),
              "angle_deg": st.floats(-90, 90), "sentence": st.text(max_size=40),
              "hex": st.text("0123456789abcdef@B", max_size=40)})


def test_random_packets_to_a_real_session_never_fail_the_server(server: Server) -> None:
    client = server.client()
    sid = client.post("/sessions", json={"vehicle_id": "fuzz", "sensors": "gyro_odometer"}
                      ).json()["id"]

    @given(batch=st.lists(PACKET | JSON, max_size=20))
    @settings(max_examples=150, deadline=None, suppress_health_check=list(HealthCheck))
    def post(batch: list[object]) -> None:
        r = client.post(f"/sessions/{sid}/packets", json=batch)
        assert r.status_code == 200, r.text
        body = r.json()
        assert body["accepted"] + len(body["rejected"]) == len(batch)

    post()
    assert client.get("/healthz").json()["status"] == "ok"

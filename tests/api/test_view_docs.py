"""The documentation the server carries: the OpenAPI document (packets as a typed union by
kind, an example on every operation, the WebSockets described) and /docs, /redoc offline."""

from __future__ import annotations

import re
from typing import Any

import httpx
import pytest

from navsvc.api.openapi import EXAMPLES
from navsvc.wire.packets import MODELS
from tests.api.server import Server


@pytest.fixture(scope="module")
def schema(server: Server) -> dict[str, Any]:
    document: dict[str, Any] = httpx.get(server.url + "/openapi.json", timeout=10.0).json()
    return document


def test_packets_are_a_union_discriminated_by_kind(schema: dict[str, Any]) -> None:
    body = schema["paths"]["/v1/sessions/{session_id}/packets"]["post"]["requestBody"]
    array = body["content"]["application/json"]["schema"]
    assert array["type"] == "array" and array["maxItems"] == 1000
    items = array["items"]
    assert items["discriminator"]["propertyName"] == "kind"
    assert set(items["discriminator"]["mapping"]) == set(MODELS)
    for kind, model in MODELS.items():
        component = schema["components"]["schemas"][model.__name__]
        assert component["properties"]["kind"]["const"] == kind
        assert component["required"][:2] == ["t", "kind"]
        assert all("description" in p for p in component["properties"].values()), kind
    gps = schema["components"]["schemas"]["GpsPacket"]
    assert gps["required"] == ["t", "kind", "lat", "lon"]
    assert gps["properties"]["lat"]["maximum"] == 90.0


def test_every_operation_has_examples(schema: dict[str, Any]) -> None:
    for path, operations in schema["paths"].items():
        for method, operation in operations.items():
            if "requestBody" in operation:
                media = operation["requestBody"]["content"]["application/json"]
                assert "example" in media or "examples" in media, (method, path)
            answers = [answer for status, answer in operation["responses"].items()
                       if status.startswith("2") and status != "204"]
            for answer in answers:
                assert any("example" in media or "examples" in media
                           for media in answer.get("content", {}).values()), (method, path)
            for status, answer in operation["responses"].items():
                if status[0] == "4":
                    media = answer["content"]["application/json"]
                    assert media["schema"] == {"$ref": "#/components/schemas/ErrorBody"}
                    assert media["example"]["error"]["code"], (method, path, status)


def test_positions_are_typed(schema: dict[str, Any]) -> None:
    components = schema["components"]["schemas"]
    assert components["BatchReply"]["properties"]["positions"]["items"] == {
        "$ref": "#/components/schemas/MatchedPosition"}
    position = components["MatchedPosition"]
    assert position["properties"]["state"]["enum"] == [
        "initializing", "on_road", "ambiguous", "off_road", "lost"]
    assert {"candidates", "gps", "edge", "fused_lat"} <= set(position["properties"])


def test_the_websockets_and_close_codes_are_described(schema: dict[str, Any]) -> None:
    text = schema["info"]["description"]
    for needle in ("/v1/sessions/{session_id}/stream", "/v1/sessions/{session_id}/view",
                   "4401", "4404", '"dropped": n', '{"type": "batch", "seq": N',
                   "docs/interfaces.md"):
        assert needle in text


def test_the_documented_batch_example_is_what_the_server_answers(server: Server) -> None:
    client = server.client()
    sid = client.post("/sessions", json=EXAMPLES[("post", "/v1/sessions")][0]).json()["id"]
    request, responses = EXAMPLES[("post", "/v1/sessions/{session_id}/packets")]
    reply = client.post(f"/sessions/{sid}/packets", json=request).json()
    documented = responses["200"]
    assert reply["accepted"] == documented["accepted"]
    assert reply["rejected"] == documented["rejected"]


def test_the_documented_match_example_is_what_the_server_answers(server: Server) -> None:
    request, responses = EXAMPLES[("post", "/v1/match")]
    route = server.client().post("/match", json=request).json()
    documented = responses["200"]
    assert route["points_in"] == documented["points_in"]
    assert route["segments"][0]["streets"] == documented["segments"][0]["streets"]


@pytest.mark.parametrize("path", ["/docs", "/redoc"])
def test_docs_pages_load_their_files_from_this_server(server: Server, path: str) -> None:
    page = httpx.get(server.url + path, timeout=10.0)
    assert page.status_code == 200
    assert "cdn" not in page.text.lower() and "fonts.googleapis" not in page.text
    assets = re.findall(r"""(?:src|href)=["']([^"']+)["']""", page.text)
    assets += re.findall(r"""url: ?['"]([^'"]+)['"]""", page.text)
    assert assets and all(a.startswith("/") for a in assets), assets
    for asset in assets:
        assert httpx.get(server.url + asset, timeout=10.0).status_code == 200, asset


def test_the_readme_client_example_runs(server: Server, tmp_path: Any) -> None:
    """The README's "Sending your vehicle's data" example, run against a real server."""
    import subprocess
    import sys
    from pathlib import Path

    readme = (Path(__file__).resolve().parents[2] / "README.md").read_text()
    section = readme[readme.index("## Sending your vehicle's data"):]
    code = section[section.index("```python") + len("```python"):section.index("```\n", 10)]
    host = server.url.removeprefix("http://")
    code = code.replace("127.0.0.1:8000", host)
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=60)
    assert done.returncode == 0, done.stderr
    lines = [line.split() for line in done.stdout.splitlines()]
    assert lines and float(lines[0][0]) == 0.0
    for _t, state, lat, lon in lines:
        assert state in ("initializing", "on_road", "ambiguous")
        assert abs(float(lat) - 43.7398) < 1e-3 and abs(float(lon) - 7.4218) < 1e-3

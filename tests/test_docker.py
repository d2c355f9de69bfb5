"""The Dockerfile and compose file keep what issue 18 asked of them (no Docker daemon is
needed: the files are read): dependencies installed in a layer before the source is copied,
the kernels compiled at build time by the image's user into a cache in the image, the map id
the map's name, the health check on /v1/healthz, compose building the image once."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def _instructions() -> list[tuple[str, str]]:
    text = (ROOT / "Dockerfile").read_text().replace("\\\n", " ")
    lines = [line.strip() for line in text.splitlines()]
    return [(line.split()[0].upper(), line.split(None, 1)[1] if " " in line else "")
            for line in lines if line and not line.startswith("#")]


def _index(steps: list[tuple[str, str]], op: str, pattern: str) -> int:
    return next(i for i, (o, arg) in enumerate(steps) if o == op and re.search(pattern, arg))


def test_dependencies_are_a_layer_before_the_source() -> None:
    steps = _instructions()
    deps = _index(steps, "RUN", r"pip install -r")
    assert _index(steps, "COPY", r"^pyproject\.toml") < deps < _index(steps, "COPY", r"^navsvc")
    assert _index(steps, "RUN", r"pip install --no-deps \.") > _index(steps, "COPY", r"^navsvc")


def test_the_kernels_are_compiled_at_build_time_by_the_runtime_user() -> None:
    steps = _instructions()
    env = " ".join(arg for op, arg in steps if op == "ENV")
    assert re.search(r"NUMBA_CACHE_DIR=/opt/navsvc-cache/numba", env)
    warm = _index(steps, "RUN", r"navsvc serve .*--warm-up-only")
    assert _index(steps, "USER", r"^navsvc$") < warm


def test_the_map_id_is_the_maps_name_and_the_health_check_asks_the_server() -> None:
    steps = _instructions()
    env = " ".join(arg for op, arg in steps if op == "ENV")
    assert "NAVSVC_MAP=/data/monaco.db" in env
    assert re.search(r"roadgraph import maps/monaco\.osm\.gz -o /data/monaco\.db",
                     steps[_index(steps, "RUN", r"roadgraph import")][1])
    health = steps[_index(steps, "HEALTHCHECK", r"CMD")][1]
    assert "/v1/healthz" in health and "--start-period=30s" in health


def test_compose_builds_the_image_once() -> None:
    text = (ROOT / "docker-compose.yml").read_text()
    assert text.count("build: .") == 1
    assert text.count("image: navsvc:local") == 3  # import, the workers, the balancer
    assert "NAVSVC_MAP: /data/${MAP_NAME:-monaco}.db" in text


def test_compose_puts_the_balancer_in_front_of_workers_with_their_own_ids() -> None:
    """Each worker service has its id (the prefix of its session ids), and the balancer
    serves the generated config (tests/api/test_cluster_config.py checks it is current)."""
    import yaml  # PyYAML: dask of the test extras requires it

    services = yaml.safe_load((ROOT / "docker-compose.yml").read_text())["services"]
    workers = {name: s for name, s in services.items() if name.startswith("worker")}
    assert {s["environment"]["NAVSVC_WORKER_ID"] for s in workers.values()} == \
        {name.removeprefix("worker") for name in workers}
    peers = next(iter(workers.values()))["environment"]["NAVSVC_PEERS"].split(",")
    assert peers == [f"http://{name}:8000" for name in sorted(workers)]
    balancer = services["balancer"]
    assert balancer["command"] == ["haproxy", "-db", "-f", "/app/deploy/haproxy-compose.cfg"]
    assert "ports" in balancer and all("ports" not in s for s in workers.values())
    assert "COPY deploy deploy" in (ROOT / "Dockerfile").read_text()


"""The balancer's generated config, the worker settings and the fleet's merged metrics,
without processes: HAProxy itself checks the config when it is installed."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from prometheus_client.parser import text_string_to_metric_families

from navsvc.api.settings import Settings
from navsvc.cluster import (
    Backend,
    ClusterPlan,
    find_haproxy,
    haproxy_config,
    main,
    restart_delay_s,
)
from navsvc.errors import ConfigError
from navsvc.metrics import Metrics, merge_expositions

ROOT = Path(__file__).resolve().parents[2]
TWO = [Backend(0, "127.0.0.1", 8001), Backend(1, "10.0.0.7", 9000)]


def test_config_routes_each_workers_ids_to_it_and_the_rest_to_any() -> None:
    text = haproxy_config(TWO, "*:8000", maxconn=500)
    assert "    bind *:8000" in text and "    maxconn 500" in text
    assert "use_backend worker0 if { path_beg /v1/sessions/w0- }" in text
    assert "use_backend worker1 if { path_beg /v1/sessions/w1- }" in text
    assert "backend worker1\n    server w1 10.0.0.7:9000\n" in text
    assert "default_backend any_worker" in text
    assert re.search(r"backend any_worker\n    balance roundrobin\n    option httpchk GET "
                     r"/v1/healthz\n.*\n    server w0 127\.0\.0\.1:8001 check", text)
    assert "timeout tunnel 1h" in text  # WebSockets outlive the HTTP timeouts
    assert '"code":"unavailable"' in text  # the API's error shape while a worker is down


def test_haproxy_accepts_the_config(tmp_path: Path) -> None:
    try:
        haproxy = find_haproxy()
    except ConfigError:
        pytest.skip("no HAProxy installed (apt-get install haproxy; make test does it as root)")
    config = tmp_path / "haproxy.cfg"
    config.write_text(haproxy_config(TWO, "127.0.0.1:8000"))
    checked = subprocess.run([haproxy, "-c", "-f", str(config)], capture_output=True, text=True)
    assert checked.returncode == 0, checked.stderr


def test_impossible_plans_are_refused() -> None:
    with pytest.raises(ConfigError, match="at least one worker"):
        haproxy_config([], "*:8000")
    with pytest.raises(ConfigError, match=r"worker ids repeat: \[0, 0\]"):
        haproxy_config([TWO[0], TWO[0]], "*:8000")
    with pytest.raises(ConfigError, match="include the balancer's port 8000"):
        ClusterPlan.local("127.0.0.1", 8000, 4, Path("t.db"), worker_port_base=7998)
    plan = ClusterPlan.local("0.0.0.0", 8000, 2, Path("t.db"))
    assert [b.port for b in plan.workers] == [8001, 8002]
    assert plan.peers() == "http://127.0.0.1:8001,http://127.0.0.1:8002"


def test_the_picows_streams_go_to_their_workers_stream_ports(
        capsys: pytest.CaptureFixture[str]) -> None:
    workers = [Backend(0, "127.0.0.1", 8001, 8003), Backend(1, "10.0.0.7", 9000, 9100)]
    text = haproxy_config(workers, "*:8000", stream_bind="*:8100")
    stream = text[text.index("frontend navsvc_stream"):]
    assert "    bind *:8100" in stream
    assert "use_backend stream1 if { path_beg /v1/sessions/w1- }" in stream
    assert "backend stream1\n    server w1 10.0.0.7:9100\n" in stream
    assert "default_backend not_a_stream" in stream and "return status 404" in stream
    assert text.startswith(haproxy_config(workers, "*:8000"))  # the rest unchanged
    with pytest.raises(ConfigError, match=r"a stream port is needed for every worker; "
                                          r"workers \[0, 1\] have none"):
        haproxy_config(TWO, "*:8000", stream_bind="*:8100")
    plan = ClusterPlan.local("0.0.0.0", 8000, 2, Path("t.db"), stream_port=8100)
    assert [(b.port, b.stream_port) for b in plan.workers] == [(8001, 8003), (8002, 8004)]
    with pytest.raises(ConfigError, match="include the balancer's stream port 8003"):
        ClusterPlan.local("0.0.0.0", 8000, 2, Path("t.db"), stream_port=8003)
    assert main(["haproxy-config", "--bind", "*:8000", "--stream-bind", "*:8100",
                 "--worker", "0=127.0.0.1:8001/8003", "--worker", "1=10.0.0.7:9000/9100"]) == 0
    assert capsys.readouterr().out == haproxy_config(workers, "*:8000", stream_bind="*:8100")


def test_haproxy_accepts_the_config_with_streams(tmp_path: Path) -> None:
    try:
        haproxy = find_haproxy()
    except ConfigError:
        pytest.skip("no HAProxy installed (apt-get install haproxy; make test does it as root)")
    config = tmp_path / "haproxy.cfg"
    config.write_text(haproxy_config([Backend(0, "127.0.0.1", 8001, 8002)], "127.0.0.1:8000",
                                     stream_bind="127.0.0.1:8100"))
    checked = subprocess.run([haproxy, "-c", "-f", str(config)], capture_output=True, text=True)
    assert checked.returncode == 0, checked.stderr


def test_config_command_prints_it_for_workers_anywhere(capsys: pytest.CaptureFixture[str]
                                                       ) -> None:
    assert main(["haproxy-config", "--bind", "*:80", "--worker", "0=127.0.0.1:8001",
                 "--worker", "1=10.0.0.7:9000"]) == 0
    assert capsys.readouterr().out == haproxy_config(TWO, "*:80")
    with pytest.raises(SystemExit):
        main(["haproxy-config", "--worker", "nohost"])
    assert "expected ID=HOST:PORT" in capsys.readouterr().err


def test_compose_balancer_config_is_the_generated_one() -> None:
    """deploy/haproxy-compose.cfg (docker-compose.yml's balancer) is what the generator
    writes for the compose file's workers."""
    expected = haproxy_config([Backend(0, "worker0", 8000), Backend(1, "worker1", 8000)],
                              "*:8000", nameserver="127.0.0.11:53")
    assert (ROOT / "deploy" / "haproxy-compose.cfg").read_text() == expected


def test_a_worker_has_its_own_ids_and_trip_log(tmp_path: Path) -> None:
    alone = Settings(map_path=tmp_path / "city.db")
    assert alone.session_prefix == "" and alone.triplog == tmp_path / "city.trips.db"
    worker = Settings.from_env({"NAVSVC_MAP": str(tmp_path / "city.db"),
                                "NAVSVC_WORKER_ID": "1",
                                "NAVSVC_PEERS": "http://a:1, http://b:2/"})
    assert worker.session_prefix == "w1-" and worker.peers == ("http://a:1", "http://b:2")
    assert worker.triplog == tmp_path / "city.trips.db.w1"
    with pytest.raises(ConfigError, match="lists 2 workers, so this one needs a worker id "
                                          "below 2"):
        Settings(map_path=tmp_path / "city.db", worker_id=2, peers=("http://a", "http://b"))
    with pytest.raises(ConfigError, match="worker_id must be >= 0"):
        Settings(map_path=tmp_path / "city.db", worker_id=-1)
    with pytest.raises(ConfigError, match="NAVSVC_WORKER_ID='x' is not a valid number"):
        Settings.from_env({"NAVSVC_MAP": "m.db", "NAVSVC_WORKER_ID": "x"})


def test_merged_metrics_label_every_sample_with_its_worker() -> None:
    a, b = Metrics(), Metrics()
    a.packets_accepted.inc(3)
    b.packets_accepted.inc(5)
    b.packets_rejected.labels("out_of_range").inc()
    a.batch_seconds.observe(0.003)
    text = merge_expositions({"0": a.text().decode(), "1": b.text().decode()},
                             {"0": True, "1": True, "2": False}).decode()
    families = {f.name: f for f in text_string_to_metric_families(text)}
    accepted = {s.labels["worker"]: s.value for s in families["navsvc_packets_accepted"].samples
                if s.name.endswith("_total")}
    assert accepted == {"0": 3.0, "1": 5.0}
    assert 'navsvc_packets_rejected_total{reason="out_of_range",worker="1"} 1.0' in text
    assert 'navsvc_batch_seconds_bucket{le="0.005",worker="0"} 1.0' in text
    assert text.count("# TYPE navsvc_batch_seconds histogram") == 1
    assert {s.labels["worker"]: s.value for s in families["navsvc_worker_up"].samples} == \
        {"0": 1.0, "1": 1.0, "2": 0.0}


def test_serve_without_haproxy_says_how_to_get_it(tmp_path: Path) -> None:
    env = {**os.environ, "PATH": str(tmp_path)}  # no haproxy on it (nor /usr/sbin's, if any)
    done = subprocess.run(
        [sys.executable, "-c", "import navsvc.cluster as c; c.shutil.which = lambda n: None; "
         "c.os.access = lambda p, m: False; import sys; from navsvc.cli import main; "
         "sys.exit(main(['serve', '--map', 'x.db', '--workers', '2']))"],
        capture_output=True, text=True, env=env, cwd=ROOT)
    assert done.returncode == 1
    assert "needs HAProxy in front of the workers: install it (Debian: apt-get install " \
           "haproxy) or serve with --workers 1" in done.stderr


def test_workers_must_be_a_count() -> None:
    done = subprocess.run([sys.executable, "-m", "navsvc", "serve", "--workers", "0"],
                          capture_output=True, text=True, cwd=ROOT)
    assert done.returncode == 2 and "--workers: 0: must be from 1 to 64" in done.stderr


def test_a_child_that_keeps_dying_is_restarted_later_each_time() -> None:
    assert restart_delay_s(0) == 0.0  # it had run a while: again at once (a kill -9, say)
    assert [restart_delay_s(n) for n in range(1, 8)] == [0.0, 1.0, 2.0, 5.0, 10.0, 10.0, 10.0]


SUPERVISE = """
import sys, time
from navsvc.cluster import Child, Supervisor
marks = sys.argv[1]
child = Child("child", [sys.executable, "-c",
    "import os, sys, time; open(sys.argv[1], 'a').write(f'{os.getpid()}\\\\n'); "
    "time.sleep(float(sys.argv[2]))", marks, sys.argv[2]], {})
sys.exit(Supervisor([child]).run())
"""


def _started(marks: Path, count: int, timeout_s: float = 30.0) -> list[int]:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        pids = [int(p) for p in marks.read_text().split()] if marks.exists() else []
        if len(pids) >= count:
            return pids
        time.sleep(0.05)
    raise AssertionError(f"fewer than {count} starts: {marks.read_text()}")


def test_the_supervisor_restarts_a_child_that_exits_and_stops_it_on_sigterm(
        tmp_path: Path) -> None:
    marks = tmp_path / "starts"
    supervisor = subprocess.Popen([sys.executable, "-c", SUPERVISE, str(marks), "0.2"],
                                  cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)})
    try:
        pids = _started(marks, 3)  # it exits after 0.2 s; it is started again, and again
        assert len(set(pids)) == len(pids)
    finally:
        supervisor.send_signal(signal.SIGTERM)
        assert supervisor.wait(timeout=30) == 0


def test_children_end_when_the_supervisor_is_killed(tmp_path: Path) -> None:
    marks = tmp_path / "starts"
    supervisor = subprocess.Popen([sys.executable, "-c", SUPERVISE, str(marks), "60"],
                                  cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)})
    child = _started(marks, 1)[0]
    supervisor.kill()  # no shutdown code runs: the kernel ends the child (PR_SET_PDEATHSIG)
    supervisor.wait(timeout=10)
    deadline = time.monotonic() + 10.0
    while Path(f"/proc/{child}").exists() and "Z" not in _state(child):
        assert time.monotonic() < deadline, "the child outlived its supervisor"
        time.sleep(0.05)


def _state(pid: int) -> str:
    try:
        return (Path(f"/proc/{pid}") / "stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return "gone"

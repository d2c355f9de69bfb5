"""Profiles wherever a session is made: `navsvc run --profile`, `navsvc send --profile`, and
`POST /v1/sessions` inline or by name from `navsvc serve --profiles DIR` (a real server)."""

from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

import pytest

from navsvc.cli import main
from navsvc.errors import ConfigError
from navsvc.session import SessionConfig, apply_profile, config_from_options
from navsvc.wire.jsonl import read_records
from tests.api.server import start_process

PROFILE = {"format": "navsvc-profile/1",
           "parameters": {"fusion.gps_uere_m": 9.0, "fusion.process.accel_mps2": 4.0,
                          "matcher.road_sigma_m": 7.5}, "tuned": {"method": "hill"}}


def test_apply_profile_sets_nested_fields_and_refuses_bad_ones() -> None:
    c = config_from_options({"profile": PROFILE})
    assert (c.fusion.gps_uere_m, c.fusion.process.accel_mps2, c.matcher.road_sigma_m) == \
        (9.0, 4.0, 7.5)
    assert apply_profile(SessionConfig(), None) == SessionConfig()
    assert apply_profile(SessionConfig(), {"fusion.inflate_after_gated_fixes": 5.0}) \
        .fusion.inflate_after_gated_fixes == 5
    cases = {
        "fusion.nope": (1.0, "FusionConfig has no field 'nope'"),
        "fusion.sensors": (1.0, "only numbers and booleans may be set"),
        "fusion.gps_uere_m": ("x", "expected a finite number, got 'x'"),
        "fusion.inflate_after_gated_fixes": (2.5, "expected a finite integer, got 2.5"),
        "map_feedback": (1, "expected true or false"),
        "matcher.min_radius_m": (100.0, "need 0 < min_radius_m <= max_radius_m"),
    }
    for name, (value, message) in cases.items():
        with pytest.raises(ConfigError) as info:
            apply_profile(SessionConfig(), {name: value})
        assert str(info.value) == f"profile parameter {name!r}: {message}"


def test_run_with_a_profile(sample_db: Path, drive_files: list[Path], tmp_path: Path,
                            capsys: pytest.CaptureFixture[str]) -> None:
    profile = tmp_path / "p.json"
    profile.write_text(json.dumps(PROFILE))
    plain, tuned = tmp_path / "plain.jsonl", tmp_path / "tuned.jsonl"
    base = ["run", "--map", str(sample_db), "-i", str(drive_files[0]), "--quiet"]
    assert main([*base, "-o", str(plain)]) == 0
    assert main([*base, "-o", str(tuned), "--profile", str(profile)]) == 0
    assert read_records(plain) != read_records(tuned)  # the parameters took effect
    bad = tmp_path / "bad.json"
    bad.write_text('{"parameters": {"fusion.gps_uere_m": -1}}')
    assert main([*base, "-o", str(tuned), "--profile", str(bad)]) == 2
    assert f"{bad}: profile parameter 'fusion.gps_uere_m': gps_uere_m must be a finite " \
        "number > 0, got -1.0" in capsys.readouterr().err
    bad.write_text('{"parameters": 3}')
    assert main([*base, "-o", str(tuned), "--profile", str(bad)]) == 2
    assert f"{bad}: a profile is an object with 'parameters'" in capsys.readouterr().err


def test_sessions_take_profiles_inline_and_by_name(sample_db: Path, drive_files: list[Path],
                                                   tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    db, folder = tmp_path / "monaco.db", tmp_path / "profiles"
    shutil.copy(sample_db, db)
    folder.mkdir()
    (folder / "harsh.json").write_text(json.dumps(PROFILE))
    server = start_process(lambda port: [
        sys.executable, "-m", "navsvc", "serve", "--map", str(db), "--host", "127.0.0.1",
        "--port", str(port), "--profiles", str(folder)], tmp_path / "server.log")
    try:
        with server.client() as http:
            by_name = http.post("/sessions", json={"vehicle_id": "a", "profile": "harsh"})
            assert by_name.status_code == 201
            assert by_name.json()["options"]["profile"] == {"name": "harsh",
                                                            "parameters": PROFILE["parameters"]}
            inline = http.post("/sessions", json={"vehicle_id": "b", "profile": PROFILE})
            assert inline.status_code == 201
            r = http.post("/sessions", json={"vehicle_id": "c", "profile": "nope"})
            assert r.status_code == 422 and r.json()["error"]["message"] == \
                "no profile 'nope' on this server (known: harsh)"
            r = http.post("/sessions", json={"vehicle_id": "c",
                                             "profile": {"fusion.gps_uere_m": -1}})
            assert r.status_code == 422 and r.json()["error"]["message"] == \
                "profile parameter 'fusion.gps_uere_m': gps_uere_m must be a finite number " \
                "> 0, got -1.0"
        # send --profile gives what run --profile gives
        profile, sent, ran = tmp_path / "p.json", tmp_path / "sent.jsonl", tmp_path / "ran.jsonl"
        profile.write_text(json.dumps(PROFILE))
        assert main(["send", str(drive_files[0]), "--url", server.url, "-o", str(sent),
                     "--profile", str(profile), "--quiet"]) == 0
        assert main(["run", "--map", str(db), "-i", str(drive_files[0]), "-o", str(ran),
                     "--profile", str(profile), "--quiet"]) == 0
        assert read_records(sent) == read_records(ran)
    finally:
        server.stop()

"""`navsvc simulate --profile harsh-urban --gps-error urbannav` on the sample map."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from navsvc.cli import build_parser, main


def _drive(sample_db: Path, tmp_path: Path, *options: str) -> list[dict[str, object]]:
    out = tmp_path / "drive.jsonl"
    assert main(["simulate", "--map", str(sample_db), "-o", str(out), "--seed", "6",
                 "--duration", "120", *options]) == 0
    return [json.loads(line) for line in out.read_text().splitlines()]


def test_harsh_urban_with_urbannav_error(sample_db: Path, tmp_path: Path) -> None:
    default = _drive(sample_db, tmp_path)
    harsh = _drive(sample_db, tmp_path, "--profile", "harsh-urban", "--gps-error", "urbannav")
    assert harsh != default
    harsh_gps = [r for r in harsh if r["kind"] == "gps"]
    assert harsh[0]["t"] == 0.0 and harsh[0]["speed_mps"] == 0.0  # standing at the start
    assert all("speed_mps" not in r for r in harsh_gps if r["t"] < 5.0)
    again = _drive(sample_db, tmp_path, "--profile", "harsh-urban", "--gps-error", "urbannav")
    assert again == harsh


def test_default_profile_is_the_default(sample_db: Path, tmp_path: Path) -> None:
    assert _drive(sample_db, tmp_path, "--profile", "default", "--gps-error", "synthetic") \
        == _drive(sample_db, tmp_path)


def test_help_names_the_options(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        build_parser().parse_args(["simulate", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "--profile {default,harsh-urban}" in text and "NLOS runs of 20-80 m" in text
    assert "--gps-error {synthetic,urbannav}" in text and "its gaps as outages" in text

"""`navsvc --help` and `--version` start without the heavy libraries (imports are lazy), and
the choices written out in the CLI agree with the enums they stand for."""

from __future__ import annotations

import subprocess
import sys

import navsvc
from navsvc import cli
from navsvc.fusion import GpsMode, SensorConfig
from navsvc.matching.hmm import HmmConfig
from navsvc.sim.simulate import SENSOR_KINDS

HEAVY = ("numpy", "numba", "networkx", "scipy", "fastapi", "uvicorn", "pydantic", "roadgraph",
         "tqdm", "matplotlib")


def _loaded_after(argv: list[str]) -> list[str]:
    code = "\n".join([
        "import sys", "from navsvc.cli import main", "try:", f"    main({argv!r})",
        "except SystemExit:", "    pass",
        f"print('loaded:' + ','.join(m for m in {HEAVY!r} if m in sys.modules))"])
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout
    loaded = out[out.rindex("loaded:") + len("loaded:"):].strip()
    return [m for m in loaded.split(",") if m]


def test_help_of_every_command_imports_no_heavy_library() -> None:
    commands = [[]] + [[name] for name in cli._COMMANDS]
    for argv in commands:
        assert _loaded_after([*argv, "--help"]) == [], argv


def test_version_imports_no_heavy_library() -> None:
    assert _loaded_after(["--version"]) == []


def test_version_prints_the_package_version() -> None:
    out = subprocess.run([sys.executable, "-m", "navsvc", "--version"], capture_output=True,
                         text=True, check=True).stdout
    assert out.strip() == f"navsvc {navsvc.__version__}"


def test_written_out_choices_agree_with_the_enums() -> None:
    assert cli.SENSOR_CHOICES == [c.value for c in SensorConfig]
    assert cli.FUSION_CHOICES == [m.value for m in GpsMode]
    assert cli.SIMULATE_SENSOR_CHOICES == list(SENSOR_KINDS)
    assert cli.HMM_SIGMA_M == HmmConfig.sigma_m

"""Profiles: the result of ``navsvc tune``, read wherever a session is made.

A profile is a JSON document::

    {"format": "navsvc-profile/1",
     "parameters": {"fusion.gps_uere_m": 4.2, ...},   # only those that differ from defaults
     "tuned": {"method": "ga", "seed": 1, "fitness_before": 0.71, "fitness_after": 0.78,
               "drives": [...], ...}}

Only ``parameters`` changes anything (:func:`navsvc.session.apply_profile` sets them); the rest
records how it was found. ``navsvc run --profile``, ``navsvc send --profile`` and
``POST /v1/sessions`` (``"profile"``: inline, or a name from ``navsvc serve --profiles DIR``)
take one.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from navsvc.errors import ConfigError
from navsvc.session import SessionConfig, apply_profile
from navsvc.tuning.params import Parameter, Value

FORMAT = "navsvc-profile/1"


def current_value(config: SessionConfig, name: str) -> Value:
    """The value of parameter ``name`` in ``config`` (a fuzzy ``.scale`` is 1 unless set)."""
    obj: Any = config
    parts = name.split(".")
    for part in parts:
        if isinstance(obj, dict) and part == "scale":
            return 1.0
        obj = getattr(obj, part)
    return obj  # type: ignore[no-any-return]


def defaults(params: Sequence[Parameter], base: SessionConfig | None = None
             ) -> dict[str, Value]:
    """The values of ``params`` in ``base`` (default: the defaults)."""
    config = base if base is not None else SessionConfig()
    return {p.name: current_value(config, p.name) for p in params}


def changed(values: dict[str, Value], base: dict[str, Value]) -> dict[str, Value]:
    """The values that differ from ``base`` (numbers compared to 5 significant digits)."""
    def same(a: Value, b: Value) -> bool:
        if isinstance(a, bool) or isinstance(b, bool):
            return a == b
        return math.isclose(float(a), float(b), rel_tol=1e-5, abs_tol=1e-12)
    return {k: v for k, v in values.items() if not same(v, base[k])}


def profile_document(parameters: dict[str, Value], tuned: dict[str, Any]) -> dict[str, Any]:
    return {"format": FORMAT, "parameters": parameters, "tuned": tuned}


def read_profile(path: Path) -> dict[str, Any]:
    """A profile file, checked by applying it to the defaults; errors name the file."""
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read the profile ({exc.strerror})") from None
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ConfigError(f"{path}:{exc.lineno}: not JSON ({exc.msg})") from None
    if not isinstance(doc, dict) or not isinstance(doc.get("parameters"), dict):
        raise ConfigError(f"{path}: a profile is an object with 'parameters' (from "
                          "`navsvc tune`)")
    try:
        apply_profile(SessionConfig(), doc)
    except ConfigError as exc:
        raise ConfigError(f"{path}: {exc}") from None
    return doc


def read_profiles(folder: Path) -> dict[str, dict[str, Any]]:
    """Every ``*.json`` profile in ``folder``, by file stem (the name a request gives)."""
    if not folder.is_dir():
        raise ConfigError(f"{folder}: not a folder of profiles")
    return {p.stem: read_profile(p) for p in sorted(folder.glob("*.json"))}

#!/usr/bin/env bash
# Set up the peer map matchers for bench/matching_eval.py: OSRM (osrm-bindings) and Valhalla
# Meili (pyvalhalla), both from PyPI as Python 3.12 wheels that ship their own executables.
#
#   bash bench/peers/setup.sh [NAME=OSM_FILE ...]
#
# Default maps: monaco=maps/monaco.osm.gz andorra=tests/data/graphhopper/andorra.osm.pbf.
# Creates .venv-peers (Python 3.12; PYTHON312 overrides the interpreter), then per map, under
# bench/.cache/peers/NAME/: map.osm.pbf (converted with pyosmium), OSRM's MLD files
# (osrm-extract with the shipped car.lua, osrm-partition, osrm-customize) and Valhalla's tiles
# (valhalla_build_tiles, config from valhalla.get_config). Idempotent: a step whose output is
# newer than its input is skipped. source.sha256 records which OSM file the map came from
# (bench/matching_eval.py checks it against the road-graph database's source). Both tools and the maps are offline: nothing is downloaded
# but the three wheels.
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
VENV="$ROOT/.venv-peers"
CACHE="$ROOT/bench/.cache/peers"
PACKAGES=(osrm-bindings==26.10.0 pyvalhalla==3.9.1 osmium==4.3.2)

say() { printf '[peers %s] %s\n' "$(date -u +%H:%M:%S)" "$*"; }

find_python312() {
  if [[ -n "${PYTHON312:-}" ]]; then echo "$PYTHON312"; return; fi
  for p in python3.12 "$HOME"/.pyenv/versions/3.12*/bin/python; do  # a pyenv shim may fail
    if "$p" -c 'import sys; assert sys.version_info[:2] == (3, 12)' >/dev/null 2>&1; then
      command -v "$p"; return
    fi
  done
  echo "no Python 3.12 found: set PYTHON312=/path/to/python3.12" >&2
  exit 1
}

if [[ ! -x "$VENV/bin/python" ]]; then
  PY="$(find_python312)"
  say "creating $VENV with $PY"
  "$PY" -m venv "$VENV"
fi
if ! "$VENV/bin/python" -c 'import osrm, valhalla, osmium' 2>/dev/null; then
  say "installing ${PACKAGES[*]}"
  "$VENV/bin/pip" install --quiet "${PACKAGES[@]}"
fi
SITE="$("$VENV/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')"
OSRM_BIN="$SITE/osrm/bin"
CAR_LUA="$SITE/osrm/share/profiles/car.lua"
VALHALLA_BIN="$SITE/valhalla/bin"
say "osrm $("$OSRM_BIN/osrm-extract" --version), valhalla $("$VALHALLA_BIN/valhalla_build_tiles" --version 2>&1 | tail -1)"

newer() { [[ -e "$1" && "$1" -nt "$2" ]]; }  # is $1 there and newer than $2?

build_map() {
  local name="$1" source="$2" dir="$CACHE/$1"
  [[ -f "$source" ]] || { echo "map source not found: $source" >&2; exit 1; }
  local sha; sha="$(sha256sum "$source" | awk '{print $1}')"
  if [[ -f "$dir/source.sha256" && "$(cat "$dir/source.sha256")" != "$sha" ]]; then
    say "$name: another source than last time, rebuilding"
    rm -rf "$dir"
  fi
  mkdir -p "$dir"
  local pbf="$dir/map.osm.pbf"
  if ! newer "$pbf" "$source"; then
    say "$name: $source -> $pbf"
    "$VENV/bin/python" - "$source" "$pbf" <<'PY'
import sys, osmium
src, dst = sys.argv[1:]
with osmium.SimpleWriter(dst + ".tmp.osm.pbf", overwrite=True) as writer:
    for obj in osmium.FileProcessor(src):
        writer.add(obj)
import os; os.replace(dst + ".tmp.osm.pbf", dst)
PY
  fi
  if ! newer "$dir/map.osrm.mldgr" "$pbf"; then
    say "$name: osrm-extract (car.lua), osrm-partition, osrm-customize"
    (cd "$dir" && "$OSRM_BIN/osrm-extract" -p "$CAR_LUA" map.osm.pbf > osrm.log 2>&1 \
      && "$OSRM_BIN/osrm-partition" map.osrm >> osrm.log 2>&1 \
      && "$OSRM_BIN/osrm-customize" map.osrm >> osrm.log 2>&1) \
      || { tail -20 "$dir/osrm.log" >&2; exit 1; }
  fi
  if ! newer "$dir/valhalla_tiles/.built" "$pbf"; then
    say "$name: valhalla_build_tiles"
    rm -rf "$dir/valhalla_tiles" && mkdir -p "$dir/valhalla_tiles"
    "$VENV/bin/python" - "$dir" <<'PY'
import json, sys
from pathlib import Path
import valhalla
d = Path(sys.argv[1])
config = valhalla.get_config(tile_extract="", tile_dir=d / "valhalla_tiles")
(d / "valhalla.json").write_text(json.dumps(config, indent=1))
PY
    "$VALHALLA_BIN/valhalla_build_tiles" -c "$dir/valhalla.json" -j 2 "$pbf" > "$dir/valhalla.log" 2>&1 \
      || { tail -20 "$dir/valhalla.log" >&2; exit 1; }
    touch "$dir/valhalla_tiles/.built"
  fi
  echo "$sha" > "$dir/source.sha256"
  say "$name: ready in $dir"
}

if [[ $# -eq 0 ]]; then
  set -- "monaco=$ROOT/maps/monaco.osm.gz" "andorra=$ROOT/tests/data/graphhopper/andorra.osm.pbf"
fi
for spec in "$@"; do
  build_map "${spec%%=*}" "${spec#*=}"
done

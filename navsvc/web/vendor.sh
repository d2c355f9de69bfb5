#!/usr/bin/env bash
# Copy Leaflet's built files and licence from its npm package into static/vendor/leaflet/.
# The copies are committed, so that a clone, a wheel and the Docker image carry them and the
# page fetches nothing from a CDN; run this (needs npm) only to change the version.
set -euo pipefail
VERSION=${1:-1.9.4}
HERE=$(cd "$(dirname "$0")" && pwd)
DEST="$HERE/static/vendor/leaflet"
WORK=$(mktemp -d)
trap 'rm -rf "$WORK"' EXIT
(cd "$WORK" && npm pack --silent "leaflet@$VERSION" >/dev/null && tar xzf "leaflet-$VERSION.tgz")
rm -rf "$DEST" && mkdir -p "$DEST/images"
cp "$WORK/package/dist/leaflet.js" "$WORK/package/dist/leaflet.css" "$DEST/"
cp "$WORK/package/dist/images/"*.png "$DEST/images/"
cp "$WORK/package/LICENSE" "$DEST/LICENSE"
echo "leaflet $VERSION (npm), BSD-2-Clause: $(sha256sum "$WORK/leaflet-$VERSION.tgz" | cut -d' ' -f1)" \
    > "$DEST/VERSION"
echo "copied leaflet $VERSION into $DEST"

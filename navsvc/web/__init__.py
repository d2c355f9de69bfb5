"""The map view: a page served by navsvc itself (``GET /`` and ``/map``) and what feeds it.

- ``static/``: the page (``index.html``, ``viewer.js``, ``viewer.css``) and Leaflet (npm
  ``leaflet`` 1.9.4, BSD-2-Clause, its files and licence under ``static/vendor/leaflet/``),
  shipped as package data: nothing is fetched from elsewhere, the page works offline.
- :mod:`navsvc.web.feed`: what the page's viewer WebSocket is sent: a session's raw GPS fixes
  and matched positions, pushed by the ingest path to bounded per-viewer queues.
- :mod:`navsvc.web.replay`: a whole drive or run file turned into what the page replays
  (``navsvc view``).
"""

from pathlib import Path

STATIC_DIR = Path(__file__).resolve().parent / "static"

__all__ = ["STATIC_DIR"]

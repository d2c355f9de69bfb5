# navsvc: the map-matching service on a slim Python base, as a non-root user.
#   docker build -t navsvc . && docker run -p 8000:8000 navsvc
# The image carries the bundled Monaco map, imported at build time into /data/map.db; mount a
# volume on /data with another database and set NAVSVC_MAP to serve another map.
ARG BASE=python:3.12-slim
FROM ${BASE}

ENV PYTHONDONTWRITEBYTECODE=1 PYTHONUNBUFFERED=1 PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    PATH=/opt/navsvc/bin:$PATH \
    NAVSVC_MAP=/data/map.db NAVSVC_HOST=0.0.0.0 NAVSVC_PORT=8000 \
    NUMBA_CACHE_DIR=/tmp/numba-cache

RUN python3 -m venv /opt/navsvc
WORKDIR /app
COPY pyproject.toml README.md ./
COPY roadgraph roadgraph
COPY navsvc navsvc
RUN pip install .
COPY maps maps

RUN useradd --create-home --uid 10001 navsvc \
    && mkdir -p /data \
    && roadgraph import maps/monaco.osm.gz -o /data/map.db --quiet \
    && chown -R navsvc /data
USER navsvc
VOLUME /data
EXPOSE 8000

HEALTHCHECK --interval=30s --timeout=5s --start-period=30s --retries=3 \
    CMD python3 -c "import os, urllib.request; urllib.request.urlopen('http://127.0.0.1:' + os.environ['NAVSVC_PORT'] + '/v1/healthz', timeout=4)"

# navsvc serve reads NAVSVC_MAP, NAVSVC_HOST and NAVSVC_PORT (and the other NAVSVC_* limits)
CMD ["navsvc", "serve"]

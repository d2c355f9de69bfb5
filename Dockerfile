# navsvc: the map-matching service on a slim Python base, as a non-root user.
#   docker build -t navsvc . && docker run -p 8000:8000 navsvc     # then open http://127.0.0.1:8000/
# The image carries the bundled Monaco map, imported at build time into /data/monaco.db (the
# map id is the file's stem: "monaco"); mount a volume on /data with another database and set
# NAVSVC_MAP to serve another map.
ARG BASE=python:3.12-slim
FROM ${BASE}

ENV PYTHONDONTWRITEBYTECODE=1 PYTHONUNBUFFERED=1 PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    PATH=/opt/navsvc/bin:$PATH \
    NAVSVC_MAP=/data/monaco.db NAVSVC_HOST=0.0.0.0 NAVSVC_PORT=8000 \
    NUMBA_CACHE_DIR=/opt/navsvc-cache/numba

# HAProxy from Debian: `navsvc serve --workers N` in one container, and the balancer service
# of docker-compose.yml (the same image).
RUN apt-get update && DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends \
      haproxy && rm -rf /var/lib/apt/lists/*
RUN python3 -m venv /opt/navsvc
WORKDIR /app
# The dependencies first, in a layer of their own: a change of the source reinstalls only navsvc.
COPY pyproject.toml ./
RUN python3 -c "import tomllib; print('\n'.join(tomllib.load(open('pyproject.toml', 'rb'))['project']['dependencies']))" > /tmp/requirements.txt \
    && pip install -r /tmp/requirements.txt
COPY README.md ./
COPY roadgraph roadgraph
COPY navsvc navsvc
RUN pip install --no-deps .
COPY maps maps
COPY deploy deploy

RUN useradd --create-home --uid 10001 navsvc \
    && mkdir -p /data "$NUMBA_CACHE_DIR" \
    && roadgraph import maps/monaco.osm.gz -o /data/monaco.db --quiet \
    && chown -R navsvc /data /opt/navsvc-cache
USER navsvc
# Compile the filter kernels now, into numba's cache in the image (~30-45 s, once per build):
# a container then warms up in about a second instead of compiling at every start. (numba
# recompiles, and says nothing worse, on a CPU the cache was not made for.)
RUN navsvc serve --map /data/monaco.db --warm-up-only
VOLUME /data
EXPOSE 8000

# Healthy once the server answers: it answers after its warm-up (a second or two on the cache).
HEALTHCHECK --interval=30s --timeout=5s --start-period=30s --retries=3 \
    CMD python3 -c "import os, urllib.request; urllib.request.urlopen('http://127.0.0.1:' + os.environ['NAVSVC_PORT'] + '/v1/healthz', timeout=4)"

# navsvc serve reads NAVSVC_MAP, NAVSVC_HOST and NAVSVC_PORT (and the other NAVSVC_* limits);
# NAVSVC_WORKERS=N: N workers behind HAProxy on NAVSVC_PORT, in this one container
CMD ["navsvc", "serve"]

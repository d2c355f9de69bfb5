# Two commands do all the set-up (see README.md): `make run` and `make test`.
# Each creates the virtual environment .venv when it is missing (PyPI only).
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
MAP_SOURCE ?= maps/monaco.osm.gz
MAP_DB ?= maps/monaco.db
HOST ?= 127.0.0.1
PORT ?= 8000

.PHONY: run test bench map clean browser balancer

$(BIN)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $@

$(MAP_DB): $(MAP_SOURCE) $(BIN)/.installed
	$(BIN)/roadgraph import $(MAP_SOURCE) -o $(MAP_DB)

map: $(MAP_DB)

run: $(MAP_DB)
	@echo "navsvc: serving $(MAP_DB): open http://$(HOST):$(PORT)/ for the live map (API: /v1, docs: /docs); Ctrl-C stops"
	$(BIN)/navsvc serve --map $(MAP_DB) --host $(HOST) --port $(PORT)

test: $(BIN)/.installed browser balancer
	$(BIN)/python -m pytest

# The map page's browser tests (tests/web) drive Debian's Chromium: installed here with apt-get
# when it is missing and we are root (as CI is); otherwise those tests skip and say why.
browser:
	@command -v chromium >/dev/null 2>&1 || command -v chromium-browser >/dev/null 2>&1 \
	  || { if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
	         echo "make test: installing Chromium for the browser tests (apt-get)"; \
	         apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq \
	           chromium >/dev/null \
	         || echo "make test: apt-get could not install Chromium: browser tests will skip"; \
	       else echo "make test: no Chromium (apt-get install chromium as root): browser tests will skip"; fi; }

# `navsvc serve --workers N` puts HAProxy in front of its workers; its tests (tests/api/
# test_workers.py) run the real one: installed here with apt-get when it is missing and we are
# root (as CI is); otherwise those tests skip and say why. `make run` does not need it.
balancer:
	@command -v haproxy >/dev/null 2>&1 || test -x /usr/sbin/haproxy \
	  || { if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
	         echo "make test: installing HAProxy for the worker tests (apt-get)"; \
	         apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq \
	           haproxy >/dev/null \
	         || echo "make test: apt-get could not install HAProxy: worker tests will skip"; \
	       else echo "make test: no HAProxy (apt-get install haproxy as root): worker tests will skip"; fi; }

bench: $(MAP_DB)
	$(BIN)/python -m pip install --quiet -e '.[test,bench]'
	$(BIN)/python bench/roadgraph_bench.py --map-source $(MAP_SOURCE)
	$(BIN)/python bench/fusion_bench.py
	$(BIN)/python bench/fusion_eval.py --map $(MAP_DB)
	$(BIN)/python bench/generalisation_eval.py --split report
	$(BIN)/python bench/comma2k19.py
	bash bench/peers/setup.sh  # OSRM and Valhalla in their own Python 3.12 venv
	$(BIN)/python bench/matching_eval.py
	$(BIN)/python bench/matching_speed.py --map $(MAP_DB)
	PYTHONPATH=. $(BIN)/python bench/service_load.py --map $(MAP_DB)
	PYTHONPATH=. $(BIN)/python bench/restart.py --map $(MAP_DB)
	PYTHONPATH=. $(BIN)/python bench/viewer_feed.py --map $(MAP_DB)
	$(BIN)/python bench/ins_eval.py  # needs ../shared/peers/rtklibexplorer-drive0708

clean:
	rm -rf $(VENV) $(MAP_DB) bench/results .pytest_cache .hypothesis

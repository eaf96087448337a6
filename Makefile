# Everything a fresh clone needs: `make demo` and `make test` build .venv on first use.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed-stamp
OUT    ?= out

.PHONY: demo test test-slow lint bench system-deps clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[all,dev]'
	touch $@

# Debian tools that tests drive as independent peers (mbpoll: a Modbus client we did not write;
# socat: a pair of pseudo-terminals, the serial line between an RTU server and the daemon).
system-deps:
	@for tool in mbpoll socat; do \
	  command -v $$tool >/dev/null 2>&1 || { \
	    echo "installing $$tool (Debian package)"; \
	    SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo ); \
	    $$SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y -qq $$tool >/dev/null; }; \
	done

# `make demo FURNACE=config/furnaces/six-zone.yaml` (or a name in config/furnaces/, e.g.
# FURNACE=modulated): the same chain on another furnace.
demo: $(STAMP)
	$(BIN)/python -m furnace_daq.demo --out $(OUT)/demo$(if $(FURNACE), --furnace $(FURNACE))

# Two workers (pytest-xdist), one per core of the 2-core target; a test module stays on one
# worker, so its module-wide fixtures (a live daemon run, a fitted record) are built once.
# The slow tests run one at a time: the 2-hour soak and the crash test judge reconnect times
# and losses over long runs, which a second worker fitting at full speed beside them would
# stretch.
test: $(STAMP) system-deps
	$(BIN)/python -m pytest -q -m "not slow" -n 2 --dist loadfile

test-slow: $(STAMP) system-deps
	$(BIN)/python -m pytest -q -m slow

lint: $(STAMP)
	$(BIN)/ruff check furnace_model furnace_daq tests bench

bench: $(STAMP)
	$(BIN)/python bench/run_all.py

clean:
	rm -rf $(VENV) $(OUT) .pytest_cache

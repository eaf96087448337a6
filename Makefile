# Everything a fresh clone needs: `make demo` and `make test` build .venv on first use.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed-stamp
OUT    ?= out

.PHONY: demo test test-slow lint bench system-deps deb clean bytecode

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[all,dev]'
	touch $@

# The package's modules compiled once: where PYTHONDONTWRITEBYTECODE is set (test machines,
# containers) every process would otherwise compile every module it imports at its start,
# about 0.2 s of CPU for each of the demo's processes and each command a test runs. A module
# edited since is compiled again at its import, as without this.
bytecode: $(STAMP)
	$(BIN)/python -m compileall -q furnace_model furnace_daq

# Debian tools that tests drive as independent peers (mbpoll: a Modbus client we did not write;
# socat: a pair of pseudo-terminals, the serial line between an RTU server and the daemon),
# and what `make deb` builds with (dpkg-deb, Debian's own python3.11 for the package's venv;
# systemd-sysusers and systemd-analyze, which the package's tests run), as TOOL:PACKAGE.
DEBIAN_TOOLS := mbpoll:mbpoll socat:socat dpkg-deb:dpkg /usr/bin/python3.11:python3.11 \
                systemd-sysusers:systemd systemd-analyze:systemd

system-deps:
	@for pair in $(DEBIAN_TOOLS); do \
	  tool=$${pair%%:*}; package=$${pair#*:}; \
	  command -v $$tool >/dev/null 2>&1 || { \
	    echo "installing $$package (Debian package, for $$tool)"; \
	    SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo ); \
	    $$SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y -qq $$package >/dev/null; }; \
	done

# The gateway's package: out/deb/furnace-daq_VERSION_ARCH.deb (deb/build_deb.py says what it
# holds; pip fetches the daemon's dependencies while building, the install needs no network).
deb: $(STAMP) system-deps
	$(BIN)/python deb/build_deb.py --out $(OUT)/deb

# `make demo FURNACE=config/furnaces/six-zone.yaml` (or a name in config/furnaces/, e.g.
# FURNACE=modulated): the same chain on another furnace. `make demo PROTOCOL=opcua` (or s7):
# the simulated PLC and the daemon speak that protocol instead of Modbus.
# `make demo SCENARIO=config/scenarios/paper_production.yaml` (or a shipped name): that
# scenario, on its own furnace (a closed-loop one runs its loops in the simulated PLC).
# `SPEED=1000`: simulated seconds per wall second (default 5000), slower where the host must
# keep up with refits and an online diagnosis.
demo: $(STAMP) bytecode
	$(BIN)/python -m furnace_daq.demo --out $(OUT)/demo$(if $(FURNACE), --furnace $(FURNACE))$(if $(SCENARIO), --scenario $(SCENARIO))$(if $(PROTOCOL), --protocol $(PROTOCOL))$(if $(SPEED), --speed $(SPEED))

# Two workers (pytest-xdist), one per core of the 2-core target; a test module stays on one
# worker, so its module-wide fixtures (a live daemon run, a fitted record) are built once.
# The slow tests run one at a time: the 2-hour soak and the crash test judge reconnect times
# and losses over long runs, which a second worker fitting at full speed beside them would
# stretch.
test: $(STAMP) system-deps bytecode
	$(BIN)/python -m pytest -q -m "not slow" -n 3 --dist loadfile

test-slow: $(STAMP) system-deps bytecode
	$(BIN)/python -m pytest -q -m slow

lint: $(STAMP)
	$(BIN)/ruff check furnace_model furnace_daq tests bench

bench: $(STAMP) bytecode
	$(BIN)/python bench/run_all.py

clean:
	rm -rf $(VENV) $(OUT) .pytest_cache

# SharedLink analyzer. `make demo` and `make test` install what they need (tshark from
# Debian's packages, a virtualenv in .venv) and are quick when it is already there.

SHELL := /bin/bash
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
PY := $(BIN)/python
CLI := $(BIN)/sharedlink
STAMP := $(VENV)/.installed
RUNTIME := $(VENV)/.runtime
DISSECTORS := $(wildcard dissector/*.lua)
SUDO := $(shell [ "$$(id -u)" = 0 ] || echo sudo)
# compiled bytecode kept out of the source tree, in the virtualenv (every `sharedlink` a test
# starts would otherwise compile the package again: ~0.05 s CPU a run)
unexport PYTHONDONTWRITEBYTECODE
export PYTHONPYCACHEPREFIX := $(CURDIR)/$(VENV)/pycache

.PHONY: all demo test test-long test-install test-all lint bench captures install uninstall deps tshark venv clean help rootfs test-matrix fuzz mutate man

all: help

help:
	@echo "make demo      generate a beacon capture and decode it with tshark and the dissector"
	@echo "make test      lint and run the test suite (not the long and install tests: docs/testing.md)"
	@echo "make test-long the long tests (scaling and memory patterns at size, live floods) and the property tests at full size"
	@echo "make test-install  the tests that build packages and virtualenvs (pipx, a wheel, make's venv)"
	@echo "make test-all  all three (what .ci/run runs, with make test-matrix)"
	@echo "make bench     print speed and memory ratios"
	@echo "make captures  regenerate captures/ (byte-identical)"
	@echo "make man       remake docs/sharedlink.1, the man page, from the command's parsers"
	@echo "make install   put the dissectors, the serial extcap and the coloring rules into your personal Wireshark folders"
	@echo "make uninstall remove them again"
	@echo "make test-matrix  the tshark tests on Wireshark 4.0, 4.4 and 4.6 (root filesystems built once)"
	@echo "make fuzz      the long fuzz run of the dissectors and the Python parsers (about 3.5 h on 2 busy cores;"
	@echo "               FUZZ_ARGS=\"--seeds 5 --random 500 --codec-runs 5000 --jobs 1\": 50 min; docs/testing.md)"
	@echo "make mutate    mutation testing of the core modules (share of mutants killed)"

# --- set-up ------------------------------------------------------------------------------
deps: tshark venv

# tshark, editcap, luacheck and the Lua 5.2 and 5.4 compilers (the dissectors' syntax checked
# by both) from Debian's packages, non-interactively (the setuid question pre-answered "no")
tshark:
	@if ! command -v tshark >/dev/null || ! command -v editcap >/dev/null || ! command -v luacheck >/dev/null \
	    || ! command -v luac5.2 >/dev/null || ! command -v luac5.4 >/dev/null; then \
	  echo "installing tshark, luacheck and luac from Debian's packages"; \
	  echo "wireshark-common wireshark-common/install-setuid boolean false" | $(SUDO) debconf-set-selections; \
	  $(SUDO) apt-get update -qq && \
	  DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get install -y -qq --no-install-recommends tshark lua-check lua5.2 lua5.4 >/dev/null; \
	fi

venv: $(STAMP)

# the virtualenv with the package alone (make install: the lean core, no extras), and with every
# extra and the test tools (make test)
define MAKE_VENV
	@if ! $(PYTHON) -m venv --help >/dev/null 2>&1 || ! $(PYTHON) -c 'import ensurepip' 2>/dev/null; then \
	  echo "installing python3-venv from Debian's packages"; \
	  $(SUDO) apt-get update -qq && DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get install -y -qq python3-venv python3-pip >/dev/null; \
	fi
	$(PYTHON) -m venv $(VENV)
	@# a pip that installs editable pyproject packages (PEP 660: 21.3) is kept: upgrading it is a
	@# round trip to the index and a reinstall for nothing (ensurepip's is 22 or newer since Python 3.11)
	@$(BIN)/python -c 'import pip, sys; sys.exit(tuple(map(int, pip.__version__.split(".")[:2])) < (21, 3))' \
	  || $(BIN)/pip install -q --upgrade pip
endef

# an editable install without setuptools' boxed "Editable installation" warning (lenient mode
# kept: a module added to the checkout is there without reinstalling); --no-compile: Python
# compiles a module when it is first imported, so only the modules used are (the venv 27 -> 19 s)
PIP_EDITABLE := PYTHONWARNINGS="ignore:Editable installation" $(BIN)/pip install -q --no-compile -e

$(RUNTIME): pyproject.toml setup.py
	$(MAKE_VENV)
	$(PIP_EDITABLE) .
	@touch $(RUNTIME)

$(STAMP): pyproject.toml setup.py
	$(MAKE_VENV)
	$(PIP_EDITABLE) '.[all,test]'
	@touch $(STAMP) $(RUNTIME)

# --- the main job ----------------------------------------------------------------------------
demo: deps
	@mkdir -p out
	$(CLI) gen -o out/demo.pcap --duration 10 --compress
	@echo; echo "== tshark with dissector/sharedlink.lua (first 12 frames) =="
	@tshark -n -X lua_script:dissector/sharedlink.lua -r out/demo.pcap -c 12 2>/dev/null
	@echo; echo "== one frame in full =="
	@tshark -n -X lua_script:dissector/sharedlink.lua -r out/demo.pcap -O sharedlink -Y 'frame.number == 2' 2>/dev/null | sed -n '/^SharedLink/,$$p'
	@echo; echo "== variables over the drive (display filter sharedlink.kind == \"full\") =="
	@tshark -n -X lua_script:dissector/sharedlink.lua -r out/demo.pcap -Y 'sharedlink.kind == "full"' \
	  -T fields -E header=y -e frame.time_relative -e sharedlink.var.name -e sharedlink.var.value -e sharedlink.checksum.status 2>/dev/null | head -8
	@echo; echo "== sharedlink stats out/demo.pcap =="
	@$(CLI) stats out/demo.pcap

# --- checks ----------------------------------------------------------------------------------
lint: deps
	$(BIN)/ruff check pytools tests bench
	luacheck -q dissector

# make test leaves out the tests marked long or install (tests/conftest.py): each has its target,
# and .ci/run runs them all (docs/testing.md says which tests and why)
export RESTORE_SIGINT := import os, signal, sys; signal.signal(signal.SIGINT, signal.SIG_DFL); os.execv(sys.argv[1], sys.argv[1:])
# (pytest started with SIGINT restored: tests stop their watch and replay processes with it, and a
# make started in the background, e.g. by nohup or a job with &, passes it on ignored)
PYTEST_ONE := $(BIN)/python -c "$$RESTORE_SIGINT" $(BIN)/pytest -q
PYTEST := $(PYTEST_ONE) -n 2 --dist loadgroup

# The live tests (marked live: they wait on the clock, using little CPU) run in a pytest process of
# their own beside the rest, their output after the rest's: on 2 cores the waits overlap the others' work
LIVE_LOG := $(shell mktemp -u /tmp/sharedlink-live-XXXXXX)
test: deps lint
	@mkdir -p $(LIVE_LOG).d; \
	$(PYTEST_ONE) -p no:cacheprovider --basetemp=$(LIVE_LOG).d/tmp --durations=5 -m "live and not long and not install" \
	  tests > $(LIVE_LOG) 2>&1 & live=$$!; \
	$(PYTEST) --durations=25 -m "not live and not long and not install" tests; rc=$$?; \
	wait $$live; lrc=$$?; \
	echo "== the live tests (run beside the rest) =="; cat $(LIVE_LOG); rm -rf $(LIVE_LOG) $(LIVE_LOG).d; \
	test $$rc -eq 0 && test $$lrc -eq 0

# the long tests, and the property tests (hypothesis) at their full figures (make test: 0.4 of them)
test-long: deps
	SHAREDLINK_EXAMPLES=1 $(PYTEST) --durations=10 -m "long or hypothesis" tests

test-install: deps
	$(PYTEST) --durations=10 -m install tests

test-all: test test-long test-install

bench: deps
	$(PY) bench/bench.py

# mutation testing (mutmut) of the core modules, each against its fast subset of the tests;
# MUTATE_ARGS: module names (codec state stream diff serial_format replay), --jobs, --resume
mutate: deps
	@$(BIN)/python -c 'import mutmut' 2>/dev/null || $(BIN)/pip install -q 'mutmut>=3.3'  # the [mutate] extra
	env -u PYTHONPATH $(PY) scripts/mutate.py $(MUTATE_ARGS)

# the man page from the parsers (argparse-manpage, in the test extra); test_cli_docs checks it fresh
man: venv
	$(PY) scripts/manpage.py docs/sharedlink.1

captures: deps
	$(CLI) gen -o captures/beacon-full.pcap --duration 60 --seed 1
	$(CLI) gen -o captures/beacon-compressed.pcap --duration 60 --seed 1 --compress --sync-interval 1

# every dissector/**/*.lua into the personal plugin folder, the serial extcap (its first line
# pointed at the venv's Python) into the personal extcap folder and the coloring rules at the top
# of the personal colorfilters, as `tshark -G folders` names them: `sharedlink plugins install`
# (sharedlink/plugins.py), from the package alone (no test extras)
install: tshark $(RUNTIME)
	@$(CLI) plugins install

# removes what install put there: the plugins, the extcap, and the coloring rules from the personal
# colorfilters, also those disabled ("!@SharedLink ...") or edited in the GUI (rules left behind
# would name fields no dissector registers: "Could not compile" at every start); a colorfilters
# file that is then the global default again (install made it from that) is removed
uninstall: tshark $(RUNTIME)
	@$(CLI) plugins uninstall

clean:
	rm -rf out .pytest_cache .ruff_cache

# --- Wireshark version matrix and fuzzing (docs/testing.md) ------------------------------------
# Debian 13 (Wireshark 4.4) and Debian unstable (4.6) root filesystems, made once with debootstrap
# into $(SHAREDLINK_ROOTFS_CACHE) (default /var/cache/sharedlink-rootfs) and reused
ROOTFS_SUITES := trixie sid

rootfs:
	scripts/rootfs.sh build $(ROOTFS_SUITES) >/dev/null

# every test that runs tshark, against 4.0 (this machine), 4.4 and 4.6 (the root filesystems)
test-matrix: deps rootfs
	scripts/test-matrix.sh

# the long fuzz run (tshark: editcap mutations, truncations, random and 64 KB payloads; the Python
# parsers: atheris). FUZZ_ARGS, e.g. "--seeds 500"; SHAREDLINK_TSHARK picks the release.
fuzz: deps
	@$(PY) -c 'import atheris' 2>/dev/null || $(PIP_EDITABLE) '.[all,fuzz]' \
	  || echo "atheris could not be installed: the Python parsers are fuzzed with hypothesis"
	$(PY) scripts/fuzz.py $(FUZZ_ARGS)
	SHAREDLINK_EXAMPLES=10 $(PYTEST) -m hypothesis tests  # the property tests at ten times their figures

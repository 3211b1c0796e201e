# SharedLink analyzer. `make demo` and `make test` install what they need (tshark from
# Debian's packages, a virtualenv in .venv) and are quick when it is already there.

SHELL := /bin/bash
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
PY := $(BIN)/python
CLI := $(BIN)/sharedlink
STAMP := $(VENV)/.installed
DISSECTORS := $(wildcard dissector/*.lua)
SUDO := $(shell [ "$$(id -u)" = 0 ] || echo sudo)
export PYTHONDONTWRITEBYTECODE := 1

.PHONY: all demo test lint bench captures install uninstall deps tshark venv clean help

all: help

help:
	@echo "make demo      generate a beacon capture and decode it with tshark and the dissector"
	@echo "make test      lint and run the whole test suite"
	@echo "make bench     print speed and memory ratios"
	@echo "make captures  regenerate captures/ (byte-identical)"
	@echo "make install   put the dissectors into your personal Wireshark plugin folder"

# --- set-up ------------------------------------------------------------------------------
deps: tshark venv

# tshark, editcap and luacheck from Debian's packages, non-interactively (the setuid
# question pre-answered "no")
tshark:
	@if ! command -v tshark >/dev/null || ! command -v editcap >/dev/null || ! command -v luacheck >/dev/null; then \
	  echo "installing tshark and luacheck from Debian's packages"; \
	  echo "wireshark-common wireshark-common/install-setuid boolean false" | $(SUDO) debconf-set-selections; \
	  $(SUDO) apt-get update -qq && \
	  DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get install -y -qq --no-install-recommends tshark lua-check >/dev/null; \
	fi

venv: $(STAMP)

$(STAMP): pyproject.toml
	@if ! $(PYTHON) -m venv --help >/dev/null 2>&1 || ! $(PYTHON) -c 'import ensurepip' 2>/dev/null; then \
	  echo "installing python3-venv from Debian's packages"; \
	  $(SUDO) apt-get update -qq && DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get install -y -qq python3-venv python3-pip >/dev/null; \
	fi
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q -e '.[test]'
	@touch $(STAMP)

# --- the main job ----------------------------------------------------------------------------
demo: deps
	@mkdir -p out
	$(CLI) gen out/demo.pcap --duration 10 --compress
	@echo; echo "== tshark with dissector/sharedlink.lua (first 12 frames) =="
	@tshark -n -X lua_script:dissector/sharedlink.lua -r out/demo.pcap -c 12 2>/dev/null
	@echo; echo "== one frame in full =="
	@tshark -n -X lua_script:dissector/sharedlink.lua -r out/demo.pcap -O sharedlink -Y 'frame.number == 2' 2>/dev/null | sed -n '/^SharedLink/,$$p'
	@echo; echo "== variables over the drive (display filter sharedlink.kind == \"full\") =="
	@tshark -n -X lua_script:dissector/sharedlink.lua -r out/demo.pcap -Y 'sharedlink.kind == "full"' \
	  -T fields -E header=y -e frame.time_relative -e sharedlink.var.name -e sharedlink.var.value -e sharedlink.checksum.status 2>/dev/null | head -8

# --- checks ----------------------------------------------------------------------------------
lint: deps
	$(BIN)/ruff check pytools tests bench
	luacheck -q dissector

test: deps lint
	$(BIN)/pytest -q -n 2 tests

bench: deps
	$(PY) bench/bench.py

captures: deps
	$(CLI) gen captures/beacon-full.pcap --duration 60 --seed 1
	$(CLI) gen captures/beacon-compressed.pcap --duration 60 --seed 1 --compress --sync-interval 1

# the personal plugin folder, as tshark reports it
install: tshark
	@dir=$$(tshark -G folders 2>/dev/null | sed -n 's/^Personal Lua Plugins:[[:space:]]*//p' | head -1); \
	[ -n "$$dir" ] || dir=$$(tshark -G folders 2>/dev/null | sed -n 's/^Personal Plugins:[[:space:]]*//p' | head -1); \
	[ -n "$$dir" ] || { echo "tshark -G folders names no personal plugin folder" >&2; exit 2; }; \
	mkdir -p "$$dir" && cp $(DISSECTORS) "$$dir"/ && echo "installed $(notdir $(DISSECTORS)) into $$dir"

clean:
	rm -rf out .pytest_cache .ruff_cache

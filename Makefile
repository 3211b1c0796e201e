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

.PHONY: all demo test lint bench captures install uninstall deps tshark venv clean help rootfs test-matrix fuzz

all: help

help:
	@echo "make demo      generate a beacon capture and decode it with tshark and the dissector"
	@echo "make test      lint and run the whole test suite"
	@echo "make bench     print speed and memory ratios"
	@echo "make captures  regenerate captures/ (byte-identical)"
	@echo "make install   put the dissectors into your personal Wireshark plugin folder"
	@echo "make test-matrix  the tshark tests on Wireshark 4.0, 4.4 and 4.6 (root filesystems built once)"
	@echo "make fuzz      the long fuzz run of the dissectors and the Python parsers"

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
	@echo; echo "== sharedlink stats out/demo.pcap =="
	@$(CLI) stats out/demo.pcap

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
	@# the serial extcap: "Personal Extcap path" (Wireshark 4.2+), else <Personal configuration>/extcap
	@# (where Wireshark 3.x/4.0 look for personal extcaps); its first line is pointed at the venv's Python
	@dir=$$(tshark -G folders 2>/dev/null | sed -n 's/^Personal Extcap path:[[:space:]]*//p' | head -1); \
	[ -n "$$dir" ] || { conf=$$(tshark -G folders 2>/dev/null | sed -n 's/^Personal configuration:[[:space:]]*//p' | head -1); \
	  [ -n "$$conf" ] && dir="$$conf/extcap"; }; \
	[ -n "$$dir" ] || { echo "tshark -G folders names no personal extcap folder" >&2; exit 2; }; \
	mkdir -p "$$dir" && sed '1s|.*|#!$(abspath $(PY))|' extcap/sharedlink-serial > "$$dir/sharedlink-serial" && \
	chmod 755 "$$dir/sharedlink-serial" && echo "installed the sharedlink-serial extcap into $$dir"
	@# the coloring rules, once, at the top of the personal colorfilters (theirs kept below; with no
	@# personal file, the global default's rules are kept below ours)
	@conf=$$(tshark -G folders 2>/dev/null | sed -n 's/^Personal configuration:[[:space:]]*//p' | head -1); \
	glob=$$(tshark -G folders 2>/dev/null | sed -n 's/^Global configuration:[[:space:]]*//p' | head -1); \
	[ -n "$$conf" ] || { echo "tshark -G folders names no personal configuration folder" >&2; exit 2; }; \
	cf="$$conf/colorfilters"; \
	if [ -f "$$cf" ] && grep -q '^@SharedLink ' "$$cf"; then echo "SharedLink coloring rules already in $$cf"; \
	else mkdir -p "$$conf" && { [ -f "$$cf" ] && base="$$cf" || base="$$glob/colorfilters"; \
	  { cat dissector/sharedlink.colorfilters; [ -f "$$base" ] && cat "$$base"; true; } > "$$cf.new" && \
	  cat "$$cf.new" > "$$cf" && rm -f "$$cf.new" && echo "added the SharedLink coloring rules to $$cf"; }; fi

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
	@$(PY) -c 'import atheris' 2>/dev/null || $(BIN)/pip install -q -e '.[fuzz]' \
	  || echo "atheris could not be installed: the Python parsers are fuzzed with hypothesis"
	$(PY) scripts/fuzz.py $(FUZZ_ARGS)

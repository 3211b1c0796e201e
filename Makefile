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
# the modules sharedlink.lua loads (dissector/sharedlink/*.lua), installed as that folder beside it
DISSECTOR_MODULES := dissector/sharedlink
SUDO := $(shell [ "$$(id -u)" = 0 ] || echo sudo)
export PYTHONDONTWRITEBYTECODE := 1

.PHONY: all demo test lint bench captures install uninstall deps tshark venv clean help rootfs test-matrix fuzz mutate

all: help

help:
	@echo "make demo      generate a beacon capture and decode it with tshark and the dissector"
	@echo "make test      lint and run the whole test suite"
	@echo "make bench     print speed and memory ratios"
	@echo "make captures  regenerate captures/ (byte-identical)"
	@echo "make install   put the dissectors, the serial extcap and the coloring rules into your personal Wireshark folders"
	@echo "make uninstall remove them again"
	@echo "make test-matrix  the tshark tests on Wireshark 4.0, 4.4 and 4.6 (root filesystems built once)"
	@echo "make fuzz      the long fuzz run of the dissectors and the Python parsers"
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

# mutation testing (mutmut) of the core modules, each against its fast subset of the tests;
# MUTATE_ARGS: module names (codec state stream diff serial_format replay), --jobs, --resume
mutate: deps
	@$(BIN)/python -c 'import mutmut' 2>/dev/null || $(BIN)/pip install -q 'mutmut>=3.3'  # the [mutate] extra
	env -u PYTHONPATH $(PY) scripts/mutate.py $(MUTATE_ARGS)

captures: deps
	$(CLI) gen captures/beacon-full.pcap --duration 60 --seed 1
	$(CLI) gen captures/beacon-compressed.pcap --duration 60 --seed 1 --compress --sync-interval 1

# a folder as `tshark -G folders` names it: $(call folder,Personal Lua Plugins)
folder = $$(tshark -G folders 2>/dev/null | sed -n 's/^$(1):[[:space:]]*//p' | head -1)
# the personal Lua plugin folder (else the personal plugin folder); the personal extcap folder
# ("Personal Extcap path", Wireshark 4.2+, else <Personal configuration>/extcap, where 3.x/4.0
# look); the personal configuration folder (the colorfilters file)
PLUGIN_DIR_SH = dir=$(call folder,Personal Lua Plugins); [ -n "$$dir" ] || dir=$(call folder,Personal Plugins); \
	[ -n "$$dir" ] || { echo "tshark -G folders names no personal plugin folder" >&2; exit 2; }
EXTCAP_DIR_SH = ext=$(call folder,Personal Extcap path); \
	[ -n "$$ext" ] || { c=$(call folder,Personal configuration); [ -n "$$c" ] && ext="$$c/extcap"; }; \
	[ -n "$$ext" ] || { echo "tshark -G folders names no personal extcap folder" >&2; exit 2; }
CONF_DIR_SH = conf=$(call folder,Personal configuration); glob=$(call folder,Global configuration); \
	[ -n "$$conf" ] || { echo "tshark -G folders names no personal configuration folder" >&2; exit 2; }

# every dissector/*.lua, the serial extcap (its first line pointed at the venv's Python, which
# `venv` makes sure exists and imports sharedlink.extcap) and the coloring rules
install: tshark venv
	@$(PLUGIN_DIR_SH); mkdir -p "$$dir" && cp -r $(DISSECTORS) $(DISSECTOR_MODULES) "$$dir"/ && \
	echo "installed $(notdir $(DISSECTORS) $(DISSECTOR_MODULES)) into $$dir"
	@$(PY) -c 'import sharedlink.extcap' || { echo "$(abspath $(PY)) cannot import sharedlink.extcap: run make venv" >&2; exit 2; }
	@$(EXTCAP_DIR_SH); mkdir -p "$$ext" && sed '1s|.*|#!$(abspath $(PY))|' extcap/sharedlink-serial > "$$ext/sharedlink-serial" && \
	chmod 755 "$$ext/sharedlink-serial" && echo "installed the sharedlink-serial extcap into $$ext (interpreter $(abspath $(PY)))"
	@# the coloring rules, once, at the top of the personal colorfilters (theirs kept below; with no
	@# personal file, the global default's rules are kept below ours)
	@$(CONF_DIR_SH); cf="$$conf/colorfilters"; \
	if [ -f "$$cf" ] && grep -q '^@SharedLink ' "$$cf"; then echo "SharedLink coloring rules already in $$cf"; \
	else mkdir -p "$$conf" && { [ -f "$$cf" ] && base="$$cf" || base="$$glob/colorfilters"; \
	  { cat dissector/sharedlink.colorfilters; [ -f "$$base" ] && cat "$$base"; true; } > "$$cf.new" && \
	  cat "$$cf.new" > "$$cf" && rm -f "$$cf.new" && echo "added the SharedLink coloring rules to $$cf"; }; fi

# removes what install put there: the plugins, the extcap, and the lines of
# dissector/sharedlink.colorfilters from the personal colorfilters (rules left behind would name
# fields no dissector registers: "Could not compile" at every start). A colorfilters file that is
# then the global default again (install made it from that) is removed.
uninstall: tshark
	@$(PLUGIN_DIR_SH); for f in $(notdir $(DISSECTORS)); do rm -f "$$dir/$$f"; done; \
	for m in $(notdir $(DISSECTOR_MODULES)); do rm -rf "$$dir/$$m"; done; \
	echo "removed $(notdir $(DISSECTORS) $(DISSECTOR_MODULES)) from $$dir"
	@$(EXTCAP_DIR_SH); rm -f "$$ext/sharedlink-serial"; echo "removed the sharedlink-serial extcap from $$ext"
	@$(CONF_DIR_SH); cf="$$conf/colorfilters"; \
	if [ -f "$$cf" ] && grep -qxF -f dissector/sharedlink.colorfilters "$$cf"; then \
	  { grep -vxF -f dissector/sharedlink.colorfilters "$$cf" || true; } > "$$cf.new" && cat "$$cf.new" > "$$cf" && rm -f "$$cf.new"; \
	  if [ -f "$$glob/colorfilters" ] && cmp -s "$$cf" "$$glob/colorfilters"; then rm -f "$$cf"; fi; \
	  echo "removed the SharedLink coloring rules from $$cf"; \
	else echo "no SharedLink coloring rules in $$cf"; fi

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

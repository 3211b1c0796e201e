"""The SharedLink profile's I/O graphs loaded by the real Wireshark GUI (issue 43): Wireshark (Qt)
on a virtual X display (Xvfb), started with the installed profile (``-C SharedLink``), a small
capture and ``-z io,stat`` (the Qt GUI's way to open Statistics > I/O Graphs at start, which is
when it reads the profile's ``io_graphs``; tshark never reads it: test_profile_io_graphs.py).

What the GUI shows is read off the screen (Pillow's X11 grab): the I/O Graphs window lists and
draws each graph in its colour (the table's colour swatch, the legend), so the four colours of
the profile's graphs (``#1f77b4``, ``#2ca02c``, ``#ff7f0e``, ``#d62728``) on that window mean its
records were parsed and kept; Wireshark's own graphs (when the file is missing or refused: "All
Packets", "TCP Errors") use none of them. The test can fail: the same file with one record
Wireshark's UAT loader refuses (a style it does not know) makes Wireshark show its error box
("Error while loading I/O Graphs ... Default graph values will be used": a window of its own,
found in the X window tree) and none of the profile's graphs, which is what the first test
checks first. The loader's warnings go to stderr (``[UAT WARNING] -- io_graphs:8: More fields
than required``: Wireshark 4.0.17 keeps such a record, dropping the extra column); none with the
installed file.

Long (``make test-long``): each run starts the GUI (2-10 s here). Skipped where ``wireshark``,
``Xvfb``, ``xwininfo``/``xev`` (x11-utils) or Pillow's X11 grab are missing.
"""

from __future__ import annotations

import os
import re
import select
import shutil
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from sharedlink import plugins
from tshark_util import env_for

pytestmark = pytest.mark.long
for _tool in ("wireshark", "Xvfb", "xwininfo", "xev"):
    if shutil.which(_tool) is None:
        pytest.skip(f"no {_tool} here (the GUI check needs wireshark-qt, xvfb and x11-utils)", allow_module_level=True)
ImageGrab = pytest.importorskip("PIL.ImageGrab", reason="Pillow (matplotlib's) reads the screen")

CLI = [sys.executable, "-m", "sharedlink"]
#: the profile's graphs' colours (dissector/profile/io_graphs)
COLOURS = {"SharedLink frames": (0x1F, 0x77, 0xB4), "B>A frames": (0x2C, 0xA0, 0x2C), "A>B frames": (0xFF, 0x7F, 0x0E),
           "Outage (s)": (0xD6, 0x27, 0x28)}
#: seconds Wireshark gets to show its window and draw the graphs (under load: tens of seconds)
DEADLINE_S = 120
IO_GRAPHS = "I/O Graphs"
#: a record Wireshark's loader refuses: a style it does not know
REFUSED = '"Enabled","refused","","#000000","NoSuchStyle","Packets","","None","1"\n'
_WINDOW = re.compile(r'^\s*(0x[0-9a-f]+) "(.*)": \("wireshark" "Wireshark"\)\s+(\d+)x(\d+)\+-?\d+\+-?\d+\s+\+(-?\d+)\+(-?\d+)',
                     re.M)


def wireshark_version() -> tuple[int, int]:
    out = subprocess.run(["wireshark", "--version"], capture_output=True, text=True, timeout=60,
                         env=dict(os.environ, QT_QPA_PLATFORM="offscreen")).stdout
    m = re.search(r"Wireshark (\d+)\.(\d+)", out)
    assert m, out
    return int(m.group(1)), int(m.group(2))


@pytest.fixture(scope="module")
def display() -> Iterator[str]:
    """A virtual X display of its own (``-displayfd``: Xvfb picks a free number)."""
    r, w = os.pipe()
    x = subprocess.Popen(["Xvfb", "-displayfd", str(w), "-screen", "0", "1280x1024x24", "-nolisten", "tcp", "-noreset"],
                         pass_fds=(w,), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    os.close(w)
    try:
        with os.fdopen(r) as fh:
            number = fh.readline().strip()
        assert number.isdigit(), f"Xvfb said no display: rc={x.poll()}"
        name = f":{number}"
        try:
            ImageGrab.grab(xdisplay=name, bbox=(0, 0, 1, 1))
        except OSError as exc:  # a Pillow built without XCB
            pytest.skip(f"Pillow cannot read an X display here: {exc}")
        yield name
    finally:
        x.terminate()
        x.wait(timeout=30)


def windows(env: dict[str, str]) -> dict[str, tuple[str, tuple[int, int, int, int]]]:
    """Wireshark's top-level windows: id -> (title, (left, top, right, bottom))."""
    tree = subprocess.run(["xwininfo", "-root", "-tree"], env=env, capture_output=True, text=True, timeout=60).stdout
    return {m[1]: (m[2], (int(m[5]), int(m[6]), int(m[5]) + int(m[3]), int(m[6]) + int(m[4])))
            for m in _WINDOW.finditer(tree)}


@contextmanager
def gui(tmp_path: Path, display: str, io_graphs: str | None = None) -> Iterator[tuple[dict[str, str], subprocess.Popen]]:
    """Wireshark with the installed SharedLink profile (its ``io_graphs`` replaced by
    ``io_graphs`` when given) on a two-way capture with an outage, its I/O Graphs window asked for."""
    home = tmp_path / "home"
    f = plugins.Folders(home / "plugins", home / "extcap", home / ".config" / "wireshark")
    plugins.install_profile(f, wireshark_version())
    if io_graphs is not None:
        (plugins.profile_dir(f) / "io_graphs").write_text(io_graphs)
    cap = tmp_path / "o.pcap"
    subprocess.run([*CLI, "gen", "-o", cap, "--duration", "8", "--outage", "3:2", "-q"], check=True, timeout=120)
    env = dict(env_for(home), DISPLAY=display, XDG_RUNTIME_DIR=str(tmp_path))
    env.pop("WAYLAND_DISPLAY", None)
    env.pop("QT_QPA_PLATFORM", None)
    p = subprocess.Popen(["wireshark", "-C", plugins.PROFILE, "-X", f"lua_script:{plugins.dissector_dir() / 'sharedlink.lua'}",
                          "-r", str(cap), "-z", "io,stat"], env=env, stdout=subprocess.DEVNULL,
                         stderr=open(tmp_path / "wireshark.err", "w"))  # noqa: SIM115 (closed with the process)
    try:
        yield env, p
    finally:
        p.kill()
        p.wait(timeout=30)


def until_mapped(env: dict[str, str], p: subprocess.Popen, ready) -> dict:
    """Wireshark's windows once ``ready(windows)`` holds, checked each time a window is mapped
    (``xev`` on the root window: no polling), within :data:`DEADLINE_S`."""
    xev = subprocess.Popen(["xev", "-root", "-event", "substructure"], env=env, stdout=subprocess.PIPE, bufsize=0)
    try:
        deadline = time.monotonic() + DEADLINE_S
        while True:
            found = windows(env)
            if ready(found):
                return found
            assert p.poll() is None, f"wireshark ended: rc={p.returncode}"
            left = deadline - time.monotonic()
            assert left > 0, f"no such window in {DEADLINE_S} s: {found}"
            while select.select([xev.stdout], [], [], left)[0]:  # (raw reads: no buffer select cannot see)
                chunk = os.read(xev.stdout.fileno(), 65536)  # type: ignore[union-attr]
                if not chunk or b"MapNotify" in chunk:
                    break
    finally:
        xev.kill()
        xev.wait(timeout=30)


def io_window(found: dict) -> tuple[int, int, int, int] | None:
    return next((box for title, box in found.values() if IO_GRAPHS in title), None)


def error_boxes(found: dict) -> list[str]:
    """Wireshark's message boxes: titled "Wireshark" alone (the main window has the capture's
    name, the dialog its own)."""
    return [wid for wid, (title, _box) in found.items() if title == "Wireshark"]


def colours_drawn(display: str, box: tuple[int, int, int, int], want: set, deadline: float) -> set:
    """The colours of ``want`` on the screen inside ``box``, grabbed again until all are there
    (the window draws itself after it is mapped) or ``deadline``."""
    while True:
        im = ImageGrab.grab(xdisplay=display, bbox=box)
        seen = {c for _n, c in im.getcolors(im.width * im.height)} & want
        if seen == want or time.monotonic() > deadline:
            return seen


def test_a_refused_io_graphs_shows_wiresharks_error(tmp_path, display):
    """The check's check: Wireshark complains of a record its loader refuses, in a window of its
    own, and keeps none of the profile's graphs."""
    text = plugins.io_graphs_text(wireshark_version()) + REFUSED
    with gui(tmp_path, display, text) as (env, p):
        found = until_mapped(env, p, lambda w: io_window(w) is not None and error_boxes(w))
        assert len(error_boxes(found)) == 1, found
        box = io_window(found)
        # the dialog drawn (its white plot) without any of the profile's colours
        assert colours_drawn(display, box, {(255, 255, 255)}, time.monotonic() + DEADLINE_S)
        assert not colours_drawn(display, box, set(COLOURS.values()), 0)


def test_the_installed_io_graphs_are_loaded(tmp_path, display):
    """The installed file: every graph of it on the I/O Graphs window, in its colour; no error
    box, no warning of Wireshark's UAT loader on stderr."""
    with gui(tmp_path, display) as (env, p):
        found = until_mapped(env, p, lambda w: io_window(w) is not None)
        box = io_window(found)
        seen = colours_drawn(display, box, set(COLOURS.values()), time.monotonic() + DEADLINE_S)
        assert seen == set(COLOURS.values()), {n for n, c in COLOURS.items() if c not in seen}
        assert not error_boxes(windows(env)), windows(env)
    err = (tmp_path / "wireshark.err").read_text()
    assert "[UAT" not in err and "io_graphs" not in err, err


def test_a_later_releases_column_is_dropped_with_a_warning(tmp_path, display):
    """Why ``install --profile`` writes the release's columns: 4.6's file (a tenth column, asAOT)
    on an earlier GUI is loaded, each record with a warning on stderr, its extra column dropped
    (Wireshark 4.0.17; not the error test_profile_io_graphs.py's loader rules say)."""
    if wireshark_version() >= plugins.IO_GRAPHS_AOT:
        pytest.skip("this Wireshark knows the tenth column")
    with gui(tmp_path, display, plugins.io_graphs_text(plugins.IO_GRAPHS_AOT)) as (env, p):
        box = io_window(until_mapped(env, p, lambda w: io_window(w) is not None))
        assert colours_drawn(display, box, set(COLOURS.values()), time.monotonic() + DEADLINE_S) == set(COLOURS.values())
    err = (tmp_path / "wireshark.err").read_text()
    assert len(re.findall(r"\[UAT WARNING\] -- io_graphs:\d+: More fields than required", err)) == len(COLOURS), err

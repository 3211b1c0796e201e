"""Put the dissectors, the serial extcap and the coloring rules into a user's Wireshark folders,
and take them out again (``sharedlink plugins install|uninstall|path``; ``make install`` runs it).

The folders are the ones ``tshark -G folders`` names for the user running it:

* plugins: "Personal Lua Plugins" (else "Personal Plugins"): every ``*.lua`` of the package's
  dissector folder, subfolders kept;
* extcap: "Personal Extcap path" (Wireshark 4.2+), else ``<Personal configuration>/extcap``
  (where 3.x/4.0 look): the ``sharedlink-serial`` launcher, its first line pointed at the Python
  running this (which imports ``sharedlink.extcap``);
* coloring rules: ``<Personal configuration>/colorfilters``: ours once at the top, the user's
  own rules kept below (with no personal file yet, the global default's rules below ours, as
  Wireshark would have shown them). Uninstall removes our lines, and our rules also when the
  user edited or disabled one in the GUI (a disabled rule is written ``!@name@...``); a file
  that is then the global default again (install made it from that) is removed.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

from sharedlink.errors import Error
from sharedlink.wireshark import colorfilters_file, dissector_dir, dissector_files, extcap_launcher

EXTCAP_NAME = "sharedlink-serial"
#: a coloring rule's line: optional "!" (disabled), then @name@
_RULE = re.compile(r"!?@([^@]*)@")


class PluginsError(Error):
    """tshark missing or naming no personal folder, or a folder that cannot be written."""


@dataclass
class Folders:
    """The personal folders of one Wireshark (``tshark -G folders``)."""

    plugins: Path
    extcap: Path
    config: Path
    global_config: Path | None = None

    @property
    def colorfilters(self) -> Path:
        return self.config / "colorfilters"


@dataclass
class Report:
    """What install or uninstall did, one line each."""

    lines: list[str] = field(default_factory=list)

    def add(self, line: str) -> None:
        self.lines.append(line)


def parse_folders(text: str) -> Folders:
    """The folders of ``tshark -G folders`` output (``Name:<tab>path`` lines)."""
    named: dict[str, str] = {}
    for line in text.splitlines():
        name, sep, path = line.partition(":")
        if sep and path.strip() and name.strip() not in named:
            named[name.strip()] = path.strip()
    plugins = named.get("Personal Lua Plugins") or named.get("Personal Plugins")
    config = named.get("Personal configuration")
    if not plugins:
        raise PluginsError("tshark -G folders names no personal plugin folder")
    if not config:
        raise PluginsError("tshark -G folders names no personal configuration folder")
    extcap = named.get("Personal Extcap path") or os.path.join(config, "extcap")
    glob = named.get("Global configuration")
    return Folders(Path(plugins), Path(extcap), Path(config), Path(glob) if glob else None)


def folders(tshark: str = "tshark") -> Folders:
    """The personal folders the given tshark names (for this user, this environment)."""
    exe = shutil.which(tshark)
    if exe is None:
        raise PluginsError(f"{tshark}: not found (install Wireshark's tshark, e.g. apt-get install tshark)")
    try:
        r = subprocess.run([exe, "-G", "folders"], capture_output=True, text=True, timeout=60)
    except (OSError, subprocess.SubprocessError) as exc:
        raise PluginsError(f"{tshark} -G folders: {exc}") from None
    if r.returncode != 0:
        raise PluginsError(f"{tshark} -G folders: exit {r.returncode}: {r.stderr.strip()[:200]}")
    return parse_folders(r.stdout)


def _rule_lines() -> list[str]:
    return colorfilters_file().read_text().splitlines()


def _rule_names(lines: list[str]) -> set[str]:
    return {m.group(1) for m in map(_RULE.match, lines) if m is not None}


def _ours(line: str, lines: set[str], names: set[str]) -> bool:
    if line in lines:
        return True
    m = _RULE.match(line)
    return m is not None and m.group(1) in names


def _write(path: Path, text: str) -> None:
    """``text`` into ``path`` (written beside it, then renamed over it)."""
    tmp = path.with_name(path.name + ".new")
    tmp.write_text(text)
    os.replace(tmp, path)


def install(f: Folders, python: str = sys.executable) -> Report:
    report = Report()
    src = dissector_dir()
    files = dissector_files()
    try:
        for p in files:
            dest = f.plugins / p.relative_to(src)
            dest.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(p, dest)
        report.add(f"installed {', '.join(str(p.relative_to(src)) for p in files)} into {f.plugins}")
        launcher = extcap_launcher().read_text().splitlines(keepends=True)
        f.extcap.mkdir(parents=True, exist_ok=True)
        dest = f.extcap / EXTCAP_NAME
        _write(dest, "".join([f"#!{python}\n", *launcher[1:]]))
        dest.chmod(0o755)
        report.add(f"installed the {EXTCAP_NAME} extcap into {f.extcap} (interpreter {python})")
        rules = _rule_lines()
        cf = f.colorfilters
        names = _rule_names(rules)
        mine = cf.read_text().splitlines() if cf.is_file() else []
        if _rule_names(mine) & names:  # enabled or disabled in the GUI: installed already
            report.add(f"SharedLink coloring rules already in {cf}")
        else:
            base = cf if cf.is_file() else (f.global_config / "colorfilters" if f.global_config else None)
            below = base.read_text() if base is not None and base.is_file() else ""
            f.config.mkdir(parents=True, exist_ok=True)
            _write(cf, colorfilters_file().read_text() + below)
            report.add(f"added the SharedLink coloring rules to {cf}")
    except OSError as exc:
        raise PluginsError(f"{exc.filename or ''}: {exc.strerror or exc}") from None
    return report


def uninstall(f: Folders) -> Report:
    report = Report()
    src = dissector_dir()
    try:
        removed = []
        for p in dissector_files():
            dest = f.plugins / p.relative_to(src)
            if dest.is_file():
                dest.unlink()
                removed.append(str(p.relative_to(src)))
            # subfolders install made, when they are empty again
            parent = dest.parent
            while parent != f.plugins and f.plugins in parent.parents and parent.is_dir() and not any(parent.iterdir()):
                parent.rmdir()
                parent = parent.parent
        report.add(f"removed {', '.join(removed) or 'no plugin'} from {f.plugins}")
        ext = f.extcap / EXTCAP_NAME
        if ext.is_file():
            ext.unlink()
            report.add(f"removed the {EXTCAP_NAME} extcap from {f.extcap}")
        else:
            report.add(f"no {EXTCAP_NAME} extcap in {f.extcap}")
        cf = f.colorfilters
        rules = _rule_lines()
        lines, names = set(rules), _rule_names(rules)
        text = cf.read_text() if cf.is_file() else ""
        kept = [ln for ln in text.splitlines(keepends=True) if not _ours(ln.rstrip("\r\n"), lines, names)]
        if cf.is_file() and len(kept) != len(text.splitlines()):
            rest = "".join(kept)
            glob = f.global_config / "colorfilters" if f.global_config else None
            if glob is not None and glob.is_file() and glob.read_text() == rest:
                cf.unlink()
            else:
                _write(cf, rest)
            report.add(f"removed the SharedLink coloring rules from {cf}")
        else:
            report.add(f"no SharedLink coloring rules in {cf}")
    except OSError as exc:
        raise PluginsError(f"{exc.filename or ''}: {exc.strerror or exc}") from None
    return report


#: the configuration profile ``install --profile`` makes (issue 43): its name and files
PROFILE = "SharedLink"
PROFILE_FILES = ("preferences", "dfilter_buttons", "colorfilters", "io_graphs")
#: the release whose I/O graphs table (``io_graphs``) has a tenth column, asAOT ("Avg over Time"),
#: after the nine of 3.6-4.4 that ``dissector/profile/io_graphs`` is written in: a record with more
#: columns than a release knows is an error there ("more fields than required"); 4.6 reads a record
#: of nine with its default for the tenth (its I/O graph dialog's defaults, kept for older profiles)
IO_GRAPHS_AOT = (4, 6)


def tshark_version(tshark: str = "tshark") -> tuple[int, int] | None:
    """The Wireshark release (major, minor) of ``tshark --version``, or None when it says none."""
    exe = shutil.which(tshark)
    if exe is None:
        return None
    try:
        out = subprocess.run([exe, "--version"], capture_output=True, text=True, timeout=60).stdout
    except (OSError, subprocess.SubprocessError):
        return None
    m = re.search(r"\(Wireshark\) (\d+)\.(\d+)", out)
    return (int(m.group(1)), int(m.group(2))) if m else None


def io_graphs_text(version: tuple[int, int] | None) -> str:
    """The profile's ``io_graphs`` for a release (None: unknown, the columns of 3.6-4.4, which
    4.6 and later read too): each record with the asAOT column ("Disabled") from 4.6 on."""
    text = (dissector_dir() / "profile" / "io_graphs").read_text()
    if version is None or version < IO_GRAPHS_AOT:
        return text
    return "".join(ln if ln.startswith("#") or not ln.strip() else ln.rstrip("\r\n") + ',"Disabled"\n'
                   for ln in text.splitlines(keepends=True))


def profile_dir(f: Folders) -> Path:
    return f.config / "profiles" / PROFILE


def install_profile(f: Folders, version: tuple[int, int] | None = None) -> Report:
    """The SharedLink profile (columns, filter buttons, coloring rules with the outage rule, I/O
    graphs in the columns of ``version``, the Wireshark release) into
    ``<Personal configuration>/profiles/SharedLink`` (Edit > Configuration Profiles)."""
    report = Report()
    dest = profile_dir(f)
    try:
        dest.mkdir(parents=True, exist_ok=True)
        for name in PROFILE_FILES:
            text = io_graphs_text(version) if name == "io_graphs" else (dissector_dir() / "profile" / name).read_text()
            _write(dest / name, text)
    except OSError as exc:
        raise PluginsError(f"{exc.filename or ''}: {exc.strerror or exc}") from None
    cols = "of Wireshark 4.6+" if version is not None and version >= IO_GRAPHS_AOT else "of Wireshark 3.6-4.4"
    report.add(f"installed the {PROFILE} configuration profile into {dest} (I/O graphs in the columns {cols})")
    return report


def uninstall_profile(f: Folders) -> Report:
    """The profile's files out again (the folder too when nothing else is in it)."""
    report = Report()
    dest = profile_dir(f)
    try:
        gone = [n for n in PROFILE_FILES if (dest / n).is_file()]
        for n in gone:
            (dest / n).unlink()
        if dest.is_dir() and not any(dest.iterdir()):
            dest.rmdir()
    except OSError as exc:
        raise PluginsError(f"{exc.filename or ''}: {exc.strerror or exc}") from None
    report.add(f"removed the {PROFILE} configuration profile from {dest}" if gone else f"no {PROFILE} profile in {dest}")
    return report


def paths(f: Folders) -> dict[str, str]:
    """Where the files come from and where install puts them."""
    return {
        "dissectors": str(dissector_dir()),
        "extcap_launcher": str(extcap_launcher()),
        "plugins": str(f.plugins),
        "extcap": str(f.extcap / EXTCAP_NAME),
        "colorfilters": str(f.colorfilters),
        "profile": str(profile_dir(f)),
    }

"""The package layout pyproject.toml cannot say: pytools/sharedlink with its subpackages, and
the repository's dissector/ and extcap/ folders as the package data folders
sharedlink/dissector (every *.lua, subfolders included, the coloring rules and the configuration
profile's files, profile/*) and
sharedlink/extcap_launcher (sharedlink.wireshark finds them there when installed, and in the
checkout when run from it)."""

from pathlib import Path

from setuptools import find_packages, setup

HERE = Path(__file__).resolve().parent
# a subfolder of dissector/ with Lua modules is a data package of its own (setuptools warns
# about folders it would otherwise take for undeclared packages)
LUA_DIRS = sorted({p.parent.relative_to(HERE / "dissector") for p in (HERE / "dissector").rglob("*.lua")})
LUA_PACKAGES = [".".join(("sharedlink.dissector", *d.parts)) for d in LUA_DIRS]

setup(
    packages=[*find_packages("pytools"), *LUA_PACKAGES, "sharedlink.extcap_launcher"],
    package_dir={"": "pytools", "sharedlink.dissector": "dissector", "sharedlink.extcap_launcher": "extcap"},
    package_data={
        **{pkg: ["*.lua"] for pkg in LUA_PACKAGES},
        "sharedlink.dissector": ["*.lua", "sharedlink.colorfilters", "profile/*"],
        "sharedlink.extcap_launcher": ["sharedlink-serial"],
    },
)

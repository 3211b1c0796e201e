"""The package layout pyproject.toml cannot say: pytools/sharedlink with its subpackages, and
the repository's dissector/ and extcap/ folders as the package data folders
sharedlink/dissector and sharedlink/extcap_launcher (sharedlink.wireshark finds them there when
installed, and in the checkout when run from it)."""

from setuptools import find_packages, setup

setup(
    packages=[*find_packages("pytools"), "sharedlink.dissector", "sharedlink.extcap_launcher"],
    package_dir={"": "pytools", "sharedlink.dissector": "dissector", "sharedlink.extcap_launcher": "extcap"},
)

"""The unit of each shared variable whose unit the bulletins or the field notes give: one table
for the decoder's views, plots and exports (``unit_of``, ``label``).

Sources: BUL-049 (AutoGpsLat/AutoGpsLon/AutoGpsHead in degrees, AutoGpsVel in mph), the Kairos
shared-variable dictionary as the team's notes read it (``throttle``, ``bbrake``, ``fbrake``
0-100 %, ``spd`` mph). A name not in the table has no known unit (``None``): its values are
shown bare, never with a guessed unit.
"""

from __future__ import annotations

#: degrees (angles and WGS 84 coordinates)
DEGREES = "°"
#: miles per hour (BUL-049: AutoGpsVel)
MPH = "mph"
PERCENT = "%"

#: variable name -> unit
UNITS: dict[str, str] = {
    "AutoGpsLat": DEGREES,
    "AutoGpsLon": DEGREES,
    "AutoGpsHead": DEGREES,
    "AutoGpsVel": MPH,
    "spd": MPH,
    "throttle": PERCENT,
    "bbrake": PERCENT,
    "fbrake": PERCENT,
}


def unit_of(name: str) -> str | None:
    """The unit of variable ``name`` (a per-pair name ``B>A:name`` too), or None."""
    return UNITS.get(name.rsplit(":", 1)[-1])


def label(name: str) -> str:
    """``AutoGpsVel (mph)``: the name with its unit when known."""
    unit = unit_of(name)
    return f"{name} ({unit})" if unit else name

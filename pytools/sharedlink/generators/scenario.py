"""A vehicle driving a plausible track: the data behind generated beacons.

Heading is degrees clockwise from north and always the direction of travel; velocity is in
mph (BUL-049's example unit) and the distance between two fixes is what that speed covers in
the time between them. The drive is a list of legs (stop, accelerate, cruise, turn, brake)
drawn from a seeded random generator, so the same seed gives the same drive.
"""

from __future__ import annotations

import math
import random
from collections.abc import Iterator
from dataclasses import dataclass

EARTH_RADIUS_M = 6_371_000.0
MPH = 0.44704  # m/s per mph

#: BUL-009's example position (near the Kairos Autonomi test ground)
START_LAT = 38.34698779
START_LON = -77.05734791
START_HEADING = 57.0


@dataclass(frozen=True)
class Fix:
    t: float  # seconds from the start
    lat: float
    lon: float
    heading: float  # degrees, [0, 360)
    speed: float  # mph


@dataclass(frozen=True)
class Leg:
    duration: float  # s
    accel: float  # mph per second
    turn_rate: float  # degrees per second (positive: right)


def plan_legs(rng: random.Random, duration: float) -> list[Leg]:
    """A drive: start stopped, then cruise / turn / stop legs until ``duration`` is covered."""
    legs = [Leg(2.0, 0.0, 0.0), Leg(6.0, 4.0, 0.0)]  # parked, then up to 24 mph
    speed = 24.0
    total = sum(leg.duration for leg in legs)
    while total < duration:
        r = rng.random()
        if r < 0.45:
            leg = Leg(rng.choice((4.0, 6.0, 8.0, 10.0)), 0.0, 0.0)  # cruise
        elif r < 0.75:
            turn = rng.choice((-90.0, -45.0, 30.0, 45.0, 90.0))
            rate = 15.0 if turn > 0 else -15.0
            leg = Leg(abs(turn) / 15.0, 0.0, rate)
        elif r < 0.9:
            target = rng.choice((12.0, 18.0, 30.0, 35.0))
            leg = Leg(2.0, (target - speed) / 2.0, 0.0)
            speed = target
        else:  # brake, wait, pull away
            legs.append(Leg(3.0, -speed / 3.0, 0.0))
            legs.append(Leg(rng.choice((2.0, 3.0, 4.0)), 0.0, 0.0))
            speed = rng.choice((15.0, 20.0, 25.0))
            leg = Leg(3.0, speed / 3.0, 0.0)
            total += legs[-1].duration + legs[-2].duration
        legs.append(leg)
        total += leg.duration
    return legs


def drive(seed: int, duration: float, rate: float) -> Iterator[Fix]:
    """Fixes at ``rate`` Hz for ``duration`` seconds (``duration * rate`` fixes)."""
    dt = 1.0 / rate
    for i, (lat, lon, heading, speed) in enumerate(drive_tuples(seed, duration, rate)):
        yield Fix(i * dt, lat, lon, heading, speed)


def drive_tuples(seed: int, duration: float, rate: float) -> Iterator[tuple[float, float, float, float]]:
    """(lat, lon, heading, speed) at ``rate`` Hz: the generator's hot path."""
    rng = random.Random(seed)
    legs = plan_legs(rng, duration)
    legs.append(Leg(1e18, 0.0, 0.0))  # keep going steady after the plan
    dt = 1.0 / rate
    lat, lon, heading, speed = START_LAT, START_LON, START_HEADING, 0.0
    li, left = 0, legs[0].duration
    accel, turn = legs[0].accel, legs[0].turn_rate
    n = int(round(duration * rate))
    deg = 180.0 / math.pi
    k = MPH / EARTH_RADIUS_M * deg  # metres -> degrees of latitude, per mph-second
    cos, sin, rad = math.cos, math.sin, math.radians
    cos_lat = cos(rad(lat))
    for _ in range(n):
        yield lat, lon, heading, speed
        # advance dt through the legs (a step may span a leg boundary)
        step = dt
        while step > 1e-12:
            h = step if step < left else left
            new_speed = speed + accel * h
            if new_speed < 0.0:
                new_speed = 0.0
            avg = (speed + new_speed) * 0.5
            if turn and avg > 0.0:  # a stopped vehicle does not turn
                new_heading = (heading + turn * h) % 360.0
                mid = rad(heading + turn * h * 0.5)
            else:
                new_heading = heading
                mid = rad(heading)
            if avg > 0.0:
                dist = avg * h * k
                lat += dist * cos(mid)
                lon += dist * sin(mid) / cos_lat
                cos_lat = cos(rad(lat))
            heading, speed = new_heading, new_speed
            step -= h
            left -= h
            if left <= 1e-12:
                li += 1
                leg = legs[li]
                left, accel, turn = leg.duration, leg.accel, leg.turn_rate


def distance_m(lat1: float, lon1: float, lat2: float, lon2: float) -> float:
    """Great-circle distance (haversine)."""
    p1, p2 = math.radians(lat1), math.radians(lat2)
    dp, dl = p2 - p1, math.radians(lon2 - lon1)
    a = math.sin(dp / 2) ** 2 + math.cos(p1) * math.cos(p2) * math.sin(dl / 2) ** 2
    return 2 * EARTH_RADIUS_M * math.asin(math.sqrt(a))


def bearing_deg(lat1: float, lon1: float, lat2: float, lon2: float) -> float:
    """Initial bearing from point 1 to point 2, degrees clockwise from north."""
    p1, p2 = math.radians(lat1), math.radians(lat2)
    dl = math.radians(lon2 - lon1)
    x = math.sin(dl) * math.cos(p2)
    y = math.cos(p1) * math.sin(p2) - math.sin(p1) * math.cos(p2) * math.cos(dl)
    return math.degrees(math.atan2(x, y)) % 360.0

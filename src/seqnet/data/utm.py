"""Latitude / longitude to UTM metres (``utm``), and the positions frame those metres are in (``UTM zone 32V``):
the one conversion of GPS logs, MSLS, bag NavSatFix topics and video tracks."""

from __future__ import annotations

import re

import numpy as np

from ..core.errors import DatasetError

UTM_FRAME = re.compile(r"UTM zone ([0-9]{1,2})([C-HJ-NP-X])")  # the positions frame of UTM metres: "UTM zone 32V"


def frame_zone(frame: str | None) -> tuple[int, str] | None:
    """``(number, band letter)`` of a positions frame ``UTM zone 32V``; None for another frame (or None)."""
    m = UTM_FRAME.fullmatch(frame or "")
    return None if m is None else (int(m.group(1)), m.group(2))


def latlon_to_utm(lat: np.ndarray, lon: np.ndarray, where: str,
                  zone: tuple[int, str] | None = None) -> tuple[np.ndarray, str]:
    """``[N, 2]`` UTM easting/northing of WGS84 ``lat, lon`` (degrees), all in ``zone`` (``(32, "U")``; default:
    the zone of the first point); and that zone (e.g. ``"32U"``). Out-of-range coordinates are refused with their
    index."""
    import utm

    lat, lon = np.asarray(lat, dtype=np.float64), np.asarray(lon, dtype=np.float64)
    bad = np.flatnonzero(~((lat >= -80) & (lat <= 84) & (np.abs(lon) <= 180)))
    if bad.size:
        i = int(bad[0])
        raise DatasetError(f"{where}: sample {i}: latitude {float(lat[i])}, longitude {float(lon[i])} out of range "
                           "(UTM covers latitudes -80..84 and longitudes -180..180, degrees)")
    if zone is None:
        _, _, number, letter = utm.from_latlon(lat[:1], lon[:1])
        zone = (int(number), str(letter))
    try:
        e, n, _, _ = utm.from_latlon(lat, lon, force_zone_number=zone[0], force_zone_letter=zone[1])
    except ValueError as err:  # utm.error.OutOfRangeError: too far from the zone asked for
        raise DatasetError(f"{where}: cannot place its points in UTM zone {zone[0]}{zone[1]} ({err})") from err
    return np.stack([e, n], axis=1), f"{zone[0]}{zone[1]}"


SWAP_FAR = 1.0  # degrees: traverses' centres further apart than this ...
SWAP_NEAR = 0.1  # ... and within this once one traverse's lat and lon are swapped: its columns are swapped


def check_latlon(latlon: np.ndarray, where: str, lines: list[int] | None = None) -> None:
    """Refuse ``latlon [N, 2]`` (latitude, longitude in degrees) with a latitude outside -90..90 or a longitude
    outside -180..180, naming the row (``lines``: its line in the file) and the likely cause: the two columns
    swapped (every value fits the other column), or metres under lat/lon names."""
    lat, lon = latlon[:, 0], latlon[:, 1]
    bad = np.flatnonzero((np.abs(lat) > 90) | (np.abs(lon) > 180))
    if not bad.size:
        return
    i = int(bad[0])
    row = f"line {lines[i]}" if lines is not None else f"row {i}"
    swapped = bool((np.abs(lon) <= 90).all() and (np.abs(lat) <= 180).all())
    metres = "metres under lat/lon names? name them easting,northing"
    scale = next((k for k in (7, 6) if (np.abs(lat) <= 90 * 10**k).all() and (np.abs(lon) <= 180 * 10**k).all()
                  and (np.abs(lat) > 90 * 10 ** (k - 1)).any()), None) if _integral(latlon) else None
    scaled = f"degrees × 10^{scale} (integers, as Android and OSM write them)? divide the lat and lon columns by " \
        f"1e{scale}" + ("" if scale == 7 else f"; or {metres}")  # UTM northings stay below 9e7: not E7
    hint = ("the lat and lon columns are swapped (every longitude is a valid latitude): swap their names in the "
            "header" if swapped else scaled if scale is not None else metres)
    raise DatasetError(f"{where}, {row}: latitude {float(lat[i]):g}, longitude {float(lon[i]):g} out of range "
                       f"(latitude -90..90, longitude -180..180 degrees); hint: {hint}")


def _integral(a: np.ndarray) -> bool:
    """Whether every value of ``a`` is a whole number."""
    return bool(np.all(a == np.round(a)))


def latlon_pair(ref: np.ndarray, query: np.ndarray, where: tuple[str, str]) -> tuple[np.ndarray, np.ndarray, str]:
    """``(ref [N, 2], query [M, 2], frame)``: both traverses' ``lat, lon`` degrees as UTM metres, the query in the
    reference's zone (its first point's), and that positions frame (``UTM zone 33W``). Traverses whose centres lie
    more than :data:`SWAP_FAR` degrees apart, within :data:`SWAP_NEAR` once one's lat and lon are swapped, are
    refused (which one is swapped the numbers cannot say: both files are named)."""
    centre = [np.median(np.asarray(p, np.float64), axis=0) for p in (ref, query)]
    apart = float(np.abs(centre[0] - centre[1]).max())
    if apart > SWAP_FAR and float(np.abs(centre[0][::-1] - centre[1]).max()) <= SWAP_NEAR:
        raise DatasetError(f"the lat and lon columns of {where[0]} or of {where[1]} look swapped: as given their "
                           f"positions lie {apart:.1f} degrees apart, with one file's two columns swapped they meet; "
                           "hint: swap the two column names in the header of the wrong one")
    r, zone = latlon_to_utm(ref[:, 0], ref[:, 1], where[0])
    q, _ = latlon_to_utm(query[:, 0], query[:, 1], where[1], (int(zone[:-1]), zone[-1]))
    return r, q, f"UTM zone {zone}"


UNIT_WORDS = {"degrees": "latitude / longitude degrees", "metres": "easting / northing metres",
              "frames": "frame numbers"}  # a positions CSV's units (seqnet.data.convert.csvfile), in messages


def mixed_frames(reference: str, query: str, files: str = "positions files") -> str:
    """The one-line message for traverses whose positions are in two frames, ``reference`` and ``query`` each a
    CSV's unit (:data:`UNIT_WORDS`) or a positions frame (``UTM zone 32V``, a track's ``x, y metres ...``), with the
    hint to give both ``files`` one kind of positions."""
    said = [UNIT_WORDS.get(f, f if f.startswith("x, y") else f"metres in {f}") for f in (reference, query)]
    kinds = "latitude / longitude in both, or easting / northing (x, y) metres of one frame in both"
    if "frames" in (reference, query):
        kinds = "latitude / longitude in both, easting / northing metres in both, or frame numbers in both"
    return (f"the reference positions are {said[0]} and the query positions {said[1]}: positions in two frames do "
            f"not compare; hint: give both {files} one kind of positions ({kinds})")

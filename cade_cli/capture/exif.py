"""A band file's EXIF read as typed TIFF entries (its first IFD, EXIF IFD and GPS IFD), and those
entries written into a TIFF that tifffile has just written.

tifffile cannot write IFD-type tags: its ``extratags`` drops the ExifIFD (34665) and GPSIFD
(34853) pointers. :func:`add_tags` patches the finished file instead: it appends a copy of the
first IFD with the given tags merged in and the two pointers added, then the EXIF and GPS
sub-IFDs, and points the header at the new IFD (the old one and its tag values stay behind,
unused: about 14 kB of the field capture's 24.6 MB cube). Classic TIFF and BigTIFF, either byte order; no external program (docs/drone.md,
"Metadata the mapping tools read").
"""

from __future__ import annotations

import struct
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path

from cade_cli.errors import CadeError

EXIF_IFD, GPS_IFD = 34665, 34853
TYPE_FORMATS = {1: "B", 2: "s", 3: "H", 4: "I", 5: "I", 6: "b", 7: "s", 8: "h", 9: "i", 10: "i", 11: "f", 12: "d",
                13: "I", 16: "Q", 17: "q", 18: "Q"}
"""TIFF field type -> struct code of one item (rationals: two items a value)."""
TYPE_SIZES = {1: 1, 2: 1, 3: 2, 4: 4, 5: 8, 6: 1, 7: 1, 8: 2, 9: 4, 10: 8, 11: 4, 12: 8, 13: 4, 16: 8, 17: 8, 18: 8}
BYTES, ASCII, SHORT, LONG, RATIONAL, UNDEFINED = 1, 2, 3, 4, 5, 7

MAIN_CARRIED = {271: "Make", 272: "Model", 274: "Orientation", 306: "DateTime", 50713: "BlackLevelRepeatDim",
                50714: "BlackLevel", 50735: "CameraSerialNumber"}
"""The first-IFD tags a registered file takes from its source (the pixel layout's own tags are
the writer's)."""
EXIF_DROPPED = {37500: "MakerNote", 40965: "InteroperabilityIFD"}
"""EXIF tags not copied: the maker note holds offsets into the source file."""
TIFF_EP_TO_EXIF = {37386: 37386, 37390: 41486, 37391: 41487, 37392: 41488}
"""TIFF/EP tags of the first IFD (FocalLength, FocalPlaneX/YResolution and unit) -> their EXIF codes."""
GEOMETRY_EXIF = (37386, 41486, 41487, 41488)
"""FocalLength and FocalPlaneX/YResolution + unit: the lens of the pixels (the reference's)."""
SUB_SEC_TIME, SUB_SEC_TIME_ORIGINAL, DATE_TIME_ORIGINAL = 37520, 37521, 36867


@dataclass(frozen=True)
class Entry:
    """One TIFF tag: ``code``, field ``type`` and ``value`` (bytes for BYTE/ASCII/UNDEFINED,
    with ASCII's trailing NUL; a tuple of numbers otherwise, rationals as numerator, denominator
    pairs)."""

    code: int
    type: int
    value: bytes | tuple

    @property
    def count(self) -> int:
        if isinstance(self.value, bytes):
            return len(self.value)
        return len(self.value) // 2 if self.type in (5, 10) else len(self.value)

    def text(self) -> str:
        return self.value.rstrip(b"\0").decode("latin-1").strip() if isinstance(self.value, bytes) else ""

    def numbers(self) -> list[float]:
        """The values as floats (rationals divided; a zero denominator gives NaN)."""
        if isinstance(self.value, bytes):
            return list(self.value)
        if self.type in (5, 10):
            pairs = zip(self.value[::2], self.value[1::2])
            return [n / d if d else float("nan") for n, d in pairs]
        return [float(v) for v in self.value]


def ascii_entry(code: int, text: str) -> Entry:
    return Entry(code, ASCII, text.encode("latin-1", "replace") + b"\0")


def rational_entry(code: int, values: Iterable[float]) -> Entry:
    pairs = []
    for value in values:
        fraction = Fraction(value).limit_denominator(1_000_000)
        pairs += [fraction.numerator, fraction.denominator]
    return Entry(code, RATIONAL, tuple(pairs))


@dataclass(frozen=True)
class SourceExif:
    """What a band file carries: its first IFD's carried tags (:data:`MAIN_CARRIED`), its EXIF
    entries (the TIFF/EP lens tags of its first IFD moved in), its GPS entries; each code -> :class:`Entry`."""

    main: Mapping[int, Entry]
    exif: Mapping[int, Entry]
    gps: Mapping[int, Entry]

    def has_fix(self) -> bool:
        """Whether the GPS IFD holds a position: latitude and longitude present, not both zero,
        and GPSStatus not ``V`` (void; the Sequoia without a fix). A bench camera with no fix
        writes 0, 0."""
        status = self.gps.get(9)
        if status is not None and status.text().upper() == "V":
            return False
        latitude, longitude = self.gps.get(2), self.gps.get(4)
        if latitude is None or longitude is None:
            return False
        values = latitude.numbers() + longitude.numbers()
        return len(values) == 6 and all(v == v for v in values) and any(v != 0 for v in values)


class _Reader:
    def __init__(self, handle, path: Path) -> None:
        self.handle, self.path = handle, path
        header = handle.read(16)
        if header[:2] not in (b"II", b"MM"):
            raise CadeError(f"{path}: not a TIFF (no byte-order mark)")
        self.order = "<" if header[:2] == b"II" else ">"
        version = struct.unpack(self.order + "H", header[2:4])[0]
        if version not in (42, 43):
            raise CadeError(f"{path}: not a TIFF (version {version})")
        self.big = version == 43
        pointer = header[8:16] if self.big else header[4:8]
        self.first = struct.unpack(self.order + ("Q" if self.big else "I"), pointer)[0]

    def read(self, offset: int, size: int) -> bytes:
        self.handle.seek(offset)
        data = self.handle.read(size)
        if len(data) != size:
            raise CadeError(f"{self.path}: truncated TIFF (an IFD points past its end)")
        return data

    def ifd(self, offset: int) -> tuple[list[Entry], int]:
        """The entries of the IFD at ``offset`` and the next IFD's offset."""
        o = self.order
        count_format, entry_format, inline = ("Q", "HHQ8s", 8) if self.big else ("H", "HHI4s", 4)
        count_size = struct.calcsize(count_format)
        count = struct.unpack(o + count_format, self.read(offset, count_size))[0]
        entry_size = struct.calcsize("=" + entry_format)
        raw = self.read(offset + count_size, count * entry_size + inline)
        entries = []
        for k in range(count):
            code, kind, n, field = struct.unpack(o + entry_format, raw[k * entry_size:(k + 1) * entry_size])
            if kind not in TYPE_SIZES:
                continue  # an unknown type: cannot be carried
            size = n * TYPE_SIZES[kind]
            data = field[:size] if size <= inline else self.read(struct.unpack(o + ("Q" if self.big else "I"),
                                                                              field)[0], size)
            entries.append(Entry(code, kind, _decode(data, kind, n, o)))
        return entries, struct.unpack(o + ("Q" if self.big else "I"), raw[count * entry_size:])[0]


def _decode(data: bytes, kind: int, count: int, order: str) -> bytes | tuple:
    if kind in (1, 2, 7):
        return bytes(data)
    items = count * (2 if kind in (5, 10) else 1)
    return struct.unpack(f"{order}{items}{TYPE_FORMATS[kind]}", data)


def _encode(entry: Entry, order: str) -> bytes:
    if isinstance(entry.value, bytes):
        return entry.value
    return struct.pack(f"{order}{len(entry.value)}{TYPE_FORMATS[entry.type]}", *entry.value)


def read_source_exif(path: Path) -> SourceExif:
    """The :class:`SourceExif` of a band file (its first IFD).

    Raises:
        CadeError: not a TIFF, or an IFD pointing past the end of the file.
    """
    try:
        with open(path, "rb") as handle:
            reader = _Reader(handle, Path(path))
            main_entries, _ = reader.ifd(reader.first)
            main = {entry.code: entry for entry in main_entries}
            exif, gps = {}, {}
            for pointer, found in ((EXIF_IFD, exif), (GPS_IFD, gps)):
                if pointer in main and main[pointer].value:
                    entries, _ = reader.ifd(int(main[pointer].value[0]))
                    found.update((entry.code, entry) for entry in entries if entry.type not in (13, 18))
    except (OSError, struct.error) as error:
        raise CadeError(f"{path}: cannot read its EXIF ({error})") from None
    for code in EXIF_DROPPED:
        exif.pop(code, None)
    for ep, code in TIFF_EP_TO_EXIF.items():
        if code not in exif and ep in main:
            exif[code] = Entry(code, main[ep].type, main[ep].value)
    if SUB_SEC_TIME_ORIGINAL not in exif and SUB_SEC_TIME in exif and DATE_TIME_ORIGINAL in exif and (
            306 not in main or main[306].text() == exif[DATE_TIME_ORIGINAL].text()):
        # MicaSense writes SubSecTime only: the sub-seconds of DateTime, which is DateTimeOriginal
        exif[SUB_SEC_TIME_ORIGINAL] = Entry(SUB_SEC_TIME_ORIGINAL, exif[SUB_SEC_TIME].type, exif[SUB_SEC_TIME].value)
    return SourceExif({code: main[code] for code in MAIN_CARRIED if code in main}, exif, gps)


def _layout(entries: list[Entry], at: int, order: str, big: bool, next_offset: int) -> bytes:
    """An IFD of ``entries`` (sorted by code) placed at file offset ``at``, followed by its
    out-of-line values (each on a word boundary)."""
    count_format, inline, offset_format = ("Q", 8, "Q") if big else ("H", 4, "I")
    entry_format = "HHQ" if big else "HHI"
    head = struct.calcsize(order + count_format) + len(entries) * (12 if not big else 20) + inline
    values, fields = bytearray(), []
    for entry in sorted(entries, key=lambda e: e.code):
        data = _encode(entry, order)
        if len(data) <= inline:
            fields.append(struct.pack(order + entry_format, entry.code, entry.type, entry.count)
                          + data.ljust(inline, b"\0"))
        else:
            if len(values) % 2:
                values += b"\0"
            fields.append(struct.pack(order + entry_format, entry.code, entry.type, entry.count)
                          + struct.pack(order + offset_format, at + head + len(values)))
            values += data
    return (struct.pack(order + count_format, len(entries)) + b"".join(fields)
            + struct.pack(order + offset_format, next_offset) + bytes(values))


def add_tags(path: Path, *, main: Iterable[Entry] = (), exif: Iterable[Entry] = (), gps: Iterable[Entry] = ()) -> None:
    """Merge ``main`` into the first IFD of the TIFF at ``path`` (same code: replaced) and give it
    an EXIF IFD of ``exif`` and a GPS IFD of ``gps`` (none when empty), in place.

    The new first IFD and its sub-IFDs are appended to the file; the header points at it.
    """
    exif, gps = list(exif), list(gps)
    with open(path, "r+b") as handle:
        reader = _Reader(handle, Path(path))
        entries, next_offset = reader.ifd(reader.first)
        merged = {entry.code: entry for entry in entries if entry.code not in (EXIF_IFD, GPS_IFD)}
        merged.update((entry.code, entry) for entry in main)
        pointer_type = 18 if reader.big else LONG
        for code, wanted in ((EXIF_IFD, exif), (GPS_IFD, gps)):
            if wanted:
                merged[code] = Entry(code, pointer_type, (0,))
        handle.seek(0, 2)
        end = handle.tell()
        start = end + (-end) % 8
        order, big = reader.order, reader.big
        block = _layout(list(merged.values()), start, order, big, next_offset)
        position = start + len(block)
        subs = []
        for code, wanted in ((EXIF_IFD, exif), (GPS_IFD, gps)):
            if wanted:
                position += (-position) % 8
                merged[code] = Entry(code, pointer_type, (position,))
                sub = _layout(wanted, position, order, big, 0)
                subs.append((position, sub))
                position += len(sub)
        block = _layout(list(merged.values()), start, order, big, next_offset)
        handle.write(b"\0" * (start - end) + block)
        for offset, sub in subs:
            handle.seek(offset)
            handle.write(sub)
        handle.seek(8 if big else 4)
        handle.write(struct.pack(order + ("Q" if big else "I"), start))

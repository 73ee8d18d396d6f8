"""The XMP packets of a registered capture's files, made from the band files' own packets: a
``--per-band`` file keeps its band's packet (band name, wavelengths, radiometric calibration,
irradiance, ...) with the geometry tags replaced by the reference's lens and a zero rig rotation
relative to the reference, as its pixels now lie on the reference band's raw grid; the cube has
the reference's packet without the tags of one band, its bands' names and wavelengths as
``rdf:Seq`` lists (one item per sample, Pix4D's form for a multi-band image). The EXIF GPS fix
and capture time are added to both (``exif:GPSLatitude`` ...), when there is a fix.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from xml.sax.saxutils import escape

from cade_cli.capture.exif import SourceExif
from cade_cli.capture.metadata import parse_xmp

CAMERA_URI = "http://pix4d.com/camera/"
GEOMETRY = ("ModelType", "PrincipalPoint", "PerspectiveFocalLength", "PerspectiveFocalLengthUnits",
            "PerspectiveDistortion", "FisheyePolynomial", "FisheyeAffineMatrix", "FisheyeAffineSymmetric")
"""The ``Camera:`` tags of a lens: the reference's are written into every registered file."""
RIG = ("RigRelatives", "RigRelativesReferenceRigCameraIndex", "RigTranslations")
"""The ``Camera:`` tags that place a band's lens in the rig: 0, 0, 0 relative to the reference."""
ONE_BAND = ("BandName", "CentralWavelength", "WavelengthFWHM", "RigCameraIndex", "RadiometricCalibration",
            "DarkRowValue", "BandSensitivity", "BandGain", "BlackCurrent", "SensorModel", "InvalidPixel",
            "CalibrationMeasurement", "BlackLevel", "CenterWavelength", "Bandwidth", "SpectralIrradiance",
            "HorizontalIrradiance", "DirectIrradiance", "ScatteredIrradiance", "RawMeasurement", "OffMeasurement",
            "SensorId", "Exposure", "Gain", "TimeStamp", "SensorTemperature")
ONE_BAND_STARTS = ("Irradiance", "Vignetting")
"""Tags that describe one band (its calibration, its irradiance reading): left out of the cube's
packet (its JSON description keeps them per band)."""
RADIOMETRIC = ("RadiometricCalibration", "VignettingCenter", "VignettingPolynomial", "VignettingPolynomial2D",
               "VignettingPolynomial2DName", "DarkRowValue", "BlackLevel", "SensorModel", "BlackCurrent")
"""The tags that turn raw values into radiance: left out of a file whose values are radiance or
reflectance already (``--radiance``, ``--reflectance``), so that no tool applies them twice."""
_DECLARATION = re.compile(r'xmlns:([A-Za-z_][\w.-]*)\s*=\s*"([^"]*)"')


def _prefixes(packet: str, uri_start: str) -> set[str]:
    return {prefix for prefix, uri in _DECLARATION.findall(packet) if uri.startswith(uri_start)}


def _property_names(packet: str) -> set[str]:
    """``Prefix:Local`` of every property of the packet, elements and attributes."""
    return set(re.findall(r"<([A-Za-z_][\w.-]*:[A-Za-z_][\w.-]*)[\s/>]", packet)) | set(
        re.findall(r"\s([A-Za-z_][\w.-]*:[A-Za-z_][\w.-]*)\s*=\s*\"", packet))


def without(packet: str, names: Sequence[str]) -> str:
    """``packet`` with the properties ``names`` (``Prefix:Local``) removed, as elements
    (``<Camera:X>...</Camera:X>``, nested ``rdf:Seq`` included) or attributes (``Camera:X="..."``)."""
    for name in names:
        name = re.escape(name)
        # each pattern starts with a literal (no leading \s*): linear in the packet's whitespace padding
        packet = re.sub(rf"<{name}(?:\s[^>]*)?>.*?</{name}>", "", packet, flags=re.DOTALL)
        packet = re.sub(rf"<{name}(?:\s[^>]*)?/>", "", packet)
        packet = re.sub(rf"(?<=\s){name}\s*=\s*\"[^\"]*\"", "", packet)
    return packet


def _element(name: str, value: str | list[str]) -> str:
    if isinstance(value, list):
        items = "".join(f"<rdf:li>{escape(item)}</rdf:li>" for item in value)
        return f"<{name}><rdf:Seq>{items}</rdf:Seq></{name}>"
    return f"<{name}>{escape(value)}</{name}>"


def with_description(packet: str, namespaces: dict[str, str], properties: dict[str, str | list[str]]) -> str:
    """``packet`` with one more ``rdf:Description`` of ``properties`` (``Prefix:Local`` ->
    text or a list, written as an ``rdf:Seq``); a new packet when ``packet`` has no ``rdf:RDF``."""
    if not properties:
        return packet
    declarations = " ".join(f'xmlns:{prefix}="{uri}"' for prefix, uri in namespaces.items())
    body = "".join(_element(name, value) for name, value in properties.items())
    about = re.search(r'rdf:about\s*=\s*"([^"]*)"', packet)  # XMP: one subject for every description
    about = about.group(1) if about else ""
    description = f'<rdf:Description rdf:about="{about}" {declarations}>{body}</rdf:Description>\n'
    end = packet.find("</rdf:RDF>")
    if end < 0:
        return ('<?xpacket begin="\ufeff" id="W5M0MpCehiHzreSzNTczkc9d"?><x:xmpmeta xmlns:x="adobe:ns:meta/">'
                '<rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">' + description
                + '</rdf:RDF></x:xmpmeta><?xpacket end="w"?>')
    return packet[:end] + description + packet[end:]


def _degrees(entry, reference: str) -> str | None:
    """EXIF (deg, min, sec) -> XMP ``DD,MM.mmmmR``."""
    values = entry.numbers() if entry is not None else []
    if len(values) != 3 or any(v != v for v in values):
        return None
    d, m, s = values
    return f"{int(d)},{m + s / 60 + (d - int(d)) * 60:.6f}{reference}"


def exif_properties(exif: SourceExif) -> dict[str, str]:
    """The EXIF GPS fix and capture time as XMP ``exif:`` properties; no GPS without a fix."""
    found = {}
    gps = exif.gps
    if exif.has_fix():
        latitude = _degrees(gps.get(2), gps[1].text() if 1 in gps else "N")
        longitude = _degrees(gps.get(4), gps[3].text() if 3 in gps else "E")
        if latitude and longitude:
            found["exif:GPSLatitude"], found["exif:GPSLongitude"] = latitude, longitude
            altitude = gps.get(6)
            if altitude is not None and altitude.type == 5 and altitude.value[1]:
                found["exif:GPSAltitude"] = f"{altitude.value[0]}/{altitude.value[1]}"
                found["exif:GPSAltitudeRef"] = str(int(gps[5].value[0]) if 5 in gps else 0)
    original = exif.exif.get(36867)
    if original is not None and original.text():
        date, _, clock = original.text().partition(" ")
        found["exif:DateTimeOriginal"] = f"{date.replace(':', '-')}T{clock}"
    return found


def _exif_namespace(properties: dict) -> dict[str, str]:
    return {"exif": "http://ns.adobe.com/exif/1.0/"} if properties else {}


def _camera(packet: str) -> tuple[str, str]:
    """The packet's ``Camera`` namespace prefix and URI (Pix4D's; MicaSense and Parrot differ by a slash)."""
    for prefix, uri in _DECLARATION.findall(packet):
        if uri.startswith(CAMERA_URI):
            return prefix, uri
    return "Camera", "http://pix4d.com/camera/1.0/"


def _geometry(reference: str, reference_index: int) -> dict[str, str | list[str]]:
    """The reference lens's tags (``Camera:`` names), rotation 0, 0, 0 relative to the reference."""
    xmp = parse_xmp(reference)
    found = {f"Camera:{name}": xmp[f"Camera:{name}"] for name in GEOMETRY if f"Camera:{name}" in xmp}
    found["Camera:RigRelatives"] = "0, 0, 0"
    found["Camera:RigRelativesReferenceRigCameraIndex"] = str(reference_index)
    return found


def _text(packet: bytes | str) -> str:
    return packet.decode("utf-8", "replace") if isinstance(packet, bytes) else str(packet)


def band_packet(own: bytes | str, reference: bytes | str, *, reference_index: int, exif: SourceExif,
                converted: bool = False) -> bytes:
    """A ``--per-band`` file's packet: the band's ``own``, its lens and rig tags replaced by the
    ``reference`` band's lens (rotation 0, 0, 0 relative to rig index ``reference_index``), and its
    EXIF fix and time added (:func:`exif_properties`); ``converted``: the values are radiance or
    reflectance, the :data:`RADIOMETRIC` tags are left out."""
    text = _text(own)
    prefixes = _prefixes(text, CAMERA_URI)
    text = without(text, [f"{prefix}:{name}" for prefix in prefixes for name in (*GEOMETRY, *RIG)])
    if converted:
        text = without(text, sorted(name for name in _property_names(text) if name.split(":")[-1] in RADIOMETRIC))
    prefix, uri = _camera(text)
    geometry = {name.replace("Camera:", f"{prefix}:"): value
                for name, value in _geometry(_text(reference), reference_index).items()}
    text = with_description(text, {prefix: uri}, geometry)
    extra = exif_properties(exif)
    return with_description(text, _exif_namespace(extra), extra).encode("utf-8")


def one_band_properties(packet: bytes | str) -> dict[str, str | list[str]]:
    """The tags of ``packet`` that describe its band alone (:data:`ONE_BAND`), ``Prefix:Local`` -> value."""
    xmp = parse_xmp(packet)
    return {name: value for name, value in xmp.items()
            if name.split(":")[-1] in ONE_BAND or name.split(":")[-1].startswith(ONE_BAND_STARTS)}


def cube_packet(reference: bytes | str, *, reference_index: int, names: Sequence[str], wavelengths: Sequence[float],
                fwhms: Sequence[float | None], exif: SourceExif) -> bytes:
    """The cube's packet: the ``reference`` band's without its one-band tags, its lens with a zero
    rotation, ``Camera:BandName`` / ``CentralWavelength`` / ``WavelengthFWHM`` as one-item-per-band
    ``rdf:Seq`` lists, and its EXIF fix and time."""
    text = _text(reference)
    drop = {name for name in _property_names(text)
            if name.split(":")[-1] in (*ONE_BAND, *GEOMETRY, *RIG) or name.split(":")[-1].startswith(ONE_BAND_STARTS)}
    drop = {name for name in drop if not name.startswith(("rdf:", "x:", "xmlns:"))}
    text = without(text, sorted(drop))
    prefix, uri = _camera(text)
    properties = {f"{prefix}:{name.split(':')[1]}": value for name, value in _geometry(_text(reference),
                                                                                       reference_index).items()}
    properties[f"{prefix}:BandName"] = list(names)
    properties[f"{prefix}:CentralWavelength"] = [f"{w:g}" for w in wavelengths]
    if all(f is not None for f in fwhms):
        properties[f"{prefix}:WavelengthFWHM"] = [f"{f:g}" for f in fwhms]
    text = with_description(text, {prefix: uri}, properties)
    extra = exif_properties(exif)
    return with_description(text, _exif_namespace(extra), extra).encode("utf-8")

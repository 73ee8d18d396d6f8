"""Dataset downloads against a local HTTP server: official paths and archive layouts, resume, failures.

Nothing here touches the internet: every URL is redirected to a ThreadingHTTPServer on
127.0.0.1 that serves small archives built in the official internal layouts, at the
official URL paths, and can be told to ignore Range, cut a transfer short or fail.
"""

from __future__ import annotations

import functools
import http.server
import io
import re
import socket
import tarfile
import threading
import zipfile
from dataclasses import replace
from pathlib import Path
from urllib.parse import urlsplit

import pytest

from cade_cli.data import (
    BASE_URL_ENV, DOWNLOADS_FOLDER, MIDDLEBURY14_TRAINING, SOURCES, Archive, DatasetSource, Expected,
    download_dataset, get_dataset, mirror_url,
)
from cade_cli.errors import CadeError
from cli_runner import run_cade


# --- a local server with Range support --------------------------------------------------

class RangeHandler(http.server.SimpleHTTPRequestHandler):
    """GET with ``Range: bytes=N-`` (206/416), switchable to ignore it, cut the body short or fail."""

    def log_message(self, format, *args) -> None:  # noqa: A002 - keep test output clean
        pass

    def do_GET(self) -> None:
        server = self.server
        requested_range = self.headers.get("Range")
        server.requests.append((urlsplit(self.path).path, requested_range))
        if server.fail_with is not None:
            self.send_error(server.fail_with)
            return
        path = Path(self.translate_path(self.path))
        if not path.is_file():
            self.send_error(404)
            return
        data = path.read_bytes()
        match = re.fullmatch(r"bytes=(\d+)-", requested_range or "")
        start = 0
        if match and server.honour_range:
            start = int(match.group(1))
            if start >= len(data):
                self.send_response(416)
                self.send_header("Content-Range", f"bytes */{len(data)}")
                self.send_header("Content-Length", "0")
                self.end_headers()
                return
            self.send_response(206)
            self.send_header("Content-Range", f"bytes {start}-{len(data) - 1}/{len(data)}")
        else:
            self.send_response(200)
        body = data[start:]
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Content-Type", "application/zip")
        self.end_headers()
        if server.cut_after is not None:
            body = body[: server.cut_after]
        self.wfile.write(body)
        self.close_connection = True


@pytest.fixture
def server(tmp_path):
    """(root folder served, base URL, server); files go at their official URL paths under root."""
    root = tmp_path / "served"
    root.mkdir()
    httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), functools.partial(RangeHandler, directory=str(root)))
    httpd.requests, httpd.honour_range, httpd.cut_after, httpd.fail_with = [], True, None, None
    thread = threading.Thread(target=httpd.serve_forever, kwargs={"poll_interval": 0.01}, daemon=True)
    thread.start()
    try:
        yield root, f"http://127.0.0.1:{httpd.server_address[1]}", httpd
    finally:
        httpd.shutdown()
        httpd.server_close()
        thread.join()


def serve(root: Path, url: str, payload: bytes) -> Path:
    """Place ``payload`` where ``url``'s path points under ``root``."""
    path = root / urlsplit(url).path.lstrip("/")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(payload)
    return path


def zip_bytes(members: dict[str, bytes], directories: tuple[str, ...] = ()) -> bytes:
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_STORED) as archive:
        for directory in directories:
            archive.writestr(zipfile.ZipInfo(directory), b"")
        for name, data in members.items():
            archive.writestr(name, data)
    return buffer.getvalue()


# --- fake archives in the official internal layouts -------------------------------------

def middlebury14_zips(resolution: str = "Q") -> dict[str, bytes]:
    """MiddEval3-data-X.zip (training + test images, calib) and MiddEval3-GT0-X.zip (GT, masks)."""
    data, gt = {}, {}
    for scene in MIDDLEBURY14_TRAINING:
        base = f"MiddEval3/training{resolution}/{scene}"
        data |= {f"{base}/{name}": f"{scene} {name}".encode() for name in ("im0.png", "im1.png", "calib.txt")}
        gt |= {f"{base}/{name}": f"{scene} {name}".encode() for name in ("disp0GT.pfm", "mask0nocc.png")}
    data |= {f"MiddEval3/test{resolution}/Australia/{name}": b"test" for name in ("im0.png", "im1.png", "calib.txt")}
    return {
        f"MiddEval3-data-{resolution}.zip": zip_bytes(data, ("MiddEval3/", f"MiddEval3/training{resolution}/")),
        f"MiddEval3-GT0-{resolution}.zip": zip_bytes(gt, ("MiddEval3/",)),
    }


def two_view_zip(scene: str) -> bytes:
    """``<Scene>-2views.zip``: ``<Scene>/{view1,view5,disp1,disp5}.png`` and ``dmin.txt``."""
    names = ("view1.png", "view5.png", "disp1.png", "disp5.png", "dmin.txt")
    return zip_bytes({f"{scene}/{name}": f"{scene} {name} ".encode() * 20 for name in names}, (f"{scene}/",))


def serve_middlebury14(root: Path, resolution: str = "Q") -> dict[str, bytes]:
    zips = middlebury14_zips(resolution)
    for archive in SOURCES["middlebury14"].archives(resolution):
        serve(root, archive.url, zips[archive.filename])
    return zips


def serve_middlebury05(root: Path, scenes=("Art", "Books"), size: str = "ThirdSize") -> dict[str, bytes]:
    payloads = {}
    for scene in scenes:
        url = f"https://vision.middlebury.edu/stereo/data/scenes2005/{size}/zip-2views/{scene}-2views.zip"
        payloads[scene] = serve(root, url, two_view_zip(scene)).read_bytes()
    return payloads


def single_line(error: pytest.ExceptionInfo) -> str:
    message = str(error.value)
    assert "\n" not in message
    return message


# --- registry -----------------------------------------------------------------------------

def test_official_urls():
    urls = {a.url for a in SOURCES["middlebury14"].archives("H")}
    assert urls == {"https://vision.middlebury.edu/stereo/submit3/zip/MiddEval3-data-H.zip",
                    "https://vision.middlebury.edu/stereo/submit3/zip/MiddEval3-GT0-H.zip"}
    (art,) = SOURCES["middlebury05"].archives("F", ["Art"])
    assert art.url == "https://vision.middlebury.edu/stereo/data/scenes2005/FullSize/zip-2views/Art-2views.zip"
    assert len(SOURCES["middlebury05"].archives()) == 6 and len(SOURCES["middlebury06"].archives()) == 21
    (aloe, *_) = SOURCES["middlebury06"].archives("H")
    assert aloe.url == "https://vision.middlebury.edu/stereo/data/scenes2006/HalfSize/zip-2views/Aloe-2views.zip"
    kitti = "https://s3.eu-central-1.amazonaws.com/avg-kitti"
    assert SOURCES["kitti2015"].archives()[0].url == f"{kitti}/data_scene_flow.zip"
    assert SOURCES["kitti2012"].archives()[0].url == f"{kitti}/data_stereo_flow.zip"
    assert mirror_url("https://a.org/x/y.zip", "http://127.0.0.1:9/m/") == "http://127.0.0.1:9/m/x/y.zip"


@pytest.mark.parametrize(
    ("name", "kwargs", "fragment"),
    [
        ("flyingthings3d", {}, "hundreds of GB"),
        ("msir-outdoor", {}, "carries no licence"),
        ("kitti2015", {"resolution": "Q"}, "drop --resolution"),
        ("middlebury14", {"resolution": "X"}, "use one of Q, H, F"),
        ("middlebury05", {"scenes": ["Computer"]}, "choose from Art"),
        ("middlebury14", {"scenes": ["Adirondack"]}, "one archive"),
        ("eth3d", {}, "choose one of"),
    ],
)
def test_impossible_requests_are_refused_before_any_request(server, tmp_path, name, kwargs, fragment):
    _, base, httpd = server
    with pytest.raises(CadeError, match=re.escape(fragment)) as error:
        download_dataset(name, tmp_path / "data", base_url=base, **kwargs)
    single_line(error)
    assert httpd.requests == [] and not (tmp_path / "data").exists()


def test_a_bad_mirror_address_is_refused(tmp_path, monkeypatch):
    monkeypatch.setenv(BASE_URL_ENV, "ftp://example")
    with pytest.raises(CadeError, match=BASE_URL_ENV):
        download_dataset("middlebury05", tmp_path / "data", scenes=["Art"])
    assert not (tmp_path / "data").exists()


# --- full downloads -----------------------------------------------------------------------

def test_middlebury14_lands_where_the_reader_finds_it(server, tmp_path):
    root, base, httpd = server
    serve_middlebury14(root)
    target = tmp_path / "data"
    report = download_dataset("middlebury14", target, resolution="Q", base_url=base)
    assert report.downloaded == ("MiddEval3-data-Q.zip", "MiddEval3-GT0-Q.zip") and report.present == ()
    assert report.folder == target / "middlebury2014"
    assert get_dataset("middlebury14").scene_names(target, resolution="Q") == sorted(MIDDLEBURY14_TRAINING)
    scene = target / "middlebury2014" / "trainingQ" / "Adirondack"
    assert (scene / "disp0GT.pfm").read_bytes() == b"Adirondack disp0GT.pfm"  # GT merged beside the images
    assert (target / "middlebury2014" / "testQ" / "Australia" / "im0.png").is_file()
    assert not (target / DOWNLOADS_FOLDER).exists()  # archives and scratch removed
    assert [path for path, _ in httpd.requests] == [
        "/stereo/submit3/zip/MiddEval3-data-Q.zip", "/stereo/submit3/zip/MiddEval3-GT0-Q.zip"]


def test_middlebury05_scenes_land_in_scene_folders(server, tmp_path):
    root, base, _ = server
    serve_middlebury05(root, ("Art", "Books"))
    report = download_dataset("middlebury05", tmp_path, scenes=["Books", "Art"], base_url=base)
    assert report.resolution == "Q" and len(report.downloaded) == 2
    assert get_dataset("middlebury05").scene_names(tmp_path) == ["Art", "Books"]
    assert (tmp_path / "middlebury2005" / "Art" / "disp5.png").read_bytes() == b"Art disp5.png " * 20


def test_kitti2015_bundle_lands_where_the_reader_finds_it(server, tmp_path):
    root, base, _ = server
    frames = {f"training/{folder}/{i:06d}_10.png": b"k" for i in range(200)
              for folder in ("image_2", "image_3", "disp_occ_0", "disp_noc_0")}
    frames |= {"training/image_2/000000_11.png": b"k", "testing/image_2/000000_10.png": b"k"}
    serve(root, SOURCES["kitti2015"].archives()[0].url, zip_bytes(frames))
    download_dataset("kitti2015", tmp_path, base_url=base)
    names = get_dataset("kitti2015").scene_names(tmp_path)
    assert len(names) == 200 and names[0] == "000000_10"
    assert (tmp_path / "kitti" / "2015" / "training" / "disp_noc_0" / "000199_10.png").is_file()


def test_progress_gets_one_task_per_file_named_after_it(server, tmp_path):
    from rich.console import Console

    from cade_cli.data import download_progress

    root, base, _ = server
    payload = serve_middlebury05(root, ("Art",))["Art"]
    progress = download_progress(Console(file=io.StringIO()))
    added = []
    add_task = progress.add_task
    progress.add_task = lambda description, **kw: added.append((description, kw["total"])) or add_task(description, **kw)
    with progress:
        download_dataset("middlebury05", tmp_path, scenes=["Art"], base_url=base, progress=progress)
    assert added == [("Art-2views-ThirdSize.zip", len(payload))] and progress.tasks == []


def test_a_second_run_does_nothing(server, tmp_path):
    root, base, httpd = server
    serve_middlebury05(root, ("Art",))
    download_dataset("middlebury05", tmp_path, scenes=["Art"], base_url=base)
    requests = len(httpd.requests)
    again = download_dataset("middlebury05", tmp_path, scenes=["Art"], base_url=base)
    assert again.already_present and again.present == ("Art-2views-ThirdSize.zip",)
    assert len(httpd.requests) == requests  # not even a request


def test_only_what_is_missing_is_fetched_and_force_fetches_again(server, tmp_path):
    root, base, httpd = server
    serve_middlebury05(root, ("Art", "Books"))
    download_dataset("middlebury05", tmp_path, scenes=["Art"], base_url=base)
    report = download_dataset("middlebury05", tmp_path, scenes=["Art", "Books"], base_url=base)
    assert report.present == ("Art-2views-ThirdSize.zip",) and report.downloaded == ("Books-2views-ThirdSize.zip",)
    (tmp_path / "middlebury2005" / "Art" / "view1.png").write_bytes(b"edited")
    forced = download_dataset("middlebury05", tmp_path, scenes=["Art"], force=True, base_url=base)
    assert forced.downloaded == ("Art-2views-ThirdSize.zip",)
    assert (tmp_path / "middlebury2005" / "Art" / "view1.png").read_bytes() == b"Art view1.png " * 20


def place_download(root: Path, filename: str, data: bytes) -> Path:
    """Put ``data`` in ``root``'s downloads folder as ``filename`` (a finished or
    partial archive left by an earlier run); return that folder."""
    downloads = root / DOWNLOADS_FOLDER
    downloads.mkdir(exist_ok=True)
    (downloads / filename).write_bytes(data)
    return downloads


def test_a_complete_archive_on_disk_is_unpacked_without_downloading(server, tmp_path):
    root, base, httpd = server
    payload = serve_middlebury05(root, ("Art",))["Art"]
    place_download(tmp_path, "Art-2views-ThirdSize.zip", payload)
    report = download_dataset("middlebury05", tmp_path, scenes=["Art"], base_url=base)
    assert report.downloaded == () and report.extracted == ("Art-2views-ThirdSize.zip",)
    assert httpd.requests == [] and (tmp_path / "middlebury2005" / "Art" / "view5.png").is_file()


# --- resume -------------------------------------------------------------------------------

def test_a_part_file_is_resumed_with_range(server, tmp_path):
    root, base, httpd = server
    payload = serve_middlebury05(root, ("Art",))["Art"]
    downloads = place_download(tmp_path, "Art-2views-ThirdSize.zip.part", payload[:300])
    report = download_dataset("middlebury05", tmp_path, scenes=["Art"], base_url=base, keep_archives=True)
    assert httpd.requests[-1][1] == "bytes=300-"
    assert report.bytes_downloaded == len(payload) - 300
    assert (downloads / "Art-2views-ThirdSize.zip").read_bytes() == payload
    assert not (downloads / "Art-2views-ThirdSize.zip.part").exists()


def test_a_cut_transfer_keeps_its_part_and_the_next_run_completes_it(server, tmp_path):
    root, base, httpd = server
    payload = serve_middlebury05(root, ("Art",))["Art"]
    httpd.cut_after = 500
    with pytest.raises(CadeError, match="run again") as error:
        download_dataset("middlebury05", tmp_path, scenes=["Art"], base_url=base)
    single_line(error)
    part = tmp_path / DOWNLOADS_FOLDER / "Art-2views-ThirdSize.zip.part"
    assert part.read_bytes() == payload[:500]
    assert not (tmp_path / "middlebury2005").exists()
    httpd.cut_after = None
    download_dataset("middlebury05", tmp_path, scenes=["Art"], base_url=base, keep_archives=True)
    assert httpd.requests[-1][1] == "bytes=500-"
    assert (tmp_path / DOWNLOADS_FOLDER / "Art-2views-ThirdSize.zip").read_bytes() == payload


def test_a_server_ignoring_range_restarts_from_zero(server, tmp_path):
    root, base, httpd = server
    payload = serve_middlebury05(root, ("Art",))["Art"]
    httpd.honour_range = False
    downloads = place_download(tmp_path, "Art-2views-ThirdSize.zip.part", b"x" * 200)  # would corrupt an append
    report = download_dataset("middlebury05", tmp_path, scenes=["Art"], base_url=base, keep_archives=True)
    assert httpd.requests[-1][1] == "bytes=200-" and report.bytes_downloaded == len(payload)
    assert (downloads / "Art-2views-ThirdSize.zip").read_bytes() == payload


def test_a_complete_part_answered_416_is_used(server, tmp_path):
    root, base, httpd = server
    payload = serve_middlebury05(root, ("Art",))["Art"]
    place_download(tmp_path, "Art-2views-ThirdSize.zip.part", payload)
    report = download_dataset("middlebury05", tmp_path, scenes=["Art"], base_url=base)
    assert report.bytes_downloaded == 0 and (tmp_path / "middlebury2005" / "Art" / "view1.png").is_file()


# --- failures -----------------------------------------------------------------------------

def test_a_corrupt_archive_is_deleted_and_nothing_is_extracted(server, tmp_path):
    root, base, _ = server
    payload = bytearray(two_view_zip("Art"))
    at = payload.index(b"Art view5.png")
    payload[at] ^= 0xFF  # member data no longer matches its CRC
    serve(root, SOURCES["middlebury05"].archives(None, ["Art"])[0].url, bytes(payload))
    with pytest.raises(CadeError, match="archive Art-2views-ThirdSize.zip is corrupt.*run again") as error:
        download_dataset("middlebury05", tmp_path, scenes=["Art"], base_url=base)
    single_line(error)
    assert not (tmp_path / "middlebury2005").exists()
    assert list((tmp_path / DOWNLOADS_FOLDER).iterdir()) == []


def test_a_wrong_checksum_counts_as_corrupt(server, tmp_path, monkeypatch):
    root, base, _ = server
    (art,) = SOURCES["middlebury05"].archives(None, ["Art"])
    serve(root, art.url, two_view_zip("Art"))
    pinned = replace(SOURCES["middlebury05"], build=lambda resolution, scenes: (replace(art, sha256="0" * 64),))
    monkeypatch.setitem(SOURCES, "middlebury05", pinned)
    with pytest.raises(CadeError, match="sha256"):
        download_dataset("middlebury05", tmp_path, base_url=base)
    assert not (tmp_path / "middlebury2005").exists()


@pytest.mark.parametrize("member", ["Art/../../evil.png", "/tmp/evil.png", "..\\evil.png"])
def test_zip_slip_members_are_refused(server, tmp_path, member):
    root, base, _ = server
    names = ("view1.png", "view5.png", "disp1.png", "disp5.png")
    payload = zip_bytes({**{f"Art/{n}": b"v" for n in names}, member: b"evil"})
    serve(root, SOURCES["middlebury05"].archives(None, ["Art"])[0].url, payload)
    target = tmp_path / "data"
    with pytest.raises(CadeError, match="unsafe member") as error:
        download_dataset("middlebury05", target, scenes=["Art"], base_url=base)
    single_line(error)
    assert not list(tmp_path.rglob("evil.png")) and not (target / "middlebury2005").exists()
    assert list((target / DOWNLOADS_FOLDER).iterdir()) == []  # the archive is gone too


def test_tar_archives_are_checked_and_unpacked_the_same_way(server, tmp_path, monkeypatch):
    root, base, _ = server

    def tar_bytes(members: dict[str, bytes]) -> bytes:
        buffer = io.BytesIO()
        with tarfile.open(fileobj=buffer, mode="w:gz") as archive:
            for name, data in members.items():
                info = tarfile.TarInfo(name)
                info.size = len(data)
                archive.addfile(info, io.BytesIO(data))
        return buffer.getvalue()

    good = Archive("https://example.org/sets/good.tar.gz", "good.tar.gz", (Expected("left/*.png", 2),), strip="set/")
    evil = Archive("https://example.org/sets/evil.tar.gz", "evil.tar.gz", (Expected("x"),))
    serve(root, good.url, tar_bytes({"set/left/a.png": b"a", "set/left/b.png": b"b"}))
    serve(root, evil.url, tar_bytes({"../escaped.png": b"e"}))
    source = DatasetSource("folder", "folder", "test", "https://example.org", good.url, {"": "tiny"},
                           build=lambda resolution, scenes: (good,))
    monkeypatch.setitem(SOURCES, "folder", source)
    download_dataset("folder", tmp_path, base_url=base)
    assert (tmp_path / "folder" / "left" / "b.png").read_bytes() == b"b"
    monkeypatch.setitem(SOURCES, "folder", replace(source, build=lambda resolution, scenes: (evil,)))
    with pytest.raises(CadeError, match="unsafe member"):
        download_dataset("folder", tmp_path, base_url=base)
    assert not list(tmp_path.rglob("escaped.png"))


def test_an_archive_without_the_expected_files_is_named(server, tmp_path):
    root, base, _ = server
    serve(root, SOURCES["middlebury05"].archives(None, ["Art"])[0].url, zip_bytes({"Art/view1.png": b"v"}))
    with pytest.raises(CadeError, match=r"did not provide Art/view5\.png") as error:
        download_dataset("middlebury05", tmp_path, scenes=["Art"], base_url=base)
    single_line(error)


@pytest.mark.parametrize(("status", "fragment"), [(404, "HTTP 404.*may have moved"), (503, "HTTP 503.*try again")])
def test_http_errors_become_one_line(server, tmp_path, status, fragment):
    root, base, httpd = server
    serve_middlebury05(root, ("Art",))
    httpd.fail_with = status
    with pytest.raises(CadeError, match=fragment) as error:
        download_dataset("middlebury05", tmp_path, scenes=["Art"], base_url=base)
    message = single_line(error)
    assert f"{base}/stereo/data/scenes2005/ThirdSize/zip-2views/Art-2views.zip" in message


def test_an_unreachable_host_is_one_line_with_advice(tmp_path):
    with socket.socket() as probe:  # a port nobody listens on
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    with pytest.raises(CadeError, match="check your connection") as error:
        download_dataset("middlebury05", tmp_path, scenes=["Art"], base_url=f"http://127.0.0.1:{port}")
    assert f"127.0.0.1:{port}" in single_line(error)


# --- CLI ----------------------------------------------------------------------------------


def test_cli_download_prints_one_summary_line(server, tmp_path, capsys, monkeypatch):
    root, base, _ = server
    serve_middlebury14(root)
    monkeypatch.setenv(BASE_URL_ENV, base)
    target = tmp_path / "data"
    code, out, err = run_cade(["datasets", "download", "middlebury14", "--resolution", "Q", "--to", target], capsys)
    assert code == 0, err
    assert len(out.strip().splitlines()) == 1 and "2 archive(s) downloaded" in out and "middlebury2014" in out
    assert len(get_dataset("middlebury14").scene_names(target)) == 15
    code, out, _ = run_cade(["datasets", "download", "middlebury14", "--to", target], capsys)
    assert code == 0 and "already present" in out and len(out.strip().splitlines()) == 1


def test_cli_download_errors_are_one_stderr_line(server, tmp_path, capsys, monkeypatch):
    _, base, _ = server
    monkeypatch.setenv(BASE_URL_ENV, base)
    code, out, err = run_cade(["datasets", "download", "middlebury05", "--to", tmp_path], capsys)
    assert code == 1 and out == ""
    assert err.count("\n") == 1 and err.startswith("cade: error: cannot download") and "HTTP 404" in err
    code, _, err = run_cade(["datasets", "download", "flyingthings3d", "--to", tmp_path], capsys)
    assert code == 1 and err.count("\n") == 1 and "lmb.informatik.uni-freiburg.de" in err


def test_cli_list_names_every_dataset(capsys):
    code, out, err = run_cade(["datasets", "list"], capsys)
    assert code == 0, err
    for name in SOURCES:
        assert name in out
    assert "vision.middlebury" in out

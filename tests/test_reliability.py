"""Reliability: every bad input or unwritable output ends as one line on stderr and a
non-zero exit, no output appears or changes unless the whole run succeeded, the readers
let only CadeError escape (property-based), and runs are deterministic and independent."""

from __future__ import annotations

import errno
import json
import os
import struct
import subprocess
import sys
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest
import tifffile
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cade_cli.errors import CadeError
from cade_cli.io.disparity import read_disparity, read_validity, write_disparity
from cade_cli.io.image_files import MAX_IMAGE_PIXELS
from cade_cli.io.images import load_image
from synthetic import render_pair
from cli_runner import run_cade

REPO = Path(__file__).resolve().parents[1]


def assert_one_line_error(code: int, stderr: str, *words: str) -> None:
    assert code != 0
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("cade: error: "), stderr
    assert "Traceback" not in stderr
    for word in words:
        assert word in lines[0], lines[0]


def hidden_files(folder: Path) -> list[str]:
    """Leftover temporaries (our stand-ins start with a dot)."""
    return sorted(str(p.relative_to(folder)) for p in folder.rglob(".*"))


def png_chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)


def bomb_png(path: Path, width: int = 60000, height: int = 60000) -> Path:
    """A few hundred bytes whose header announces a huge greyscale image."""
    header = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + png_chunk(b"IHDR", header)
                     + png_chunk(b"IDAT", zlib.compress(b"\0" * 1000)) + png_chunk(b"IEND", b""))
    return path


@pytest.fixture
def pair(tmp_path, rng):
    """A small textured pair (8-bit PNGs) with a 4 px disparity; fast with every matcher."""
    rendered = render_pair(rng, (40, 72), background=(4.0, 0.0))
    left, right = tmp_path / "l.png", tmp_path / "r.png"
    cv2.imwrite(str(left), np.rint(rendered.left * 255).astype(np.uint8))
    cv2.imwrite(str(right), np.rint(rendered.right * 255).astype(np.uint8))
    return left, right


# --- unwritable places: chmod does not stop root, so use places no one can write to ---

def unwritable_folders(tmp_path: Path) -> dict[str, Path]:
    """Folders that exist (or seem to) but take no new file, whoever runs the tests."""
    places = {}
    (tmp_path / "a_file").write_text("not a folder")
    places["file as parent"] = tmp_path / "a_file"
    if Path("/proc/self").is_dir():
        places["/proc"] = Path("/proc")  # no new file there, even for root (Linux)
    if hasattr(os, "geteuid") and os.geteuid() != 0:
        read_only = tmp_path / "read_only"
        read_only.mkdir()
        read_only.chmod(0o500)
        places["read-only folder"] = read_only
    return places


UNWRITABLE = ["file as parent", "/proc", "read-only folder"]


def unwritable(tmp_path: Path, kind: str) -> Path:
    places = unwritable_folders(tmp_path)
    if kind not in places:
        pytest.skip(f"no {kind} here (root ignores permissions; /proc needs Linux)")
    return places[kind]


def commands(pair, dataset: Path, bad: Path, good: Path) -> dict[str, list]:
    """Every subcommand with one output in the unwritable ``bad`` folder, the others in ``good``."""
    left, right = pair
    disparity = ["disparity", left, right, "--max-disp", 8]
    benchmark = ["benchmark", "-d", "folder", "--data-dir", dataset, "--methods", "sgbm", "--protocol", "cs",
                 "--preprocess", "none", "--scenes", "first"]
    return {
        "disparity -o": [*disparity, "-o", bad / "d.pfm", "--vis", good / "v.png", "--validity", good / "m.png"],
        "disparity --vis": [*disparity, "-o", good / "d.pfm", "--vis", bad / "v.png", "--validity", good / "m.png"],
        "disparity --validity": [*disparity, "-o", good / "d.pfm", "--vis", good / "v.png",
                                 "--validity", bad / "m.png"],
        "register -o": ["register", "--reference", left, "--moving", right, "-o", bad / "r.tif", "--max-disp", 8],
        "benchmark --json": [*benchmark, "--json", bad / "b.json", "--report", good / "b.md",
                             "--save-dir", good / "maps"],
        "benchmark --report": [*benchmark, "--json", good / "b.json", "--report", bad / "b.md",
                               "--save-dir", good / "maps"],
        "benchmark --save-dir": [*benchmark, "--json", good / "b.json", "--report", good / "b.md",
                                 "--save-dir", bad / "maps"],
        "datasets download --to": ["datasets", "download", "middlebury05", "--to", bad / "data"],
    }


COMMANDS = ["disparity -o", "disparity --vis", "disparity --validity", "register -o", "benchmark --json",
            "benchmark --report", "benchmark --save-dir", "datasets download --to"]


@pytest.mark.parametrize("kind", UNWRITABLE)
@pytest.mark.parametrize("command", COMMANDS)
def test_an_unwritable_output_is_refused_before_any_work(pair, folder_dataset, tmp_path, capfd, monkeypatch,
                                                         command, kind):
    bad = unwritable(tmp_path, kind)
    good = tmp_path / "out"
    good.mkdir()
    (good / "d.pfm").write_bytes(b"ORIGINAL")
    monkeypatch.setenv("CADE_DOWNLOAD_BASE_URL", "http://127.0.0.1:9")  # never the network
    import cade_cli.evaluation.loop
    import cade_cli.registration
    import cade_cli.stereo

    def must_not_run(*args, **kwargs):
        raise AssertionError("the work started although an output could not be written")

    for module, name in ((cade_cli.stereo, "estimate_disparity"), (cade_cli.registration, "estimate_disparity"),
                         (cade_cli.evaluation.loop, "run_benchmark")):
        monkeypatch.setattr(module, name, must_not_run)
    code, stdout, stderr = run_cade(commands(pair, folder_dataset, bad, good)[command], capfd)
    assert_one_line_error(code, stderr, str(bad))
    assert sorted(p.name for p in good.iterdir()) == ["d.pfm"] and (good / "d.pfm").read_bytes() == b"ORIGINAL"


def no_space(path, *args, **kwargs):
    """A writer that starts writing, then meets a full disk."""
    Path(path).write_bytes(b"half")
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))


def test_a_side_output_failing_late_leaves_every_output_untouched(pair, tmp_path, capfd, monkeypatch):
    """The disk fills while --validity is written: the map and --vis, already written to
    their temporaries, do not replace the existing files, and no temporary is left."""
    import cade_cli.io.match_outputs

    left, right = pair
    out, vis, mask = tmp_path / "o.pfm", tmp_path / "v.png", tmp_path / "m.png"
    out.write_text("ORIGINAL")
    monkeypatch.setattr(cade_cli.io.match_outputs, "write_validity", no_space)
    code, _, stderr = run_cade(["disparity", left, right, "-o", out, "--vis", vis, "--validity", mask,
                                "--max-disp", 8], capfd)
    assert_one_line_error(code, stderr, "could not write", "m.png", "No space left")
    assert out.read_text() == "ORIGINAL" and not vis.exists() and not mask.exists()
    assert hidden_files(tmp_path) == []


def test_register_on_a_full_disk_is_one_line_and_keeps_the_old_file(pair, tmp_path, capfd, monkeypatch):
    left, right = pair
    out = tmp_path / "r.tif"
    out.write_text("ORIGINAL")
    monkeypatch.setattr(tifffile, "imwrite", no_space)
    code, _, stderr = run_cade(["register", "--reference", left, "--moving", right, "-o", out, "--max-disp", 8], capfd)
    assert_one_line_error(code, stderr, "could not write", "r.tif", "No space left")
    assert out.read_text() == "ORIGINAL" and hidden_files(tmp_path) == []


def test_benchmark_on_a_full_disk_writes_none_of_its_outputs(folder_dataset, tmp_path, capfd, monkeypatch):
    out = tmp_path / "out"
    out.mkdir()
    real_write_text = Path.write_text

    def full_disk_for_markdown(self, text, *args, **kwargs):
        if self.suffix == ".md":
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))  # a stream write names no file
        return real_write_text(self, text, *args, **kwargs)

    monkeypatch.setattr(Path, "write_text", full_disk_for_markdown)
    code, _, stderr = run_cade(["benchmark", "-d", "folder", "--data-dir", folder_dataset, "--methods", "sgbm",
                                "--protocol", "cs", "--preprocess", "none", "--json", out / "b.json",
                                "--report", out / "b.md", "--save-dir", out / "maps"], capfd)
    assert_one_line_error(code, stderr, "could not write", "No space left")
    assert list(out.iterdir()) == []


def test_an_existing_save_dir_gets_the_new_maps_and_keeps_its_other_files(folder_dataset, tmp_path, capfd):
    maps = tmp_path / "maps"
    maps.mkdir()
    (maps / "notes.txt").write_text("mine")
    code, _, stderr = run_cade(["benchmark", "-d", "folder", "--data-dir", folder_dataset, "--methods", "sgbm",
                                "--protocol", "rgb", "--preprocess", "none", "--save-dir", maps], capfd)
    assert code == 0, stderr
    assert sorted(str(p.relative_to(maps)) for p in maps.rglob("*") if p.is_file()) == [
        "notes.txt", "sgbm+none/rgb/first_RGB-median.pfm", "sgbm+none/rgb/first_RGB-median_error.png",
        "sgbm+none/rgb/second_RGB-median.pfm", "sgbm+none/rgb/second_RGB-median_error.png"]
    assert hidden_files(maps) == []


# --- the table, row by row ---

def test_a_single_disparity_range_is_refused_by_disparity_and_register(pair, tmp_path, capfd):
    """A one-value range (--min-disp 4 --max-disp 4) is refused in one line before any work (issue 40:
    it used to give every pixel that one disparity and report it valid); nothing is written."""
    left, right = pair
    for command in (["disparity", left, right, "-o", tmp_path / "o.pfm"],
                    ["register", "--reference", left, "--moving", right, "-o", tmp_path / "o.tif"]):
        code, _, stderr = run_cade([*command, "--min-disp", 4, "--max-disp", 4], capfd)
        assert_one_line_error(code, stderr, "--min-disp 4 and --max-disp 4 leave one disparity")
    assert not list(tmp_path.glob("o.*"))


def test_register_refuses_estimation_options_with_a_given_disparity(pair, tmp_path, capfd):
    left, right = pair
    given_map = tmp_path / "d.pfm"
    write_disparity(given_map, np.full((40, 72), 4.0, np.float32))
    out = tmp_path / "o.tif"
    code, _, stderr = run_cade(["register", "--reference", left, "--moving", right, "-o", out, "--disparity", given_map, "--method", "foo",
                                "--preprocess", "bogus"], capfd)
    assert_one_line_error(code, stderr, "--method and --preprocess", "--disparity")
    assert not out.exists()
    code, _, stderr = run_cade(["register", "--reference", left, "--moving", right, "-o", out, "--method", "foo"], capfd)
    assert_one_line_error(code, stderr, "unknown method 'foo'")
    code, _, stderr = run_cade(["register", "--reference", left, "--moving", right, "-o", out, "--preprocess", "bogus"], capfd)
    assert_one_line_error(code, stderr, "unknown preprocess 'bogus'")
    code, _, stderr = run_cade(["register", "--reference", left, "--moving", right, "-o", out, "--fill", "bogus"], capfd)
    assert_one_line_error(code, stderr, "--fill")


def test_a_constant_pair_warns_and_is_reported_zero_percent_valid(tmp_path, capfd):
    grey = np.full((40, 72), 128, np.uint8)
    left, right = tmp_path / "a.png", tmp_path / "b.png"
    cv2.imwrite(str(left), grey)
    cv2.imwrite(str(right), grey)
    mask = tmp_path / "m.png"
    code, stdout, stderr = run_cade(["disparity", left, right, "-o", tmp_path / "d.pfm", "--max-disp", 8,
                                     "--validity", mask], capfd)
    assert code == 0 and "valid 0.0%" in stdout
    assert stderr.startswith("warning: ") and "no texture" in stderr and str(left) in stderr
    assert not read_validity(mask).any()
    code, stdout, stderr = run_cade(["register", "--reference", left, "--moving", right, "-o", tmp_path / "r.tif", "--max-disp", 8], capfd)
    assert code == 0 and "valid 0.0%" in stdout and "no texture" in stderr


def test_textured_pairs_keep_their_validity(pair, tmp_path, capfd):
    left, right = pair
    code, stdout, stderr = run_cade(["disparity", left, right, "-o", tmp_path / "d.pfm", "--max-disp", 8], capfd)
    assert code == 0 and "warning" not in stderr
    assert float(stdout.split("valid ")[1].split("%")[0]) > 80


def test_a_flat_area_in_one_band_makes_those_estimates_invalid(rng):
    from cade_cli.stereo import estimate_disparity

    rendered = render_pair(rng, (40, 72), background=(4.0, 0.0))
    left, right = rendered.left.copy(), rendered.right.copy()
    right[:, 30:60] = 1.0  # saturated in the right band only
    result = estimate_disparity(left, right, method="sgbm", max_disp=8)
    # flat 9x9 neighbourhoods of the right band: columns 34..55; x - d lands there for
    # every d in [0, 8] when x is in 42..55
    assert not result.valid[:, 42:56].any()
    assert result.valid[:, 10:25].mean() > 0.5
    assert np.isnan(result.disparity[~result.valid]).all()


@pytest.mark.parametrize("value", [1e30, -500.0, 72.0])
def test_register_refuses_values_that_are_not_disparities_of_the_pair(pair, tmp_path, capfd, value):
    left, right = pair
    given_map = tmp_path / "huge.npy"
    np.save(given_map, np.full((40, 72), value, np.float32))
    out = tmp_path / "o.tif"
    code, _, stderr = run_cade(["register", "--reference", left, "--moving", right, "-o", out, "--disparity", given_map], capfd)
    assert_one_line_error(code, stderr, str(given_map), "beyond", "72 px")
    assert not out.exists()


def test_register_refuses_a_map_without_a_valid_pixel(pair, tmp_path, capfd):
    left, right = pair
    given_map = tmp_path / "empty.pfm"
    write_disparity(given_map, np.full((40, 72), np.nan, np.float32))
    code, _, stderr = run_cade(["register", "--reference", left, "--moving", right, "-o", tmp_path / "o.tif", "--disparity", given_map], capfd)
    assert_one_line_error(code, stderr, str(given_map), "no valid pixel")


@pytest.mark.parametrize("kept", [0.02, 0.3, 0.9])
def test_a_truncated_png_prints_only_our_line(pair, tmp_path, capfd, kept):
    left, right = pair
    truncated = tmp_path / "t.png"
    truncated.write_bytes(left.read_bytes()[: int(kept * left.stat().st_size)])
    code, _, stderr = run_cade(["disparity", truncated, right, "-o", tmp_path / "d.pfm", "--max-disp", 8], capfd)
    assert_one_line_error(code, stderr, str(truncated), "corrupt or truncated")


def test_decoder_messages_never_reach_the_terminal(pair, tmp_path):
    """As a user runs it: a separate process, C decoders writing straight to fd 2."""
    left, right = pair
    truncated = tmp_path / "t.png"
    truncated.write_bytes(left.read_bytes()[: len(left.read_bytes()) * 3 // 4])
    failed = subprocess.run([sys.executable, "-m", "cade_cli", "disparity", truncated, right, "-o",
                             tmp_path / "d.pfm", "--max-disp", "8"], capture_output=True, text=True)
    assert failed.returncode == 1 and failed.stderr.count("\n") == 1, failed.stderr
    assert failed.stderr.startswith("cade: error: cannot decode")


@pytest.mark.parametrize("kept", [8, 60, 200])
def test_a_damaged_tiff_prints_only_our_line(pair, tmp_path, capfd, kept):
    _, right = pair
    damaged = tmp_path / "t.tif"
    tifffile.imwrite(damaged, np.zeros((40, 72), np.uint8))
    damaged.write_bytes(damaged.read_bytes()[:kept])  # tifffile logs a warning per damaged tag
    code, _, stderr = run_cade(["disparity", damaged, right, "-o", tmp_path / "d.pfm", "--max-disp", 8], capfd)
    assert_one_line_error(code, stderr, str(damaged))


def test_links_that_lead_nowhere_are_named_as_such(pair, tmp_path, capfd):
    left, right = pair
    (tmp_path / "loop1.png").symlink_to(tmp_path / "loop2.png")
    (tmp_path / "loop2.png").symlink_to(tmp_path / "loop1.png")
    (tmp_path / "broken.png").symlink_to(tmp_path / "gone.png")
    for source, words in ((tmp_path / "loop1.png", ("symbolic link", "loops")),
                          (tmp_path / "broken.png", ("broken symbolic link", "gone.png")),
                          (tmp_path / "missing.png", ("does not exist",))):
        code, _, stderr = run_cade(["disparity", source, right, "-o", tmp_path / "d.pfm"], capfd)
        assert_one_line_error(code, stderr, str(source), *words)


def test_a_decompression_bomb_is_refused_as_too_large(pair, tmp_path, capfd):
    _, right = pair
    bomb = bomb_png(tmp_path / "bomb.png")
    code, _, stderr = run_cade(["disparity", bomb, right, "-o", tmp_path / "d.pfm"], capfd)
    assert_one_line_error(code, stderr, str(bomb), "too large", "60000x60000")


def huge_headers(folder: Path) -> list[Path]:
    """Small files of every format whose header announces 60000 x 60000 pixels."""
    side = 60000
    files = [bomb_png(folder / "bomb.png")]
    jpeg = folder / "bomb.jpg"
    frame = b"\xff\xc0" + struct.pack(">HBHHB", 11, 8, side, side, 1) + b"\x01\x11\x00"
    jpeg.write_bytes(b"\xff\xd8" + b"\xff\xe0" + struct.pack(">H", 16) + b"JFIF\0" + b"\0" * 9 + frame + b"\xff\xd9")
    bmp = folder / "bomb.bmp"
    bmp.write_bytes(b"BM" + struct.pack("<IHHI", 1000, 0, 0, 54) + struct.pack("<IiiHHIIiiII", 40, side, side, 1, 8,
                                                                                   0, 0, 0, 0, 0, 0) + b"\0" * 100)
    pgm = folder / "bomb.pgm"
    pgm.write_bytes(b"P5\n# a comment\n%d %d\n255\n" % (side, side) + b"\0" * 100)
    pfm = folder / "bomb.pfm"
    pfm.write_bytes(b"Pf\n%d %d\n-1.0\n" % (side, side) + b"\0" * 100)
    tiff = folder / "bomb.tif"
    with tifffile.TiffWriter(tiff) as writer:  # a real header, announcing pixels that are not there
        writer.write(shape=(side, side), dtype=np.uint8, photometric="minisblack")
    npy = folder / "bomb.npy"
    header = {"descr": "<f4", "fortran_order": False, "shape": (side, side)}
    with open(npy, "wb") as stream:
        np.lib.format.write_array_header_1_0(stream, header)
        stream.write(b"\0" * 100)
    return [*files, jpeg, bmp, pgm, pfm, tiff, npy]


def test_every_reader_refuses_huge_headers_before_decoding(tmp_path):
    for path in huge_headers(tmp_path):
        reader = read_disparity if path.suffix in (".pfm", ".npy") else load_image
        with pytest.raises(CadeError, match="too large"):
            reader(path)
    assert 60000 * 60000 > MAX_IMAGE_PIXELS


def test_benchmark_errors_start_on_the_first_line(tmp_path, capfd):
    code, _, stderr = run_cade(["benchmark", "-d", "folder", "--data-dir", tmp_path / "nope"], capfd)
    assert_one_line_error(code, stderr, "does not exist")
    assert stderr.startswith("cade: error:")


@pytest.mark.parametrize("option", ["--scenes", "--methods", "--protocol", "--preprocess"])
@pytest.mark.parametrize("value", ["", " , "])
def test_benchmark_refuses_an_empty_list(folder_dataset, capfd, option, value):
    code, _, stderr = run_cade(["benchmark", "-d", "folder", "--data-dir", folder_dataset, option, value], capfd)
    assert_one_line_error(code, stderr, option, "names nothing")


def test_benchmark_save_dir_that_is_a_file(folder_dataset, tmp_path, capfd):
    (tmp_path / "maps").write_text("a file")
    code, _, stderr = run_cade(["benchmark", "-d", "folder", "--data-dir", folder_dataset, "--methods", "sgbm",
                                "--save-dir", tmp_path / "maps"], capfd)
    assert_one_line_error(code, stderr, "is a file, not a folder")


# --- the readers: whatever the bytes, only CadeError escapes ---

READERS = {
    ".png": (load_image, read_disparity, read_validity), ".jpg": (load_image,), ".bmp": (load_image,),
    ".pgm": (load_image,), ".tif": (load_image, read_disparity, read_validity), ".pfm": (read_disparity,),
    ".npy": (read_disparity,),
}
FUZZ = settings(max_examples=int(os.environ.get("CADE_FUZZ_EXAMPLES", "60")), deadline=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture])
"""60 examples per property keep the suite fast; CADE_FUZZ_EXAMPLES=5000 searches harder."""


def read_all(path: Path, capfd) -> None:
    """Every reader of ``path``'s format: a result or a CadeError, nothing else, and
    nothing printed (decoders' own messages included)."""
    capfd.readouterr()
    for reader in READERS[path.suffix]:
        try:
            result = reader(path)
        except CadeError as error:
            assert str(error) and "\n" not in str(error).strip()
        else:
            assert isinstance(result, np.ndarray)
    assert capfd.readouterr() == ("", "")


def valid_file(folder: Path, suffix: str, image: np.ndarray) -> Path:
    """``image`` written in the format of ``suffix`` the way users' tools write it."""
    path = folder / f"valid{suffix}"
    if suffix in (".pfm", ".npy"):
        write_disparity(path, image.astype(np.float32))
    elif suffix == ".tif":
        tifffile.imwrite(path, image)
    else:
        cv2.imwrite(str(path), image)
    return path


@FUZZ
@given(suffix=st.sampled_from(sorted(READERS)), data=st.binary(max_size=600))
def test_random_bytes_only_raise_cade_errors(tmp_path, capfd, suffix, data):
    path = tmp_path / f"random{suffix}"
    path.write_bytes(data)
    read_all(path, capfd)


@FUZZ
@given(suffix=st.sampled_from(sorted(READERS)), cut=st.floats(0.0, 1.0), flips=st.lists(
    st.tuples(st.floats(0.0, 1.0), st.integers(0, 255)), max_size=3), seed=st.integers(0, 2**16))
def test_truncated_and_damaged_files_only_raise_cade_errors(tmp_path, capfd, suffix, cut, flips, seed):
    image = (np.random.default_rng(seed).random((9, 13)) * 255).astype(np.uint8)
    raw = bytearray(valid_file(tmp_path, suffix, image).read_bytes())
    for where, value in flips:  # damage a byte (headers included)
        raw[int(where * (len(raw) - 1))] = value
    path = tmp_path / f"damaged{suffix}"
    path.write_bytes(bytes(raw[: max(1, int(cut * len(raw)))]))
    read_all(path, capfd)


DTYPES = ["u1", "i1", "u2", "i2", "u4", "i4", "i8", "f2", "f4", "f8", "?", "c8"]


@pytest.mark.filterwarnings("ignore:.*are stored as RGB:DeprecationWarning")  # tifffile's guess, fine here
@FUZZ
@given(dtype=st.sampled_from(DTYPES), shape=st.sampled_from([(1, 1), (5, 7), (5, 7, 2), (5, 7, 3), (5, 7, 5), (3,),
                                                              (2, 3, 4, 2)]),
       special=st.sampled_from([0.0, 1.0, -1.0, 1e30, -1e30, np.inf, -np.inf, np.nan]), seed=st.integers(0, 2**16))
def test_odd_dtypes_shapes_and_values_only_raise_cade_errors(tmp_path, capfd, dtype, shape, special, seed):
    values = np.random.default_rng(seed).normal(0, 1e4, shape)
    values.flat[0] = special
    with np.errstate(invalid="ignore", over="ignore"):
        array = values.astype(dtype)
    tiff, npy = tmp_path / "odd.tif", tmp_path / "odd.npy"
    tifffile.imwrite(tiff, array)
    np.save(npy, array)
    read_all(tiff, capfd)
    read_all(npy, capfd)


@FUZZ
@given(width=st.integers(0, 2**32 - 1), height=st.integers(0, 2**32 - 1))
def test_any_announced_size_only_raises_cade_errors(tmp_path, capfd, width, height):
    path = tmp_path / "sized.png"
    path.write_bytes(bomb_png(tmp_path / "template.png").read_bytes().replace(
        b"IHDR" + struct.pack(">II", 60000, 60000), b"IHDR" + struct.pack(">II", width, height)))
    read_all(path, capfd)
    pfm = tmp_path / "sized.pfm"
    pfm.write_bytes(b"Pf\n%d %d\n-1.0\n" % (width, height) + b"\0" * 64)
    read_all(pfm, capfd)


# --- determinism and concurrency ---

def test_same_input_same_bytes_and_parallel_runs_do_not_interfere(pair, tmp_path, capfd):
    """Two `cade` processes writing different outputs in one folder at once, and a third
    run in this process: every output is byte-identical to its twin, no temporary left."""
    left, right = pair
    out = tmp_path / "out"
    out.mkdir()

    def outputs(tag: str) -> list:
        return ["-o", out / f"{tag}.pfm", "--vis", out / f"{tag}_vis.png", "--validity", out / f"{tag}_valid.tif"]

    base = [sys.executable, "-m", "cade_cli", "disparity", left, right, "--max-disp", "8"]
    register = [sys.executable, "-m", "cade_cli", "register", "--reference", left, "--moving", right, "--max-disp", "8"]
    processes = [subprocess.Popen([*base, *outputs(tag)], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
                 for tag in ("a", "b")]
    processes += [subprocess.Popen([*register, "-o", out / f"{tag}.tif"], stdout=subprocess.PIPE,
                                   stderr=subprocess.PIPE) for tag in ("ra", "rb")]
    for process in processes:
        _, stderr = process.communicate(timeout=120)
        assert process.returncode == 0, stderr.decode()
    code, _, stderr = run_cade(["disparity", left, right, "--max-disp", 8, *outputs("c")], capfd)
    assert code == 0, stderr
    for suffix in (".pfm", "_vis.png", "_valid.tif"):
        first = (out / f"a{suffix}").read_bytes()
        assert (out / f"b{suffix}").read_bytes() == first and (out / f"c{suffix}").read_bytes() == first
    assert (out / "ra.tif").read_bytes() == (out / "rb.tif").read_bytes()
    assert hidden_files(out) == []


def test_benchmark_jobs_give_the_same_json_records(folder_dataset, tmp_path, capfd):
    runs = {}
    for jobs in (1, 2):
        out = tmp_path / f"jobs{jobs}.json"
        code, _, stderr = run_cade(["benchmark", "-d", "folder", "--data-dir", folder_dataset, "--methods", "sgbm",
                                    "--protocol", "cs,rgb", "--preprocess", "cade", "--jobs", jobs,
                                    "--json", out], capfd)
        assert code == 0, stderr
        runs[jobs] = json.loads(out.read_text())
    untimed = lambda run: [{k: v for k, v in r.items() if k != "seconds"} for r in run["records"]]  # noqa: E731
    assert untimed(runs[1]) == untimed(runs[2]) and len(runs[1]["records"]) == 2 * 7
    assert runs[1]["config"] == runs[2]["config"]

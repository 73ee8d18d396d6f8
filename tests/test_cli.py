"""The ``cade`` command end to end: outputs, notes, and one clean line per user error."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import tifffile

from cade_cli import cli
from cade_cli.io.disparity import read_disparity
from cade_cli.io.images import load_image
from synthetic import render_pair
from cli_runner import run_cade, write_png16


@pytest.fixture
def pair_files(tmp_path, rng):
    """A rendered pair on disk: left as 16-bit PNG, right through another 'filter'."""
    pair = render_pair(rng, (72, 112), background=(5.0, 0.04), foreground=(13.0, 0.0))
    left = write_png16(tmp_path / "left_bp400.png", pair.left)
    right = write_png16(tmp_path / "right_bp900.png", 0.1 + 0.5 * pair.right**2.0)
    return pair, left, right


def test_disparity_writes_an_accurate_map_and_a_summary(pair_files, tmp_path, capsys):
    pair, left, right = pair_files
    out, vis = tmp_path / "disp.pfm", tmp_path / "disp_vis.png"
    code, stdout, stderr = run_cade(["disparity", left, right, "-o", out, "--max-disp", 20, "--vis", vis], capsys)
    assert code == 0, stderr
    estimate = read_disparity(out)
    assert np.abs(estimate - pair.disparity)[pair.reliable].mean() < 0.5
    picture = cv2.imread(str(vis))
    assert picture.shape[0] > 72 and picture.shape[1] >= 112  # the map, and its colour bar under it
    assert len(stdout.strip().splitlines()) == 1
    assert "112x72" in stdout and "valid" in stdout and "cade+cade" in stdout  # the default, auto resolved


@pytest.mark.parametrize("suffix", [".tif", ".png", ".npy"])
def test_disparity_output_formats(pair_files, tmp_path, capsys, suffix):
    pair, left, right = pair_files
    out = tmp_path / f"disp{suffix}"
    code, _, stderr = run_cade(["disparity", left, right, "-o", out, "--max-disp", 20], capsys)
    assert code == 0, stderr
    assert np.abs(read_disparity(out) - pair.disparity)[pair.reliable].mean() < 0.5


def test_default_max_disp_is_announced(pair_files, tmp_path, capsys):
    _, left, right = pair_files
    code, _, stderr = run_cade(["disparity", left, right, "-o", tmp_path / "d.pfm", "--method", "sgbm"], capsys)
    assert code == 0
    assert "--max-disp not given: searching up to 32 px" in stderr  # 112 / 4 = 28 -> 32


def test_colour_input_is_converted_with_a_note(tmp_path, rng, capsys):
    pair = render_pair(rng, (48, 80))
    rgb = (np.stack([pair.left] * 3, axis=2) * 255).astype(np.uint8)
    cv2.imwrite(str(tmp_path / "l.png"), rgb)
    write_png16(tmp_path / "r.png", pair.right)
    code, _, stderr = run_cade(["disparity", tmp_path / "l.png", tmp_path / "r.png", "-o", tmp_path / "d.npy",
                                "--max-disp", 12], capsys)
    assert code == 0
    assert "luminance" in stderr and "--left-band" in stderr


def test_band_selection_from_multiband_tiff(tmp_path, rng, capsys):
    pair = render_pair(rng, (48, 80), background=(4.0, 0.0))
    noise = rng.random((48, 80)).astype(np.float32)
    tifffile.imwrite(tmp_path / "stack.tif", np.stack([noise, pair.left, noise]), photometric="minisblack")
    tifffile.imwrite(tmp_path / "other.tif", np.stack([pair.right, noise]), photometric="minisblack")
    out = tmp_path / "d.pfm"
    code, _, stderr = run_cade(["disparity", tmp_path / "stack.tif", tmp_path / "other.tif", "-o", out,
                                "--left-band", 1, "--right-band", 0, "--max-disp", 10], capsys)
    assert code == 0, stderr
    assert np.abs(read_disparity(out) - 4.0)[pair.reliable].mean() < 0.3


def test_negative_min_disp(tmp_path, rng, capsys):
    pair = render_pair(rng, (64, 96), background=(-5.0, 0.0), foreground=(4.0, 0.0))
    left, right = write_png16(tmp_path / "l.png", pair.left), write_png16(tmp_path / "r.png", pair.right)
    out = tmp_path / "d.tif"
    code, _, stderr = run_cade(["disparity", left, right, "-o", out, "--min-disp", -8, "--max-disp", 8], capsys)
    assert code == 0, stderr
    assert np.abs(read_disparity(out) - pair.disparity)[pair.reliable].mean() < 0.5


def test_register_writes_reference_registered_and_validity(pair_files, tmp_path, capsys):
    pair, left, right = pair_files
    out = tmp_path / "registered.tif"
    code, stdout, stderr = run_cade(["register", "--reference", left, "--moving", right, "-o", out, "--max-disp", 20, "--fill", "none"], capsys)
    assert code == 0, stderr
    bands = load_image(out)
    assert bands.shape == (72, 112, 3) and bands.dtype == np.float32
    reference, registered, valid = bands[..., 0], bands[..., 1], bands[..., 2]
    np.testing.assert_allclose(reference, load_image(left), atol=1e-6)
    expected = 0.1 + 0.5 * pair.left**2.0  # the right 'filter' seen from the left view
    trusted = pair.reliable & (valid == 1.0)
    assert trusted.sum() > 0.9 * pair.reliable.sum()
    assert np.abs(registered - expected)[trusted].mean() < 0.02
    assert set(np.unique(valid)) <= {0.0, 1.0}
    assert np.array_equal(np.isnan(registered), valid == 0.0)


def test_register_with_a_given_disparity(pair_files, tmp_path, capsys):
    pair, left, right = pair_files
    disparity = tmp_path / "gt.pfm"
    from cade_cli.io.disparity import write_disparity

    write_disparity(disparity, pair.disparity)
    out = tmp_path / "registered.tiff"
    code, _, stderr = run_cade(["register", "--reference", left, "--moving", right, "-o", out, "--disparity", disparity], capsys)
    assert code == 0, stderr
    registered = load_image(out)[..., 1]
    assert np.abs(registered - (0.1 + 0.5 * pair.left**2.0))[pair.reliable].mean() < 0.01


# --- bad input: one line on stderr, non-zero exit, nothing written or overwritten ---

def corrupt(path: Path) -> Path:
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + b"garbage" * 10)
    return path


BAD_INPUTS = {
    "missing file": (lambda d, l, r: [d / "nope.png", r], "does not exist"),
    "corrupt file": (lambda d, l, r: [corrupt(d / "bad.png"), r], "cannot decode"),
    "unsupported input extension": (lambda d, l, r: [l.rename(d / "left.gif"), r], "unsupported extension"),
    "different sizes": (lambda d, l, r: [l, write_png16(d / "small.png", np.zeros((70, 112)))], "differ in size"),
    "smaller than window": (
        lambda d, l, r: [write_png16(d / "a.png", np.zeros((4, 40))), write_png16(d / "b.png", np.zeros((4, 40)))],
        "smaller than"),
    "band out of range": (lambda d, l, r: [l, r, "--left-band", 3], "out of range"),
    "max-disp below min-disp": (lambda d, l, r: [l, r, "--max-disp", -1], "--max-disp -1 is below --min-disp 0"),
    "max-disp too wide": (lambda d, l, r: [l, r, "--max-disp", 112], "does not fit"),
    "unknown method": (lambda d, l, r: [l, r, "--method", "magic"], "unknown method"),
    "unknown preprocess": (lambda d, l, r: [l, r, "--preprocess", "magic"], "unknown preprocess"),
    "not a number": (lambda d, l, r: [l, r, "--max-disp", "ten"], "--max-disp"),
}


@pytest.mark.parametrize("case", BAD_INPUTS)
def test_bad_input_fails_cleanly(pair_files, tmp_path, capsys, case):
    _, left, right = pair_files
    make_args, message = BAD_INPUTS[case]
    out = tmp_path / "disp.pfm"
    out.write_bytes(b"previous result")
    args = make_args(tmp_path, left, right)
    extra = [] if "--max-disp" in map(str, args) else ["--max-disp", 20]
    code, stdout, stderr = run_cade(["disparity", *args[:2], "-o", out, *args[2:], *extra], capsys)
    assert code != 0
    assert len(stderr.strip().splitlines()) == 1, stderr
    assert stderr.startswith("cade: error:") and message in stderr
    assert out.read_bytes() == b"previous result"
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".")) == []  # no temp files


@pytest.mark.parametrize(
    "output, message",
    [("missing_dir/disp.pfm", "does not exist"), ("disp.jpg", "unsupported extension"), ("left_bp400.png", "also an input")],
)
def test_bad_output_fails_before_any_work(pair_files, tmp_path, capsys, output, message):
    _, left, right = pair_files
    before = left.read_bytes()
    code, _, stderr = run_cade(["disparity", left, right, "-o", tmp_path / output, "--max-disp", 20], capsys)
    assert code != 0 and message in stderr and len(stderr.strip().splitlines()) == 1
    assert left.read_bytes() == before
    assert not (tmp_path / "missing_dir").exists()


def test_vis_must_not_replace_the_disparity_file(pair_files, tmp_path, capsys):
    _, left, right = pair_files
    out = tmp_path / "d.png"
    code, _, stderr = run_cade(["disparity", left, right, "-o", out, "--vis", out, "--max-disp", 20], capsys)
    assert code != 0 and "same file" in stderr and not out.exists()


def test_png_output_refuses_disparities_from_256(tmp_path, rng, capsys):
    # KITTI PNGs store d * 256 in uint16: 256 px and beyond cannot be written.
    pair = render_pair(rng, (40, 400), background=(270.0, 0.0))
    left, right = write_png16(tmp_path / "l.png", pair.left), write_png16(tmp_path / "r.png", pair.right)
    out = tmp_path / "d.png"
    code, _, stderr = run_cade(["disparity", left, right, "-o", out, "--min-disp", 260, "--max-disp", 280,
                                "--method", "sgbm"], capsys)
    assert code != 0 and "256" in stderr
    assert not out.exists()


def test_register_rejects_a_mismatched_disparity(pair_files, tmp_path, capsys):
    _, left, right = pair_files
    np.save(tmp_path / "wrong.npy", np.zeros((10, 10), np.float32))
    out = tmp_path / "r.tif"
    code, _, stderr = run_cade(["register", "--reference", left, "--moving", right, "-o", out, "--disparity", tmp_path / "wrong.npy"], capsys)
    assert code != 0 and "does not match" in stderr and not out.exists()


def test_real_process_has_no_traceback_and_help_stays_light(tmp_path):
    """As a user runs it: a separate process, and --help without onnxruntime or torch."""
    failed = subprocess.run([sys.executable, "-m", "cade_cli", "disparity", tmp_path / "a.png", tmp_path / "b.png",
                             "-o", tmp_path / "d.pfm"], capture_output=True, text=True)
    assert failed.returncode != 0
    assert failed.stderr.strip().count("\n") == 0 and "Traceback" not in failed.stderr
    probe = ("import sys; from cade_cli import cli\n"
             "for args in (['--help'], ['--version'], ['disparity', '--help']):\n"
             "    try: cli.main(args)\n"
             "    except SystemExit as e: assert e.code == 0, e.code\n"
             "print(sorted(m for m in ('torch', 'onnxruntime', 'cv2') if m in sys.modules))")
    light = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True)
    assert light.returncode == 0, light.stderr
    assert light.stdout.strip().splitlines()[-1] == "[]"


def test_method_names_in_help_match_the_registry():
    from cade_cli.matching import MATCHERS

    assert tuple(MATCHERS) == cli.METHOD_NAMES


def test_the_commands_default_to_the_library_default_method():
    from cade_cli.stereo import DEFAULT_METHOD

    assert cli.DEFAULT_METHOD == DEFAULT_METHOD


def test_unfilled_output_and_validity_mark_what_the_matcher_rejected(pair_files, tmp_path, capsys):
    """--fill none writes the format's invalid marker exactly where --validity says 0, and
    the filled map agrees with the unfilled one wherever the matcher kept its estimate."""
    pair, left, right = pair_files
    dense, unfilled, mask = tmp_path / "dense.pfm", tmp_path / "unfilled.pfm", tmp_path / "valid.png"
    args = [left, right, "--max-disp", 20, "--method", "census-sgm"]
    assert run_cade(["disparity", *args, "-o", dense], capsys)[0] == 0
    code, stdout, stderr = run_cade(["disparity", *args, "-o", unfilled, "--fill", "none", "--validity", mask], capsys)
    assert code == 0, stderr
    valid = cv2.imread(str(mask), cv2.IMREAD_UNCHANGED) == 255
    sparse = read_disparity(unfilled)
    assert 0 < (~valid).sum() < valid.size // 4  # the left border and occlusions, not more
    assert np.array_equal(np.isfinite(sparse), valid)
    assert np.array_equal(sparse[valid], read_disparity(dense)[valid])
    assert np.isfinite(read_disparity(dense)).all()


def test_register_trusts_only_the_valid_pixels_of_a_given_map(pair_files, tmp_path, capsys):
    pair, left, right = pair_files
    disparity, mask, out = tmp_path / "d.pfm", tmp_path / "valid.tif", tmp_path / "reg.tif"
    assert run_cade(["disparity", left, right, "-o", disparity, "--max-disp", 20, "--validity", mask], capsys)[0] == 0
    code, stdout, stderr = run_cade(["register", "--reference", left, "--moving", right, "-o", out, "--disparity", disparity,
                                     "--validity", mask], capsys)
    assert code == 0, stderr
    registered_valid = tifffile.imread(out)[2] > 0
    written_valid = tifffile.imread(mask) > 0
    assert not (registered_valid & ~written_valid).any() and (~written_valid).any()
    code, _, stderr = run_cade(["register", "--reference", left, "--moving", right, "-o", tmp_path / "r2.tif", "--validity", mask], capsys)
    assert code != 0 and "--validity needs --disparity" in stderr


def test_model_option_runs_another_exported_network(pair_files, tmp_path, capsys):
    """--model takes a card's path (a copy of the shipped card and files in another folder:
    same map) and refuses a missing card and the classical methods in one line."""
    import shutil

    from cade_cli.model_card import card_path, read_card

    pair, left, right = pair_files
    folder = tmp_path / "mine"
    folder.mkdir()
    for variant in read_card().variants:
        shutil.copy(variant.path, folder)
    shutil.copy(card_path(), folder / "my-model.json")
    shipped, mine = tmp_path / "a.pfm", tmp_path / "b.pfm"
    assert run_cade(["disparity", left, right, "-o", shipped, "--max-disp", 20], capsys)[0] == 0
    code, _, stderr = run_cade(["disparity", left, right, "-o", mine, "--max-disp", 20,
                                "--model", folder / "my-model.json"], capsys)
    assert code == 0, stderr
    assert np.array_equal(read_disparity(shipped), read_disparity(mine))
    code, _, stderr = run_cade(["disparity", left, right, "-o", tmp_path / "c.pfm", "--max-disp", 20, "--model", tmp_path / "no.json"],
                               capsys)
    assert code != 0 and "no.json" in stderr and len(stderr.strip().splitlines()) == 1
    code, _, stderr = run_cade(["disparity", left, right, "-o", tmp_path / "c.pfm", "--method", "sgbm",
                                "--model", folder / "my-model.json"], capsys)
    assert code != 0 and "has no network" in stderr and not (tmp_path / "c.pfm").exists()


def shifted_texture_files(tmp_path, rng, shift: int, width: int = 160) -> tuple[Path, Path]:
    """A seeded texture as LEFT and RIGHT(x) = LEFT(x + shift): a pair of known, constant
    disparity ``shift`` (I_left(x) = I_right(x - d); negative: seen behind the pair's plane)."""
    from synthetic import smooth_texture

    texture = smooth_texture(rng, (64, width + 2 * abs(shift) + 20))
    start = abs(shift) + 10
    left = write_png16(tmp_path / "l.png", texture[:, start:start + width])
    right = write_png16(tmp_path / "r.png", texture[:, start + shift:start + shift + width])
    return left, right


def test_png_output_refuses_a_range_beyond_it_before_matching(tmp_path, rng, capsys, monkeypatch):
    """A 16-bit PNG holds 0 <= d < 256: the default range of a wide image (a quarter of 1100 px)
    and a negative --min-disp are refused before any matching, in one line naming the user's
    path (never a temporary file) and the fix."""
    import cade_cli.scale.tiling

    def no_matching(*args, **kwargs):
        raise AssertionError("matched before refusing the output")

    monkeypatch.setattr(cade_cli.scale.tiling, "estimate_disparity_tiled", no_matching)
    left, right = shifted_texture_files(tmp_path, rng, 10, width=1100)
    out = tmp_path / "d.png"
    for extra, fix in (([], "--max-disp below 256"), (["--min-disp", -4, "--max-disp", 20], "--min-disp of 0")):
        code, _, stderr = run_cade(["disparity", left, right, "-o", out, "-m", "census-sgm", *extra], capsys)
        errors = [line for line in stderr.splitlines() if not line.startswith("note:")]
        assert code != 0 and len(errors) == 1, stderr
        assert str(out) in errors[0] and fix in errors[0] and ".pfm, .tif or .npy" in errors[0]
        assert ".tmp-" not in stderr and not out.exists()


def test_an_empty_or_one_value_range_is_refused_before_any_work(tmp_path, rng, capsys, monkeypatch):
    """--max-disp 0 with the default --min-disp 0 (and any max == min) would give every pixel the one
    disparity, "valid 100 %": disparity and register refuse it before reading the pair, in one line
    that says what to give; a range entirely at or below zero stays allowed."""
    import cade_cli.cli.pairs
    import cade_cli.cli.register

    def no_reading(*args, **kwargs):
        raise AssertionError("read the pair before refusing the range")

    left, right = shifted_texture_files(tmp_path, rng, 3)
    for module in (cade_cli.cli.pairs, cade_cli.cli.register):
        monkeypatch.setattr(module, "read_pair", no_reading)
    out = tmp_path / "d.pfm"
    for command in ("disparity", "register"):
        for bounds, message in ((["--max-disp", 0], "--min-disp 0 and --max-disp 0 leave one disparity"),
                                (["--min-disp", 7, "--max-disp", 7], "--min-disp 7 and --max-disp 7 leave one"),
                                (["--min-disp", 4, "--max-disp", 2], "--max-disp 2 is below --min-disp 4")):
            pair = [left, right] if command == "disparity" else ["--reference", left, "--moving", right]
            code, stdout, stderr = run_cade([command, *pair, "-o", out, *bounds], capsys)
            assert code != 0 and len(stderr.strip().splitlines()) == 1, stderr
            assert stderr.startswith("cade: error:") and message in stderr
            assert "--max-disp" in stderr and not out.exists()
    from cade_cli.errors import CadeError
    from cade_cli.matching import DisparityRange

    with pytest.raises(CadeError, match=r"\[5, 5\] holds one value"):
        DisparityRange(5, 5).check_for_width(64)
    DisparityRange(-80, 0).check_for_width(100)  # entirely below zero: searched


def test_range_entirely_below_zero_and_auto_for_register(tmp_path, rng, capsys):
    """--min-disp -30 --max-disp 0 finds a disparity of -12 (disparity and register), and register
    takes --max-disp / --min-disp auto like disparity does."""
    left, right = shifted_texture_files(tmp_path, rng, -12)
    out = tmp_path / "d.tif"
    code, stdout, stderr = run_cade(["disparity", left, right, "-o", out, "-m", "census-sgm", "--min-disp", -30,
                                     "--max-disp", 0], capsys)
    assert code == 0, stderr
    assert np.median(read_disparity(out)[8:-8, 8:-30]) == pytest.approx(-12, abs=0.25)
    registered = tmp_path / "reg.tif"
    code, stdout, stderr = run_cade(["register", "--reference", left, "--moving", right, "-o", registered, "-m", "census-sgm", "--min-disp",
                                     "auto", "--max-disp", 0], capsys)
    assert code == 0, stderr
    assert "note: --min-disp auto: searching [" in stderr and ", 0] px" in stderr
    bands = load_image(registered)
    inner = (slice(8, -8), slice(8, -30))
    assert np.abs(bands[..., 1] - bands[..., 0])[inner].mean() < 0.02  # the moving band lands on the reference
    code, _, stderr = run_cade(["register", "--reference", left, "--moving", right, "-o", registered, "-m", "census-sgm", "--max-disp", "ten"],
                               capsys)
    assert code != 0 and "'auto'" in stderr and "valid integer" not in stderr


def test_step_bar_counts_stages_and_the_tiles_added_to_them():
    from cade_cli.cli.options import StepBar

    with StepBar(3, "checking the pair") as bar:
        bar.advance("matching")
        bar.advance("matching 5 tiles", steps=0, more=4)
        bar.advance()
        task = bar.progress.tasks[0]
        assert (task.completed, task.total, task.description) == (2, 7, "matching 5 tiles")


def test_a_step_bar_without_a_total_takes_one_when_the_work_is_known():
    from cade_cli.cli.options import StepBar

    with StepBar(None, "benchmark middlebury14") as bar:  # the benchmark: its runs are counted after loading
        assert bar.progress.tasks[0].total is None
        bar.set_total(12)
        bar.advance("middlebury14 1")
        task = bar.progress.tasks[0]
        assert (task.completed, task.total, task.description) == (1, 12, "middlebury14 1")

"""The benchmark loop end to end on a tiny dataset we render ourselves: one decode per
scene, task subsets, degraded right bands, timing, deterministic parallel runs."""

from __future__ import annotations

import dataclasses
import gzip
import json
from pathlib import Path

import numpy as np
import pytest

from cade_cli import cli
from cade_cli.data import DATASETS
from cade_cli.errors import CadeError
from cade_cli.evaluation.loop import run_benchmark
from cade_cli.evaluation.report import markdown
from cade_cli.evaluation.timing import Timing
from cade_cli.matching import DisparityResult
from conftest import FOLDER_DISPARITY as DISPARITY



class Oracle:
    """A matcher that returns the known disparity (all valid) and remembers its calls."""

    def __init__(self):
        self.calls = []

    def __call__(self, left, right, *, max_disp, min_disp=0, preprocess="auto"):
        self.calls.append((left.copy(), right.copy(), max_disp, preprocess))
        return DisparityResult(np.full(left.shape, DISPARITY, np.float32), np.ones(left.shape, bool))


@pytest.fixture
def oracle() -> dict:
    return {"oracle": Oracle()}


@pytest.fixture
def counted_loads(monkeypatch) -> list[str]:
    """Registers dataset "counted": the folder reader, logging each scene it decodes."""
    loads: list[str] = []
    folder = DATASETS["folder"]

    def list_scenes(root, resolution):
        def counted(name, load):
            loads.append(name)
            return load()

        return {name: (lambda name=name, load=load: counted(name, load))
                for name, load in folder.list_scenes(root, resolution).items()}

    monkeypatch.setitem(DATASETS, "counted", dataclasses.replace(folder, name="counted", list_scenes=list_scenes))
    return loads


def test_a_matcher_returning_the_ground_truth_scores_zero(folder_dataset, oracle):
    run = run_benchmark(dataset="folder", data_dir=folder_dataset, methods=["oracle"], matchers=oracle,
                        protocols=["cs", "rgb", "native"], preprocess=["none"])
    assert len(run.records) == 2 * (6 + 1 + 1)  # scenes x (CS tasks + RGB median + native)
    for record in run.records:
        assert record.scores["epe_all"] == 0.0
        assert all(record.scores[f"bad{t}_all"] == 0.0 for t in (1, 2, 3, 5))
        assert record.scores["invalid"] == 0.0
    assert [row["protocol"] for row in run.summary()] == ["cs", "rgb", "native"]


def test_a_real_matcher_scores_plausibly_and_orders_columns(folder_dataset):
    run = run_benchmark(dataset="folder", data_dir=folder_dataset, methods=["census-sgm", "sgbm"],
                        protocols=["cs"], preprocess=["none", "cade"])
    rows = run.summary()
    assert [(r["method"], r["preprocess"]) for r in rows] == [
        ("census-sgm", "none"), ("census-sgm", "cade"), ("sgbm", "none"), ("sgbm", "cade")]
    census = rows[0]["scores"]
    assert census["epe_all"] < 1.0 and census["bad3_all"] < 10.0
    assert rows[0]["maps"] == 2 * 6


def test_jobs_do_not_change_the_results(folder_dataset):
    kwargs = dict(dataset="folder", data_dir=folder_dataset, methods=["sgbm"], protocols=["cs", "rgb"],
                  preprocess=["cade"])
    serial, parallel = run_benchmark(jobs=1, **kwargs), run_benchmark(jobs=2, **kwargs)
    strip = lambda run: [(r.scene, r.protocol, r.task, r.scores) for r in run.records]  # noqa: E731
    assert strip(serial) == strip(parallel)
    assert [r.scene for r in parallel.records] == ["first"] * 7 + ["second"] * 7  # scene order


def test_save_dir_writes_disparities_and_error_maps(folder_dataset, tmp_path):
    save = tmp_path / "saved"
    run_benchmark(dataset="folder", data_dir=folder_dataset, methods=["sgbm"], protocols=["rgb"],
                  preprocess=["none"], scenes=["first"], save_dir=save)
    folder = save / "sgbm+none" / "rgb"
    assert sorted(p.name for p in folder.iterdir()) == ["first_RGB-median.pfm", "first_RGB-median_error.png"]


def test_unknown_names_fail_with_the_choices(folder_dataset):
    with pytest.raises(CadeError, match="census-sgm"):
        run_benchmark(dataset="folder", data_dir=folder_dataset, methods=["nope"], protocols=["cs"], preprocess=["none"])
    with pytest.raises(CadeError, match="cs"):
        run_benchmark(dataset="folder", data_dir=folder_dataset, methods=["sgbm"], protocols=["xx"], preprocess=["none"])
    with pytest.raises(CadeError, match="second"):
        run_benchmark(dataset="folder", data_dir=folder_dataset, methods=["sgbm"], protocols=["cs"],
                      preprocess=["none"], scenes=["third"])


def test_cli_writes_json_and_markdown(folder_dataset, tmp_path, capsys):
    out_json, out_md = tmp_path / "r.json", tmp_path / "r.md"
    with pytest.raises(SystemExit) as exit_info:
        cli.main(["benchmark", "--dataset", "folder", "--data-dir", str(folder_dataset), "--methods", "sgbm",
                  "--protocol", "cs", "--preprocess", "cade", "--json", str(out_json), "--report", str(out_md)])
    assert exit_info.value.code == 0
    printed = capsys.readouterr().out
    assert "sgbm + cade" in printed and "all pixels with ground truth" in printed
    data = json.loads(out_json.read_text())
    assert len(data["records"]) == 12 and data["summary"][0]["method"] == "sgbm"
    report = out_md.read_text()
    assert "folder (64x40, 2 scenes)" in report and "| sgbm + cade |" in report


def test_cli_bad_dataset_is_one_line(tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_info:
        cli.main(["benchmark", "--dataset", "nope", "--data-dir", str(tmp_path)])
    err = capsys.readouterr().err
    assert exit_info.value.code != 0 and len(err.strip().splitlines()) == 1 and "middlebury14" in err


def test_markdown_names_resolution_and_pixel_set(folder_dataset, oracle):
    run = run_benchmark(dataset="folder", data_dir=folder_dataset, methods=["oracle"], matchers=oracle,
                        protocols=["cs"], preprocess=["none"])
    text = markdown(run, command="cade benchmark ...")
    assert "all pixels with ground truth" in text and "non-occluded" not in text  # folder has no masks
    assert "| oracle + none | 0.00 | 0.0 | 0.0 |" in text


def test_each_scene_is_decoded_once_for_all_protocols_methods_and_preprocessing(folder_dataset, counted_loads,
                                                                                 oracle):
    run = run_benchmark(dataset="counted", data_dir=folder_dataset, methods=["oracle", "sgbm"],
                        matchers={**oracle, "sgbm": __import__("cade_cli.matching").matching.MATCHERS["sgbm"]},
                        protocols=["cs", "rgb"], preprocess=["none", "cade"])
    assert counted_loads == ["first", "second"]
    assert len(run.records) == 2 * 2 * 2 * (6 + 1)  # scenes x methods x preprocess x (CS + RGB median)
    first = [(r.protocol, r.method, r.preprocess, r.task) for r in run.records if r.scene == "first"]
    assert first[:7] == [("cs", "oracle", "none", t) for t in ("R>G", "R>B", "G>R", "G>B", "B>R", "B>G")] + [
        ("cs", "oracle", "cade", "R>G")]


def test_task_subset_runs_only_those_tasks(folder_dataset, oracle):
    run = run_benchmark(dataset="folder", data_dir=folder_dataset, methods=["oracle"], matchers=oracle,
                        protocols=["cs"], preprocess=["none"], tasks=["G>B", "R>B"])
    assert [(r.scene, r.task) for r in run.records] == [
        ("first", "R>B"), ("first", "G>B"), ("second", "R>B"), ("second", "G>B")]
    assert len(oracle["oracle"].calls) == 4
    with pytest.raises(CadeError, match="unknown task 'R>R'"):
        run_benchmark(dataset="folder", data_dir=folder_dataset, methods=["oracle"], matchers=oracle,
                      protocols=["cs"], preprocess=["none"], tasks=["R>R"])
    with pytest.raises(CadeError, match="protocol rgb"):
        run_benchmark(dataset="folder", data_dir=folder_dataset, methods=["oracle"], matchers=oracle,
                      protocols=["cs", "rgb"], preprocess=["none"], tasks=["R>B"])


def test_degradations_change_only_the_right_band(folder_dataset, oracle):
    run = run_benchmark(dataset="folder", data_dir=folder_dataset, scenes=["first"], methods=["oracle"],
                        matchers=oracle, protocols=["cs"], preprocess=["none"], tasks=["R>B"],
                        degradations=["none", "invert", "noise-6"])
    (plain_left, plain_right, *_), (left, right, *_), (noisy_left, noisy_right, *_) = oracle["oracle"].calls
    np.testing.assert_array_equal(left, plain_left)
    np.testing.assert_array_equal(noisy_left, plain_left)
    np.testing.assert_allclose(right, 1 - plain_right, atol=1e-6)
    assert 4 / 255 < np.std(noisy_right - plain_right) < 8 / 255
    assert [r.degradation for r in run.records] == ["none", "invert", "noise-6"]
    rows = run.summary(by=("degradation", "method"))
    assert [(row["degradation"], row["method"]) for row in rows] == [
        ("none", "oracle"), ("invert", "oracle"), ("noise-6", "oracle")]
    records = json.loads(run.to_json())["records"]
    assert "degradation" not in records[0] and records[1]["degradation"] == "invert"
    with pytest.raises(CadeError, match="unknown degradation 'fog'"):
        run_benchmark(dataset="folder", data_dir=folder_dataset, methods=["oracle"], matchers=oracle,
                      protocols=["cs"], preprocess=["none"], degradations=["fog"])


def test_timing_option_warms_up_and_repeats(folder_dataset, oracle):
    run = run_benchmark(dataset="folder", data_dir=folder_dataset, scenes=["first"], methods=["oracle"],
                        matchers=oracle, protocols=["native"], preprocess=["none"],
                        timing=Timing(warmup=1, repeat=3))
    assert len(oracle["oracle"].calls) == 4 and len(run.records) == 1
    assert run.config["timing"] == {"warmup": 1, "repeat": 3, "threads": None}
    assert run.scene_shapes == {"first": (40, 64, 16)}


def test_search_range_is_the_scenes_inclusive_max_disp(folder_dataset, oracle):
    run_benchmark(dataset="folder", data_dir=folder_dataset, scenes=["first"], methods=["oracle"],
                  matchers=oracle, protocols=["native"], preprocess=["cade"])
    ((_, _, max_disp, preprocess),) = oracle["oracle"].calls
    assert (max_disp, preprocess) == (16, "cade")  # max_disp_from_gt: 5 px -> 16


def test_preprocess_a_matcher_does_not_take_is_skipped(folder_dataset):
    run = run_benchmark(dataset="folder", data_dir=folder_dataset, scenes=["first"], methods=["sgbm", "cade"],
                        protocols=["native"], preprocess=["none", "cade"])
    assert [(r.method, r.preprocess) for r in run.records] == [("sgbm", "none"), ("sgbm", "cade"), ("cade", "cade")]


def test_compare_records_reports_each_changed_score(folder_dataset, oracle, tmp_path):
    import importlib.util

    script = Path(__file__).resolve().parents[1] / "benchmarks" / "compare_records.py"
    spec = importlib.util.spec_from_file_location("compare_records", script)
    compare = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(compare)
    run = run_benchmark(dataset="folder", data_dir=folder_dataset, methods=["oracle"], matchers=oracle,
                        protocols=["cs"], preprocess=["none"])
    old, new = tmp_path / "old.json", tmp_path / "new.json"
    old.write_text(run.to_json())
    data = json.loads(run.to_json())
    data["records"][3]["scores"]["epe_all"] = 0.25
    data["records"][3]["seconds"] = 99.0  # timing is not compared
    new.write_text(json.dumps(data))
    assert compare.main([str(old), str(old)]) == 0
    assert compare.main([str(old), str(new)]) == 1
    packed = tmp_path / "old.json.gz"  # docs/bench keeps its largest records gzipped
    packed.write_bytes(gzip.compress(old.read_bytes()))
    assert compare.main([str(packed), str(old)]) == 0 and compare.main([str(packed), str(new)]) == 1
    lines = [line for line in compare.differences(*[compare.records_by_key(p)[1] for p in (old, new)],
                                                  data["config"], 0.0)]
    assert lines == ["folder / first / cs / oracle / none / G>B / none: epe_all 0.0 -> 0.25 (+0.25)"]
    data["records"][3]["scores"]["epe_all"] = 0.0
    data["records"][0]["scores"]["auc_new"] = 1.0  # a score added since OLD
    new.write_text(json.dumps(data))
    assert compare.main([str(old), str(new)]) == 1
    assert compare.main([str(old), str(new), "--new-metrics"]) == 0


def _shipping_rule():
    import importlib.util

    script = Path(__file__).resolve().parents[1] / "benchmarks" / "shipping_rule.py"
    spec = importlib.util.spec_from_file_location("shipping_rule", script)
    rule = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(rule)
    return rule


def _rule_runs(tmp_path, scores: dict) -> list[str]:
    """dataset -> protocol -> method -> (EPE, BMP3): one JSON per dataset, two records per method and protocol."""
    paths = []
    for dataset, protocols in scores.items():
        records = [{"protocol": protocol, "method": method, "scores": {"epe_all": epe + delta, "bad3_all": bad}}
                   for protocol, methods in protocols.items() for method, (epe, bad) in methods.items()
                   for delta in (-0.1, 0.1)]
        path = tmp_path / f"{dataset}.json"
        path.write_text(json.dumps({"config": {"dataset": dataset}, "records": records}))
        paths.append(str(path))
    return paths


def test_the_shipping_rule_pools_every_middlebury_record_and_judges_each_set_by_its_tolerance(tmp_path, capsys):
    rule = _shipping_rule()
    rule.TOLERANCES.clear()  # every set at the default 3 %; a set's own tolerance is set below
    args = ["--shipped", "old", "--candidate", "new"]
    real = {"native": {"old": (1.0, 10.0), "new": (0.9, 9.0)}}
    scores = {"middlebury05": {"cs": {"old": (2.0, 20.0), "new": (1.9, 19.0)},
                               "rgb": {"old": (1.5, 15.0), "new": (1.5, 15.2)}},  # RGB alone slightly worse
              "middlebury14": {"cs": {"old": (5.0, 25.0), "new": (4.8, 24.5)},
                               "rgb": {"old": (4.0, 20.0), "new": (4.0, 20.0)}},
              "msir-outdoor": real}
    assert rule.main(args + _rule_runs(tmp_path, scores)) == 0  # pooled means lower, every set within 3 %
    out = capsys.readouterr().out
    assert "Middlebury means (8 records, 2005 + 2014, CS + RGB)" in out and "passes: ships" in out
    scores["middlebury05"]["rgb"]["new"] = (1.5, 15.6)  # +4 % BMP3: beyond the default 3 %
    assert rule.main(args + _rule_runs(tmp_path, scores)) == 1
    assert "sets worse beyond their tolerance: middlebury05 rgb" in capsys.readouterr().out
    rule.TOLERANCES[("middlebury05", "rgb")] = (0.01, 0.05)  # a noisier set: its own tolerance admits it
    assert rule.main(args + _rule_runs(tmp_path, scores)) == 0
    scores["middlebury14"]["cs"]["new"] = (4.8, 25.6)  # the pooled BMP3 is now higher
    assert rule.main(args + _rule_runs(tmp_path, scores)) == 1
    assert "not both lower" in capsys.readouterr().out


def test_the_shipping_rule_reads_gzipped_records_as_plain_ones(tmp_path, capsys):
    rule = _shipping_rule()
    rule.TOLERANCES.clear()
    args = ["--shipped", "old", "--candidate", "new"]
    scores = {"middlebury05": {"cs": {"old": (2.0, 20.0), "new": (1.9, 19.0)}},
              "msir-outdoor": {"native": {"old": (1.0, 10.0), "new": (0.9, 9.0)}}}
    plain = _rule_runs(tmp_path, scores)
    assert rule.main(args + plain) == 0
    expected = capsys.readouterr().out
    zipped = []
    for path in plain:
        Path(path + ".gz").write_bytes(gzip.compress(Path(path).read_bytes()))
        Path(path).unlink()
        zipped.append(path + ".gz")
    assert rule.main(args + zipped) == 0
    assert capsys.readouterr().out == expected


def test_the_shipping_rule_pools_kitti_and_needs_the_real_check(tmp_path, capsys):
    rule = _shipping_rule()
    rule.TOLERANCES.clear()  # every set at the default 3 %
    args = ["--shipped", "old", "--candidate", "new"]
    middlebury = {"cs": {"old": (2.0, 20.0), "new": (1.9, 19.0)}}
    scores = {"middlebury05": middlebury,
              "kitti2012": {"cs": {"old": (1.0, 6.0), "new": (1.0, 7.0)}},  # +17 % alone ...
              "kitti2015": {"cs": {"old": (1.0, 8.0), "new": (1.0, 7.2)}}}  # ... pooled with 2015: +1.4 %
    assert rule.main(args + _rule_runs(tmp_path, scores)) == 1  # no real cross-spectral check in the runs
    assert "cannot be decided" in capsys.readouterr().out
    scores["msir-outdoor"] = {"native": {"old": (1.0, 10.0), "new": (1.0, 10.0)}}
    assert rule.main(args + _rule_runs(tmp_path, scores)) == 0
    assert "| driving cs |" in capsys.readouterr().out
    scores["msir-outdoor"]["native"]["new"] = (1.1, 10.0)  # the real check 10 % worse
    assert rule.main(args + _rule_runs(tmp_path, scores)) == 1
    assert "sets worse beyond their tolerance: msir-outdoor native" in capsys.readouterr().out


def test_the_shipping_rule_prints_both_models_region_rows_and_judges_on_all_pixels(tmp_path, capsys):
    rule = _shipping_rule()
    rule.TOLERANCES.clear()
    args = ["--shipped", "old", "--candidate", "new"]
    scores = {"middlebury14": {"cs": {"old": (2.0, 20.0), "new": (1.9, 19.0)}},
              "msir-outdoor": {"native": {"old": (1.0, 10.0), "new": (1.0, 10.0)}}}
    paths = _rule_runs(tmp_path, scores)
    data = json.loads(Path(paths[0]).read_text())
    for record in data["records"]:  # regions: the candidate far worse at edges, the old model has no occ score
        new = record["method"] == "new"
        record["scores"].update({"epe_nonocc": 1.0, "bad3_nonocc": 10.0, "epe_edge": 8.0 if new else 4.0,
                                 "bad3_edge": 40.0 if new else 20.0})
        record["scores"].update({"epe_occ": 3.0, "bad3_occ": 30.0} if new else {"epe_occ": float("nan"),
                                                                                 "bad3_occ": float("nan")})
    Path(paths[0]).write_text(json.dumps(data))
    assert rule.main(args + paths) == 0  # the verdict stays on all pixels
    out = capsys.readouterr().out
    assert "| middlebury14 cs | non-occluded | 1.000 / 10.00 | 1.000 / 10.00 | +0.0% / +0.0% |" in out
    assert "| middlebury14 cs | depth edges | 4.000 / 20.00 | 8.000 / 40.00 | +100.0% / +100.0% |" in out
    assert "| middlebury14 cs | occluded | — | 3.000 / 30.00 | — |" in out
    assert "msir-outdoor native | non-occluded" not in out  # its records score no region


def test_shipping_tolerances_are_the_largest_change_between_neighbouring_checkpoints(tmp_path):
    rule = _shipping_rule()
    scores = {"kitti2012": {"cs": {"a": (1.0, 10.0), "b": (1.1, 9.0), "c": (1.1, 9.9)}}}
    spread = rule.tolerances(rule.read_records(_rule_runs(tmp_path, scores)), ["a", "b", "c"])
    assert spread == {("driving", "cs"): (0.1, 0.1)}  # EPE +10 % (a -> b), BMP3 +10 % (b -> c)


def test_several_models_score_in_one_run_as_method_colon_model(folder_dataset, tmp_path, capsys):
    """--model a,b: each learned method runs once per model (rows METHOD:MODEL); a copy of
    the shipped card under another name scores exactly as the shipped one."""
    import shutil

    from cade_cli.model_card import card_path, read_card

    folder = tmp_path / "my-models"
    folder.mkdir()
    for variant in read_card("fast").variants:
        shutil.copy(variant.path, folder)
    shutil.copy(card_path("fast"), folder / "copy.json")
    out_json = folder / "r.json"
    with pytest.raises(SystemExit) as exit_info:
        cli.main(["benchmark", "--dataset", "folder", "--data-dir", str(folder_dataset), "--methods",
                  "sgbm,cade-network", "--protocol", "rgb", "--preprocess", "cade", "--json", str(out_json),
                  "--model", f"fast,{folder / 'copy.json'}"])
    assert exit_info.value.code == 0
    summary = {row["method"]: row for row in json.loads(out_json.read_text())["summary"]}
    assert set(summary) == {"sgbm", "cade-network:fast", "cade-network:copy"}
    shipped, copy = summary["cade-network:fast"], summary["cade-network:copy"]
    assert {k: v for k, v in shipped.items() if k != "method" and "time" not in k and "s_per" not in k} == \
        {k: v for k, v in copy.items() if k != "method" and "time" not in k and "s_per" not in k}
    with pytest.raises(SystemExit) as exit_info:
        cli.main(["benchmark", "--dataset", "folder", "--data-dir", str(folder_dataset), "--methods", "cade-network",
                  "--model", f"fast,{folder / 'fast.json'}"])
    assert exit_info.value.code != 0


class RefusingNone(Oracle):
    """The oracle, taking only ``preprocess="cade"`` as the CADE network does."""

    def resolve_preprocess(self, value):
        if value == "none":
            raise CadeError("method refusing takes --preprocess cade (or auto), not none")
        return "cade" if value == "auto" else value


def test_what_does_not_apply_is_left_out_and_a_run_of_nothing_is_an_error(folder_dataset):
    """`cade` + `none`: no row of dashes, one reason kept in the config; only such combinations:
    an error saying why, before any scene runs."""
    matchers = {"oracle": Oracle(), "refusing": RefusingNone()}
    run = run_benchmark(dataset="folder", data_dir=folder_dataset, methods=["oracle", "refusing"], matchers=matchers,
                        protocols=["cs"], preprocess=["none", "cade"])
    assert run.config["not_applicable"] == {"refusing + none": "method refusing takes --preprocess cade (or auto), "
                                                                "not none"}
    report = markdown(run)
    assert "| refusing + cade |" in report and "| refusing + none |" not in report and "| oracle + none |" in report
    assert "Left out, as they do not apply: refusing + none: method refusing takes --preprocess cade" in report
    refusing = RefusingNone()
    with pytest.raises(CadeError, match=r"nothing to score: method refusing takes --preprocess cade"):
        run_benchmark(dataset="folder", data_dir=folder_dataset, methods=["refusing"],
                      matchers={"refusing": refusing}, protocols=["cs"], preprocess=["none"])
    assert not refusing.calls


def test_combinations_left_out_for_one_reason_are_named_in_one_clause():
    from cade_cli.evaluation.loop import BenchmarkRun
    from cade_cli.evaluation.report import left_out

    reason, other = "method cade takes --preprocess cade (or auto), not none", "another reason"
    run = BenchmarkRun({"not_applicable": {"cade:a + none": reason, "cade:b + none": reason, "x + none": other}})
    assert left_out(run) == f"cade:a + none, cade:b + none: {reason}; x + none: {other}"
    assert left_out(BenchmarkRun({"not_applicable": {}})) == ""


def test_cli_scoring_nothing_is_an_error_and_left_out_combinations_a_note(folder_dataset, tmp_path, capsys):
    out_json = tmp_path / "r.json"
    args = ["benchmark", "--dataset", "folder", "--data-dir", str(folder_dataset), "--protocol", "native"]
    with pytest.raises(SystemExit) as exit_info:
        cli.main([*args, "--methods", "cade", "--preprocess", "none", "--json", str(out_json)])
    captured = capsys.readouterr()
    assert exit_info.value.code != 0 and not out_json.exists() and not captured.out
    assert "nothing to score: method cade takes --preprocess cade" in captured.err
    assert len(captured.err.strip().splitlines()) == 1
    with pytest.raises(SystemExit) as exit_info:
        cli.main([*args, "--methods", "sgbm,cade-network", "--preprocess", "none,cade", "--scenes", "first"])
    captured = capsys.readouterr()
    assert exit_info.value.code == 0
    assert "note: left out, as they do not apply: cade-network + none: method cade-network takes --preprocess cade" \
        in captured.err
    assert "cade-network + cade" in captured.out and "cade-network + none" not in captured.out


def test_progress_counts_every_matcher_run(folder_dataset, oracle):
    """on_start gets the number of matcher runs and on_run is called that many times, in-process
    as each task is matched, or per scene from worker processes."""
    for jobs in (1, 2):
        started, runs = [], []
        run_benchmark(dataset="folder", data_dir=folder_dataset, methods=["sgbm"], protocols=["cs", "rgb"],
                      preprocess=["none", "cade"], jobs=jobs, on_start=started.append, on_run=runs.append)
        assert started == [2 * (6 + 3) * 2] and len(runs) == started[0]  # scenes x tasks x preprocessing
        assert runs[0] == ("first R>G: sgbm + none" if jobs == 1 else "first done")


def test_brightness_classes_put_each_gross_error_where_the_light_is():
    """A texture shifted 8 px, its left half darkened to 5 %: the dark class holds the left half's
    pixels, the bright one the right half's; the cade matcher recovers the bright half, and GT off
    by 10 px makes every scored pixel a gross error in every class."""
    import importlib.util

    from cade_cli.data import Scene
    from cade_cli.evaluation.protocols import get_protocol

    script = Path(__file__).resolve().parents[1] / "benchmarks" / "brightness.py"
    spec = importlib.util.spec_from_file_location("brightness", script)
    brightness = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(brightness)
    rng = np.random.default_rng(7)
    height, width, shift = 96, 160, 8
    grey = rng.random((height // 4, (width + shift) // 4, 1), dtype=np.float32)  # the same in every band
    texture = np.repeat(np.repeat(grey, 4, axis=0), 4, axis=1) * np.array([0.9, 1.0, 0.7], np.float32)
    light = np.where(np.arange(width + shift) < (width + shift) // 2, 0.05, 1.0).astype(np.float32)[None, :, None]
    texture = texture * light
    left, right = texture[:, :width], texture[:, shift:shift + width]
    gt = np.full((height, width), float(shift), np.float32)
    gt[:, :shift] = np.nan
    scene = Scene("shifted", np.ascontiguousarray(left), np.ascontiguousarray(right), gt, None, 32, "test")
    protocol = get_protocol("cs").select(["R>B"])
    edges = (0.0, 0.1, 0.4)
    counts = brightness.count_scene(scene, models=("cade-v13",), protocol=protocol, edges=edges)[0]
    scored = counts[:, 1]
    assert scored.sum() == np.isfinite(gt).sum()
    half = height * (width // 2)
    assert abs(scored[0] - (half - height * shift)) < height * 12  # the dark half, less its unknown columns
    assert abs(scored[2] - half) < height * 12  # the bright half
    assert counts[2, 0] < 0.05 * scored[2]
    wrong = dataclasses.replace(scene, disparity=gt + 10)
    off = brightness.count_scene(wrong, models=("cade-v13",), protocol=protocol, edges=edges)[0]
    assert np.all(off[:, 0] >= 0.9 * off[:, 1])


def test_no_garbage_collection_lands_inside_a_timed_call_and_the_collector_comes_back_on():
    import gc

    from cade_cli.evaluation.timing import measure

    seconds, inside = measure(gc.isenabled, warmup=1, repeat=3)
    assert inside is False and len(seconds) == 3 and gc.isenabled()
    with pytest.raises(ZeroDivisionError):
        measure(lambda: 1 / 0)
    assert gc.isenabled()  # also after a call that failed


def test_the_model_table_puts_each_models_regional_means_side_by_side_across_runs(tmp_path, capsys):
    """Two runs against the same shipped card: its row comes from the first run, each candidate's from its own, each
    cell the mean over the set's records of the protocol (msir-outdoor: every record); a shipped card whose scores
    differ between the runs is said so."""
    import importlib.util

    script = Path(__file__).resolve().parents[1] / "benchmarks" / "model_table.py"
    spec = importlib.util.spec_from_file_location("model_table", script)
    table = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(table)

    def run(folder: Path, method: str, m14: tuple[float, float], shipped_edge: float = 30.0, zipped: bool = False):
        folder.mkdir()
        records = [{"protocol": "cs", "method": "old",
                    "scores": {"epe_all": 1.0, "bad3_all": 20.0, "epe_edge": 2.0, "bad3_edge": shipped_edge}},
                   {"protocol": "rgb", "method": method, "scores": {"epe_all": 9.0, "bad3_all": 99.0}},  # another protocol: left out
                   *({"protocol": "cs", "method": method, "scores": {"epe_all": 1.0, "bad3_all": value}} for value in m14)]
        text = json.dumps({"config": {"dataset": "middlebury14"}, "records": records})
        if zipped:
            (folder / "middlebury14.json.gz").write_bytes(gzip.compress(text.encode()))
        else:
            (folder / "middlebury14.json").write_text(text)
        msir = [{"protocol": "native", "method": method, "scores": {"epe_all": 0.5, "bad3_all": 2.0}}]
        (folder / "msir-outdoor.json").write_text(json.dumps({"config": {"dataset": "msir-outdoor"}, "records": msir}))

    run(tmp_path / "a", "new", (18.0, 19.0))
    (tmp_path / "a" / "new.json").write_text(json.dumps({"format": 2, "name": "new"}))  # a card beside the runs
    run(tmp_path / "b", "other", (21.0, 23.0), zipped=True)
    text = table.table([tmp_path / "a", tmp_path / "b"], "cs", "bad3")
    rows = {line.split(" | ")[0][2:]: line.split(" | ")[1:] for line in text.splitlines()[2:]}
    assert rows["old"][:3] == ["20.00", "–", "30.00"] and rows["new"][0] == "18.50" and rows["other"][0] == "22.00"
    assert rows["new"][-1].startswith("2.00") and "note" not in capsys.readouterr().err
    run(tmp_path / "c", "third", (20.0, 20.0), shipped_edge=31.0)
    text = table.table([tmp_path / "a", tmp_path / "c"], "cs", "bad3")
    assert "note: old middlebury14 edge differs" in capsys.readouterr().err
    assert [line for line in text.splitlines() if line.startswith("| old |")][0].split(" | ")[3] == "30.00"

"""Study files: the shipped ones load; every bad value names the file, the key and the value."""

from __future__ import annotations

from pathlib import Path

import pytest

from avdata.errors import InputError
from avdata.studies import load_study

STUDIES = Path(__file__).resolve().parents[2] / "studies"


def test_shipped_studies_reproduce_the_published_case_tables() -> None:
    c1 = load_study(STUDIES / "v2i-comm-range.yaml")
    assert [(c.name, c.comm_range_m, c.rate_hz, c.noise) for c in c1.cases] == [
        ("C1-Ideal", 100.0, 10.0, "none"), ("C1-1", 100.0, 10.0, "high"), ("C1-2", 70.0, 10.0, "med"),
        ("C1-3", 50.0, 10.0, "low"), ("C1-Base", None, 10.0, "none")]
    c2 = load_study(STUDIES / "v2i-rate.yaml")
    assert [(c.name, c.comm_range_m, c.rate_hz, c.noise) for c in c2.cases] == [
        ("C2-Ideal", 80.0, 10.0, "none"), ("C2-1", 80.0, 10.0, "high"), ("C2-2", 80.0, 5.0, "low"),
        ("C2-Base", None, 10.0, "none")]
    scenario = c1.scenario(2)
    # The published setup: ego lidar 25 m; infrastructure lidars 15 m high, pitched 30 deg, 180 deg field of view.
    assert scenario["seed"] == 2 and scenario["scenes"] == 1 and scenario["traffic"]["vehicles"] == 40
    assert scenario["egos"][0]["sensors"][0]["lidar"]["max_range_m"] == 25
    infra = scenario["infrastructure"]
    assert (infra["height_m"], infra["pitch_deg"], infra["sensors"][0]["lidar"]["horizontal_fov_deg"]) == (15, 30, 180)


@pytest.mark.parametrize(("text", "message"), [
    ("name: x\ncases: []\n", "non-empty list"),
    ("name: x\ncases: [{name: a, comm_range_m: far}]\n", "comm_range_m to be float, got 'far'"),
    ("name: x\ncases: [{name: a, noise: loud}]\n", "noise in .*got 'loud'"),
    ("name: x\ncases: [{name: a, speed: 3}]\n", r"unknown axis \['speed'\]"),
    ("name: x\ncases: [{name: a}, {name: a}]\n", "unique case names"),
    ("name: x\ntrials: 'two'\ncases: [{name: a}]\n", "trials to be int, got 'two'"),
    ("name: x\npreset: nowhere\ncases: [{name: a}]\n", "preset in"),
    ("name: x\noverrides: {traffic: {vehicles: -3}}\ncases: [{name: a}]\n", "vehicles"),
    ("name: x\ncases: [{name: a, rate_hz: 0}]\n", r"rate_hz in \(0, 1000\]"),
    ("name: [x\n", "expected valid YAML, got line 2, column 1: "),
    ("- just a list\n", "mapping at the top level"),
])
def test_bad_study_files(tmp_path: Path, text: str, message: str) -> None:
    assert str(tmp_path / "study.yaml") in _refused(tmp_path, text, message)


def _refused(tmp_path: Path, text: str, message: str) -> str:
    """The error of loading a study file holding ``text``, which must match ``message``."""
    path = tmp_path / "study.yaml"
    path.write_text(text)
    with pytest.raises(InputError, match=message) as info:
        load_study(path)
    return str(info.value)


@pytest.mark.parametrize(("text", "message"), [
    # A list or mapping where a name belongs was a TypeError traceback (unhashable), as were keys that are not text
    # beside keys that are (sorting them for the message).
    ("name: x\ncases: [{name: a, noise: [low]}]\n", r"cases\[0\]: expected noise in \['high', 'low', 'med', 'none'\], "
                                                   r"got \['low'\]"),
    ("name: x\ncases: [{name: a, detector: {kind: [simulated]}}]\n", "expected detector to be a mapping with kind in"),
    ("name: x\ncases: [{name: a}]\nplots: [{metric: HOTA, axis: [rate_hz]}]\n", "expected a plot metric in"),
    ("name: x\ncases: [{name: a}]\nplots: 5\n", "expected 'plots' to be a list of {metric, axis} mappings, got 5"),
    ("name: x\ncases: [{name: a}]\n1: 2\nfoo: 3\n", r"unknown key\(s\) \[1, 'foo'\]"),
    ("name: x\ncases: [{name: a, 1: 2, foo: 3}]\n", r"cases\[0\]: unknown axis \[1, 'foo'\]"),
    ("name: x\ncases: [{name: a}]\nevaluation: {null: 2, foo: 3}\n", r"evaluation: unknown key\(s\) \[None, 'foo'\]"),
    ("name: x\ncases: [{name: a, detector: {kind: simulated, 1: 2}}]\n", r"got \[1, 'kind'\]"),
    # A value of another type was converted without a word: a case named "None", overrides [] read as none.
    ("name: x\ncases: [{name: null}]\n", r"cases\[0\]: expected name to be str, got None"),
    ("name: x\ncases: [{name: a}]\noverrides: []\n", r"expected 'overrides' to be a mapping, got \[\]"),
    ("name: x\ncases: [{name: a}]\nevaluation: 0\n", "expected 'evaluation' to be a mapping, got 0"),
    ("name: x\ndescription: [a]\ncases: [{name: a}]\n", r"expected description to be str, got \['a'\]"),
    # A generator section set to null was an AttributeError traceback of the scenario check.
    ("name: x\noverrides: {town: null}\ncases: [{name: a}]\n", "field town: expected a mapping, got None"),
])
def test_study_values_of_the_wrong_type_are_one_line(tmp_path: Path, text: str, message: str) -> None:
    error = _refused(tmp_path, text, message)
    assert error.startswith(str(tmp_path / "study.yaml")) and "\n" not in error


def test_an_ego_the_scenario_does_not_have_is_refused_before_any_trial(tmp_path: Path) -> None:
    # It was accepted: the name is first looked up by each run, after the trials are generated.
    path = tmp_path / "study.yaml"
    path.write_text((Path(__file__).resolve().parent / "small_study.yaml").read_text() + "ego: cav_7\n")
    with pytest.raises(InputError, match=r"expected ego to be one of the scenario's egos \['ego'\], got 'cav_7'"):
        load_study(path)


def test_a_yaml_alias_bomb_is_named_in_a_short_line(tmp_path: Path) -> None:
    # Ten lines of aliases (10^9 numbers) made the message's repr take minutes and gigabytes; 10^7 here.
    anchors = ["    - &l0 [1, 1, 1, 1, 1, 1, 1, 1, 1, 1]"]
    anchors += [f"    - &l{i} [" + ", ".join([f"*l{i - 1}"] * 10) + "]" for i in range(1, 8)]
    path = tmp_path / "study.yaml"
    path.write_text("name: x\ncases: [{name: a}]\nevaluation:\n  max_range_m:\n" + "\n".join(anchors) + "\n")
    with pytest.raises(InputError, match=r"expected evaluation.max_range_m to be float, got \[\[1, 1, 1, ") as info:
        load_study(path)
    assert len(str(info.value)) < 1000


@pytest.mark.parametrize(("option", "value"), [("--trials", str(2**31)), ("--trials", str(2**63)), ("--frames", "1")])
def test_study_run_overrides_are_checked_like_the_file(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                      option: str, value: str) -> None:
    from avdata.cli import main

    # --trials 2**31 was a MemoryError traceback, 2**63 an OverflowError: the file's bounds were not applied
    study = Path(__file__).parent / "small_study.yaml"
    assert main(["study", "run", str(study), str(tmp_path / "out"), option, value]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"avdata: error: {study} with --trials ")
    assert "expected trials in [1, 1000], frames in [2, 100000]" in err and not (tmp_path / "out").exists()


def test_study_run_out_in_a_studied_dataset_and_report_of_a_long_name(tmp_path: Path,
                                                                      capsys: pytest.CaptureFixture[str]) -> None:
    from avdata.cli import main
    from avdata.demo import write_demo

    dataset = write_demo(tmp_path / "ds")
    study = tmp_path / "study.yaml"
    study.write_text(f"name: s\ndatasets: [{{name: d, path: {dataset}}}]\n"
                     "cases: [{name: sim, detector: {kind: simulated, noise: low}}]\n")
    before = sorted(dataset.rglob("*"))
    assert main(["study", "run", str(study), str(dataset / "study"), "--quiet"]) == 1  # it was run into the dataset
    long = tmp_path / ("x" * 300)
    assert main(["study", "report", str(long)]) == 1  # Path.is_file raised ENAMETOOLONG: a traceback
    assert capsys.readouterr().err.splitlines() == [
        f"avdata: error: {dataset / 'study'}: expected an output outside the study's dataset, got a path inside the "
        f"study's dataset {dataset}",
        f"avdata: error: {long / 'results.parquet'}: expected a results file of 'avdata study run', got File name too long"]
    assert sorted(dataset.rglob("*")) == before

"""Identification of many inputs in parallel: the same parameters as one input at a time, a summary
table with the intervals and warnings per membrane, the spread plot, and bad inputs named."""
import csv
import math

import pytest

from dea_ros.cli import main
from dea_ros.identify.many import identify_many, labels_for
from dea_ros.study import Engine


def test_labels_are_unique_folder_names():
    assert labels_for(["/a/A2", "/b/A2", "/c/run.mcap", "/d/A1/"]) == ["A2", "A2_2", "run", "A1"]


def test_many_inputs_in_parallel_match_the_single_input_path(synthetic, identified, tmp_path):
    """Two inputs on two processes (the paper's two stages without the evaluation, the cheapest fit; the
    same data set twice under two names) give the parameters and intervals of the single-input path."""
    import shutil

    a2, _ = synthetic("A2")
    a1 = tmp_path / "A2_copy"
    shutil.copytree(a2, a1)
    bad = tmp_path / "broken"
    bad.mkdir()
    (bad / "manifest.yaml").write_text("format: dea_ros.experiments/1\nexperiments:\n- kind: static\n  file: x.csv\n")
    with Engine("processes", workers=2) as engine:
        summary = identify_many([a2, a1, bad], tmp_path / "out", engine=engine, progress=False, refine="none",
                                evaluate_fit=False)   # the parameters do not depend on the evaluation
    rows = {r["name"]: r for r in summary["rows"]}
    assert [r["name"] for r in summary["rows"]] == [a2.name, a1.name, "broken"]
    assert rows["broken"]["status"] == "bad input" and "manifest.yaml" in rows["broken"]["error"]
    for folder in (a2, a1):
        row, ref = rows[folder.name], identified("A2", "two-stage")
        assert row["status"] == "ok", row
        p = ref.parameters
        for col, value in (("eps_r", p.relative_permittivity), ("k1_Pa", p.k1_Pa), ("eta1_Pa_s", p.eta1_Pa_s),
                           ("eta2_Pa_s", p.eta2_Pa_s)):
            assert row[col] == pytest.approx(value, rel=1e-6), (folder.name, col)
        meta = ref.identification_metadata()
        assert [row["k1_Pa_ci95_low"], row["k1_Pa_ci95_high"]] == pytest.approx(meta["k1_Pa_ci95"], rel=1e-6)
        assert row["n_warnings"] == len(row["warnings"].split(" | ")) if row["warnings"] else row["n_warnings"] == 0
        assert (tmp_path / "out" / folder.name / "params.yaml").is_file()
        assert math.isnan(row["peak_frequency_Hz"])   # no evaluation asked: no model peak
    with open(summary["summary_csv"], newline="") as fh:
        table = list(csv.DictReader(fh))
    assert [t["status"] for t in table] == ["ok", "ok", "bad input"]
    assert float(table[0]["k1_Pa"]) == pytest.approx(identified("A2", "two-stage").parameters.k1_Pa, rel=1e-12)
    text = (tmp_path / "out" / "summary.md").read_text()
    assert "| broken | bad input" in text and "k1_Pa [MPa] (95 % interval)" in text
    assert (tmp_path / "out" / "spread.png").stat().st_size > 1000


def test_cli_many_inputs_name_a_bad_input_before_any_work(synthetic, tmp_path, capsys):
    a2, _ = synthetic("A2")
    junk = tmp_path / "junk.txt"
    junk.write_text("not data")
    code = main(["identify", str(a2), str(junk), "--out", str(tmp_path / "o"), "--engine", "serial"])
    assert code == 2 and "junk.txt: neither an experiment folder" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()

"""`tvf compare` through the command line: the table, the JSON file and a one-line error."""

import json

from cli_run import run


def _eval_folder(folder, successes):
    folder.mkdir()
    records = [{"task": "put-t", "seed": 2 * i + 1, "success": ok} for i, ok in enumerate(successes)]
    (folder / "episodes.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))
    return str(folder)


def test_compare_prints_the_pairs_and_writes_json(capsys, tmp_path):
    a = _eval_folder(tmp_path / "a", [False] * 6)
    b = _eval_folder(tmp_path / "b", [True] * 6)
    json_file = str(tmp_path / "c.json")
    code, out, err = run(capsys, "compare", a, b, "--labels", "before,after", "--json", json_file)
    assert code == 0, err
    assert "| after | 6 | 0 | 0.0312 |" in out
    saved = json.loads((tmp_path / "c.json").read_text())
    assert saved["pairs"][0]["wins"] == 6 and saved["runs"][1]["successes"] == 6


def test_compare_of_a_missing_folder_is_one_line(capsys, tmp_path):
    a = _eval_folder(tmp_path / "a", [True])
    code, _, err = run(capsys, "compare", a, str(tmp_path / "nowhere"))
    assert code == 2
    assert err.count("\n") == 1 and "no episodes.jsonl" in err

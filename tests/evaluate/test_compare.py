"""Paired comparison of evaluation folders: the sign test, episode matching, labels and bad input."""

import json
from fractions import Fraction

import pytest

from tvf.errors import TvfError
from tvf.evaluate.compare import compare, comparison_markdown, read_run, read_runs, sign_test


def binomial_tail(n: int, k: int) -> float:
    """P(X <= k) for X ~ Binomial(n, 1/2), by Pascal's rule (independent of math.comb)."""
    row = [Fraction(1)]
    for _ in range(n):
        row = [a + b for a, b in zip([Fraction(0), *row], [*row, Fraction(0)], strict=True)]
    return float(sum(row[: k + 1]) / 2**n)


def write_eval(folder, outcomes, meta=None):
    """An evaluation folder: one episodes.jsonl record per (task, seed, success), eval.json if given."""
    folder.mkdir(parents=True)
    lines = [json.dumps({"task": t, "seed": s, "success": ok, "progress": 1.0 if ok else 0.5, "steps": 3})
             for t, s, ok in outcomes]  # fmt: skip
    (folder / "episodes.jsonl").write_text("\n".join(lines) + "\n")
    if meta is not None:
        (folder / "eval.json").write_text(json.dumps(meta))
    return folder


@pytest.mark.parametrize(("wins", "losses", "p"), [(5, 0, 0.0625), (0, 4, 0.125), (3, 4, 1.0), (0, 0, 1.0),
                                                   (1, 1, 1.0), (6, 0, 0.03125)])  # fmt: skip
def test_sign_test_small_cases(wins, losses, p):
    assert sign_test(wins, losses) == pytest.approx(p)
    assert sign_test(losses, wins) == pytest.approx(p)


@pytest.mark.parametrize(("wins", "losses"), [(29, 18), (28, 7), (27, 2), (10, 30)])
def test_sign_test_matches_the_binomial_tail(wins, losses):
    n = wins + losses
    assert sign_test(wins, losses) == pytest.approx(min(1.0, 2 * binomial_tail(n, min(wins, losses))))


def test_sign_test_rejects_negative_counts():
    with pytest.raises(ValueError, match="non-negative"):
        sign_test(-1, 3)


def test_compare_pairs_the_shared_episodes(tmp_path):
    base = write_eval(
        tmp_path / "a",
        [
            ("put-t", 1, True),
            ("put-t", 3, False),
            ("stack-stair", 1, True),
            ("stack-stair", 3, False),
            ("stack-stair", 5, True),
        ],  # fmt: skip
        meta={"method": "tvf-large", "depth": 1, "k": None, "resolved": {"k": 3}},
    )
    other = write_eval(tmp_path / "b", [("stack-stair", 1, False), ("stack-stair", 3, True),
                                        ("put-t", 1, True), ("put-t", 3, True)])  # fmt: skip
    result = compare(read_runs([base, other]))
    assert result["episodes"] == 4 and result["per_task"] == {"put-t": 2, "stack-stair": 2}
    first, second = result["runs"]
    assert first["label"] == "tvf-large depth=1" and second["label"] == "b"
    assert first["tasks"] == {"put-t": 1, "stack-stair": 1} and first["successes"] == 2
    assert second["tasks"] == {"put-t": 2, "stack-stair": 1} and second["success"] == 0.75
    (p,) = result["pairs"]
    assert (p["wins"], p["losses"]) == (2, 1) and p["p_value"] == pytest.approx(1.0)
    assert result["left_out"] == {"tvf-large depth=1": 1, "b": 0}
    text = comparison_markdown(result)
    assert "| b | 2 | 1 | 1 |" in text and "left out" in text and "**3** (75.0%" in text


def test_repeated_labels_fall_back_to_the_folders(tmp_path):
    meta = {"method": "gctn"}
    a = write_eval(tmp_path / "seed0", [("put-t", 1, True)], meta)
    b = write_eval(tmp_path / "seed1", [("put-t", 1, False)], meta)
    assert [r.label for r in read_runs([a, b])] == [str(a), str(b)]
    assert [r.label for r in read_runs([a, b], ["one", "two"])] == ["one", "two"]


def _one_record(folder, record):
    (folder / "episodes.jsonl").write_text(json.dumps(record) + "\n")
    return folder


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda d: d.mkdir(), "no episodes.jsonl"),
        (lambda d: write_eval(d, []), "no finished episodes"),
        (lambda d: write_eval(d, []) and _one_record(d, {"task": "put-t"}), "without task, seed"),
    ],
)
def test_bad_folders_are_one_line_errors(tmp_path, make, message):
    make(tmp_path / "x")
    with pytest.raises(TvfError, match=message):
        read_run(tmp_path / "x")


def test_runs_without_shared_episodes_or_a_partner_are_errors(tmp_path):
    a = write_eval(tmp_path / "a", [("put-t", 1, True)])
    b = write_eval(tmp_path / "b", [("put-t", 3, True)])
    with pytest.raises(TvfError, match="share no episode"):
        compare(read_runs([a, b]))
    with pytest.raises(TvfError, match="at least two"):
        compare(read_runs([a]))
    with pytest.raises(TvfError, match="one label per folder"):
        read_runs([a, b], ["only one"])

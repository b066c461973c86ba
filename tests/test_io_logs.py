"""The append-only logs (tvf.io.append_jsonl / read_jsonl, used by every .jsonl of tvf) and full-disk
errors at the write sites (issue 16, case 3)."""

from __future__ import annotations

import errno
import json
import os
import pickle
from pathlib import Path

import pytest

from tvf.errors import DiskFullError
from tvf.io import append_jsonl, as_disk_full, atomic_path, output_dir, read_jsonl

TORN = b'{"task": "stack-stair", "se'


def lines(path: Path) -> list[bytes]:
    return path.read_bytes().splitlines(keepends=True)


def test_records_are_appended_as_whole_lines_and_read_back(tmp_path):
    log = tmp_path / "log.jsonl"
    append_jsonl(log, {"step": 1})
    append_jsonl(log, {"step": 2, "x": [1.5]})
    assert log.read_bytes() == b'{"step": 1}\n{"step": 2, "x": [1.5]}\n'
    assert read_jsonl(log) == [{"step": 1}, {"step": 2, "x": [1.5]}]
    assert read_jsonl(tmp_path / "missing.jsonl") == []


def test_a_torn_last_line_is_ignored_with_a_note_and_the_next_record_starts_a_fresh_line(tmp_path, capsys):
    log = tmp_path / "log.jsonl"
    log.write_bytes(b'{"step": 1}\n' + TORN)
    assert read_jsonl(log) == [{"step": 1}]
    assert f"tvf: note: {log}: ignored a torn last line ({len(TORN)} bytes" in capsys.readouterr().err
    append_jsonl(log, {"step": 2})
    assert lines(log) == [b'{"step": 1}\n', b'{"step": 2}\n']  # not glued onto the torn line
    assert "dropped a torn last line" in capsys.readouterr().err
    assert read_jsonl(log) == [{"step": 1}, {"step": 2}]
    assert capsys.readouterr().err == ""  # nothing left to note


def test_a_whole_record_without_its_newline_is_kept(tmp_path, capsys):
    log = tmp_path / "log.jsonl"
    log.write_bytes(b'{"step": 1}\n{"step": 2}')
    assert read_jsonl(log) == [{"step": 1}, {"step": 2}]
    append_jsonl(log, {"step": 3})
    assert read_jsonl(log) == [{"step": 1}, {"step": 2}, {"step": 3}]
    assert log.read_bytes().endswith(b'{"step": 2}\n{"step": 3}\n') and capsys.readouterr().err == ""


def test_a_torn_line_longer_than_a_read_chunk_is_dropped_whole(tmp_path):
    log = tmp_path / "log.jsonl"
    log.write_bytes(b'{"step": 1}\n' + b'{"x": "' + b"a" * 200_000)
    append_jsonl(log, {"step": 2})
    assert lines(log) == [b'{"step": 1}\n', b'{"step": 2}\n']
    log.write_bytes(b'{"x": "' + b"a" * 100_000)  # no whole line at all
    append_jsonl(log, {"step": 3})
    assert lines(log) == [b'{"step": 3}\n']


def test_other_bad_lines_are_counted_in_the_note(tmp_path, capsys):
    log = tmp_path / "log.jsonl"
    log.write_bytes(b'{"step": 1}\nnot json\n[1, 2]\n\n{"step": 2}\n')
    assert read_jsonl(log) == [{"step": 1}, {"step": 2}]
    assert "ignored 2 line(s) that are not JSON records" in capsys.readouterr().err


def _fail_after(monkeypatch, allowed: int) -> None:
    """os.write that writes ``allowed`` more bytes, then finds the disk full."""
    real, left = os.write, [allowed]

    def write(fd, data):
        n = min(len(data), left[0])
        if n == 0:
            raise OSError(errno.ENOSPC, "No space left on device")
        left[0] -= n
        return real(fd, bytes(data)[:n])

    monkeypatch.setattr(os, "write", write)


def test_an_append_that_fills_the_disk_leaves_no_partial_line(tmp_path, monkeypatch):
    log = tmp_path / "log.jsonl"
    append_jsonl(log, {"step": 1})
    before = log.read_bytes()
    _fail_after(monkeypatch, 5)  # five bytes of the next line reach the disk, then it is full
    with pytest.raises(DiskFullError) as caught:
        append_jsonl(log, {"step": 2, "loss": 0.25})
    assert log.read_bytes() == before  # the five bytes are cut back off
    assert caught.value.path == str(log) and str(log) in str(caught.value)
    monkeypatch.undo()
    append_jsonl(log, {"step": 2})
    assert read_jsonl(log) == [{"step": 1}, {"step": 2}]


def test_an_append_after_a_torn_line_that_fills_the_disk_keeps_the_whole_lines(tmp_path, monkeypatch):
    log = tmp_path / "log.jsonl"
    log.write_bytes(b'{"step": 1}\n' + TORN)
    _fail_after(monkeypatch, 3)
    with pytest.raises(DiskFullError):
        append_jsonl(log, {"step": 2})
    assert log.read_bytes() == b'{"step": 1}\n'


@pytest.mark.parametrize(
    "failure",
    [
        OSError(errno.ENOSPC, "No space left on device"),
        OSError(errno.EDQUOT, "Disk quota exceeded"),
        RuntimeError("Can't decrement id ref count (file write failed: errno = 28, error message = 'x')"),
    ],
)
def test_a_full_disk_inside_an_atomic_write_names_the_file_and_leaves_no_temporary(tmp_path, failure):
    path = tmp_path / "out.json"
    with pytest.raises(DiskFullError) as caught, atomic_path(path) as tmp:
        tmp.write_bytes(b"half")
        raise failure
    assert caught.value.path == str(path) and not path.exists()
    assert list(tmp_path.iterdir()) == []


def test_a_wrapped_full_disk_is_recognised_through_the_exception_chain(tmp_path):
    """torch's checkpoint writer raises a RuntimeError while handling the OSError of the full disk."""
    path = tmp_path / "ckpt.pt"
    with pytest.raises(DiskFullError), atomic_path(path) as tmp:
        tmp.write_bytes(b"half")
        try:
            raise OSError(errno.ENOSPC, "No space left on device")
        except OSError:
            raise RuntimeError("[enforce fail at inline_container.cc:672] . unexpected pos 704 vs 598")  # noqa: B904
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(RuntimeError), atomic_path(path):  # the same error without a full disk is not one
        raise RuntimeError("unexpected pos 704 vs 598")


def test_the_full_disk_error_is_one_line_and_crosses_worker_processes(tmp_path):
    err = DiskFullError(tmp_path / "a.h5").keeping("3 episodes kept in OUT/train")
    again = pickle.loads(pickle.dumps(err))
    assert str(again) == str(err) and again.kept == "3 episodes kept in OUT/train"
    assert str(err).startswith("no space left on /")
    assert str(err).endswith(f"(writing {tmp_path / 'a.h5'}), 3 episodes kept in OUT/train; "
                             "free space and re-run the same command to resume")  # fmt: skip
    assert as_disk_full(err) is err


# ------------------------------------------------------------------------------------ every log reader
def _torn(path: Path, records: list[dict]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(b"".join(json.dumps(r).encode() + b"\n" for r in records) + TORN)


def test_each_log_reader_ignores_a_torn_last_line(tmp_path, capsys):
    from tvf.data.generation import read_failures
    from tvf.evaluate.closed_loop import read_results
    from tvf.runs import RunDir

    run = RunDir(tmp_path / "run")
    _torn(run.metrics_path, [{"step": 1, "split": "train"}, {"step": 1, "split": "val", "loss": 2.0}])
    assert [r["split"] for r in run.metrics()] == ["train", "val"]
    assert run.last_validation()["loss"] == 2.0
    run.truncate_metrics(1)  # a resume rewrites the log without the torn line
    assert run.metrics_path.read_bytes().endswith(b'"loss": 2.0}\n')

    _torn(tmp_path / "eval" / "episodes.jsonl", [{"task": "stack-stair", "seed": 1, "success": True}])
    assert read_results(tmp_path / "eval" / "episodes.jsonl") == [
        {"task": "stack-stair", "seed": 1, "success": True}
    ]

    _torn(tmp_path / "demos" / "failures.jsonl", [{"task": "stack-stair", "seed": 2}, {"seed": 4}])
    assert list(read_failures(tmp_path / "demos")) == [("stack-stair", 2)]
    assert capsys.readouterr().err.count("ignored a torn last line") == 3


def test_an_output_folder_made_for_a_failed_setup_is_removed_only_while_empty(tmp_path):
    with pytest.raises(ValueError), output_dir(tmp_path / "a" / "b"):
        assert (tmp_path / "a" / "b").is_dir()
        raise ValueError("setup failed")
    assert not (tmp_path / "a").exists()
    (tmp_path / "kept").mkdir()
    with pytest.raises(ValueError), output_dir(tmp_path / "kept" / "run") as run:
        (run / "config.json").write_text("{}")
        raise ValueError("failed after writing")
    assert (tmp_path / "kept" / "run" / "config.json").exists()  # nothing written is ever deleted
    with output_dir(tmp_path / "ok") as run:
        pass
    assert run.is_dir()

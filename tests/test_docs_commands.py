"""The commands in README.md and docs/ run as written: every `tvf ...` line of a code block parses, and
the data and training chains run end to end at smoke size (fewer tasks, episodes and steps)."""

import re
import shlex
from pathlib import Path

import pytest
import tyro

from tvf.cli import COMMANDS, main
from tvf.cli.train import TrainGctn, split_config_flag

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
SMOKE = {"--episodes": "1", "--workers": "1", "--steps": "2", "--batch": "2", "--preset": "smoke",
         "--tasks": "stack-tower", "--demos": "1", "--val-every": "1", "--warmup": "0"}  # fmt: skip


def doc_commands(path: Path) -> list[list[str]]:
    """The `tvf` command lines of the fenced code blocks of a Markdown file (synopses with | or ... and
    placeholders such as FILE are skipped); continuation lines are joined, comments dropped."""
    commands, block = [], False
    text = re.sub(r"\\\n\s*", " ", path.read_text())
    for line in text.splitlines():
        if line.startswith("```"):
            block = not block
            continue
        line = line.split("  #")[0].strip()
        if block and line.startswith("tvf ") and not re.search(r"\||\.\.\.|…|\b[A-Z]{3,}\b|\[", line):
            commands.append(shlex.split(line)[1:])
    return commands


ALL = [(p.name, c) for p in DOCS for c in doc_commands(p)]


def test_the_docs_show_commands():
    assert len(ALL) >= 15, ALL
    assert {c[0] for _, c in ALL} >= {"demos", "train", "eval", "experiment", "quickstart"}


@pytest.mark.parametrize(("doc", "argv"), ALL, ids=[f"{d}:{' '.join(a[:2])}" for d, a in ALL])
def test_every_documented_command_parses(doc, argv):
    """Parsing builds the command's dataclass: unknown or renamed flags fail here."""
    name, rest = argv[0], argv[1:]
    assert name in COMMANDS, f"{doc}: `tvf {name}` is no command"
    if name == "train" and "--config" in rest:  # a relaunch: the flags beside --config are training flags
        path, flags = split_config_flag(rest)
        assert path and path.endswith("config.json"), f"{doc}: `tvf train --config` takes RUN/config.json"
        cmd = tyro.cli(TrainGctn, args=flags, default=TrainGctn(data=Path("."), out=Path(".")))
    else:
        cmd = tyro.cli(COMMANDS[name], args=rest)
    assert callable(cmd.run)


def smoke(argv: list[str]) -> list[str]:
    """A documented command at smoke size: the sizing flags replaced (or added to commands that train)."""
    out, i = [], 0
    while i < len(argv):
        out.append(argv[i])
        if argv[i] in SMOKE and i + 1 < len(argv):
            out.append(SMOKE[argv[i]])
            i += 1
        i += 1
    if argv[:1] == ["train"]:
        out += [
            f
            for k in ("--steps", "--batch", "--val-every", "--tasks")
            if k not in argv
            for f in (k, SMOKE[k])
        ]
    return out


@pytest.mark.slow  # demos, both trainings and an evaluation at smoke size: about 40 s on 2 cores
def test_the_data_and_training_chains_run_at_smoke_size(tmp_path, monkeypatch, capsys):
    """docs/data.md then docs/training.md, in order, in one folder: each command reads what the ones
    before it wrote (the first commands of training.md once wrote a nested split the next could not read)."""
    monkeypatch.chdir(tmp_path)
    chain = [c for p in ("data.md", "training.md") for c in doc_commands(ROOT / "docs" / p)]
    chain = [c for c in chain if c[0] in ("demos", "train", "eval") or c[:2] == ["data", "info"]]
    assert [c[0] for c in chain].count("train") == 4  # gctn, vf, a relaunch and a symmetrised fine-tune
    for argv in chain:
        try:
            main(smoke(argv))
        except SystemExit as exc:
            pytest.fail(f"`tvf {' '.join(smoke(argv))}` exited {exc.code}: {capsys.readouterr().err}")

"""Shipping weights: one model from a run into a weights folder, copying a folder, evaluations, the card."""

import json
from pathlib import Path

import pytest

import tvf.weights
from tvf.errors import TvfError
from tvf.evaluate.closed_loop import summarise
from tvf.experiment import shipping
from tvf.experiment.shipping import (
    model_card,
    record_evaluation,
    ship_model,
    ship_weights,
    upgrade_weights,
    write_model_card,
)
from tvf.io import atomic_write_json
from tvf.models.checkpoint import load_model, save_checkpoint
from tvf.models.gctn import GCTN
from tvf.models.presets import SMOKE
from tvf.models.vf import VisualForesight
from tvf.runs import RunDir
from tvf.weights import (
    MODEL_CARD,
    PROVENANCE,
    WEIGHTS_DIR,
    config_path,
    provenance,
    sha256_file,
    shipped_files,
)


def _run(root: Path, model, step: int, seed: int = 0) -> Path:
    """A training run folder as `tvf train` leaves it: config.json, metrics.jsonl, checkpoints/last.pt."""
    run = RunDir(root)
    episodes = [["stack-tower", 0], ["stack-tower", 2]]
    train = {"steps": step, "batch": 2, "lr": 1e-3, "schedule": "constant", "warmup": 0, "seed": seed}
    atomic_write_json(run.config_path, {"data_fingerprint": "abc", "seed": seed, "episodes": episodes,
                                        "train": train})  # fmt: skip
    run.log({"step": step, "split": "val", "loss": 0.25})
    save_checkpoint(run.last, model, None, step, extra={"data_fingerprint": "abc", "val": {"loss": 0.25}})
    return root


@pytest.fixture
def folder(tmp_path):
    """A weights folder with a smoke GCTN and VF shipped from their runs."""
    out = tmp_path / "weights"
    ship_model(_run(tmp_path / "gctn", GCTN(SMOKE, seed=0), 3), "gctn", out)
    ship_model(_run(tmp_path / "vf", VisualForesight(SMOKE, seed=0), 5), "vf", out)
    return out


def _evaluation(root: Path, method: str, successes: dict[str, list[bool]], **settings) -> Path:
    results = [{"task": t, "success": s, "progress": float(s)} for t, ss in successes.items() for s in ss]
    n = len(next(iter(successes.values())))
    meta = {"method": method, "gctn": None, "vf": None, "episodes": n, "seed_start": 1_000_001,
            "step_slack": 0, **settings}  # fmt: skip
    atomic_write_json(root / "eval.json", meta)
    atomic_write_json(root / "summary.json", summarise(results, method))
    return root


def test_ship_model_writes_weights_provenance_hashes_and_card(folder):
    assert sorted(p.name for p in folder.iterdir()) == sorted(shipped_files("smoke"))
    record = provenance(folder)
    gctn = record["models"]["gctn"]
    assert (gctn["file"], gctn["config"], gctn["step"], gctn["preset"]) == (
        "gctn-smoke.safetensors", "gctn-smoke.json", 3, "smoke",
    )  # fmt: skip
    assert gctn["train"]["steps"] == 3 and gctn["episodes"] == [["stack-tower", 0], ["stack-tower", 2]]
    assert (
        gctn["validation"] == {"step": 3, "split": "val", "loss": 0.25}
        and gctn["architecture"]["name"] == "smoke"
    )
    assert gctn["sha256"] == {
        n: sha256_file(folder / n) for n in ("gctn-smoke.safetensors", "gctn-smoke.json")
    }
    assert gctn["converted_from"] == {"file": "last.pt", "sha256": sha256_file(
        folder.parent / "gctn" / "checkpoints" / "last.pt")}  # fmt: skip
    model, ckpt = load_model(folder / "vf-smoke.safetensors", "vf")
    assert ckpt.step == 5 and ckpt.optimizer is None
    card = (folder / MODEL_CARD).read_text()
    assert card == model_card(record)
    assert gctn["sha256"]["gctn-smoke.safetensors"] in card and "| stack-tower | 2 | 0, 2 |" in card
    assert "No closed-loop evaluation is recorded" in card


def test_evaluations_enter_the_card_and_a_new_model_drops_them(folder, tmp_path):
    gctn = _evaluation(
        tmp_path / "e1", "gctn", {"stack-tower": [True, False], "stack-building": [False, False]}
    )
    entry = record_evaluation(gctn, folder)
    assert entry["name"] == "GCTN" and entry["seed_range"] == "test" and entry["settings"] == {}
    assert entry["results"]["train"]["success"] == 0.5 and entry["results"]["unseen"]["success"] == 0.0
    tvf_l = _evaluation(tmp_path / "e2", "tvf-large", {"stack-building": [False, False]}, proposals="nms")
    record_evaluation(tvf_l, folder, name="TVF-L, NMS")
    record_evaluation(tvf_l, folder, name="TVF-L, NMS")  # the same name replaces its entry
    record = provenance(folder)
    assert [e["name"] for e in record["evaluations"]] == ["GCTN", "TVF-L, NMS"]
    assert record["evaluations"][1]["settings"] == {"proposals": "nms"}
    card = (folder / MODEL_CARD).read_text()
    assert card == model_card(record)
    assert "| GCTN | test (odd, from 1 000 001) | 2 | 0.0 % [0–66] | 50.0 % [9–91] |" in card
    assert (
        "| stack-building | 0 % | 0 % |" in card
        and "more than 10 % of the episodes of stack-building" in card
    )
    other = _evaluation(tmp_path / "e3", "gctn", {"stack-tower": [True]}, gctn="runs/mine")
    with pytest.raises(TvfError, match="evaluated --gctn files it kept no SHA-256 of"):
        record_evaluation(other, folder)
    source = sha256_file(tmp_path / "gctn" / "checkpoints" / "last.pt")  # the run the weights came from
    of_run = _evaluation(tmp_path / "e6", "gctn", {"stack-tower": [True]}, gctn=str(tmp_path / "gctn"),
                         weights={"gctn": source})  # fmt: skip
    assert "gctn" not in record_evaluation(of_run, folder, name="GCTN of its run")
    stale = _evaluation(tmp_path / "e4", "gctn", {"stack-tower": [True]}, weights={"gctn": "ab" * 32})
    with pytest.raises(TvfError, match="evaluated other gctn weights"):  # eval.json's hashes are checked
        record_evaluation(stale, folder)
    digest = provenance(folder)["models"]["gctn"]["sha256"]["gctn-smoke.safetensors"]
    fresh = _evaluation(tmp_path / "e5", "gctn", {"stack-tower": [True]}, weights={"gctn": digest})
    assert record_evaluation(fresh, folder, name="GCTN again")["settings"] == {}
    ship_model(folder / "gctn-smoke.safetensors", "gctn", folder)  # a model replaced: its results go
    assert "evaluations" not in provenance(folder)
    assert provenance(folder)["models"]["gctn"]["train"] is None  # weights carry no run record


def test_ship_weights_copies_checked_files_and_refuses_changed_ones(folder, tmp_path):
    target = tmp_path / "package"
    ship_weights(folder, target, "smoke")
    assert sorted(p.name for p in target.iterdir()) == sorted(shipped_files("smoke"))
    assert (target / MODEL_CARD).read_text() == (folder / MODEL_CARD).read_text()
    load_model(target / "gctn-smoke.safetensors", "gctn")
    data = bytearray((folder / "vf-smoke.safetensors").read_bytes())
    data[-1] ^= 1
    (folder / "vf-smoke.safetensors").write_bytes(bytes(data))
    with pytest.raises(TvfError, match=r"vf-smoke\.safetensors does not match its SHA-256"):
        ship_weights(folder, tmp_path / "again", "smoke")
    (folder / PROVENANCE).unlink()
    with pytest.raises(TvfError, match=r"provenance\.json is missing"):
        ship_weights(folder, tmp_path / "again", "smoke")


def test_upgrade_weights_keeps_the_tensors_and_the_record_and_adds_the_hashes(folder, tmp_path, capsys):
    record_evaluation(_evaluation(tmp_path / "e", "gctn", {"stack-tower": [True, False]}), folder)
    tensors = {n: (folder / n).read_bytes() for n in ("gctn-smoke.safetensors", "vf-smoke.safetensors")}
    for name in tensors:  # as tvf wrote the configs before weights carried hashes (version 1)
        meta = json.loads(config_path(folder / name).read_text())
        del meta["sha256"]
        atomic_write_json(config_path(folder / name), {**meta, "version": 1}, indent=2)
    before = provenance(folder)
    assert upgrade_weights(folder) == [folder / "gctn-smoke.safetensors", folder / "vf-smoke.safetensors"]
    assert "loaded unverified" in capsys.readouterr().err  # read once as version 1
    record = provenance(folder)
    assert {n: (folder / n).read_bytes() for n in tensors} == tensors  # bit-identical tensors
    for kind, entry in record["models"].items():
        meta = json.loads((folder / entry["config"]).read_text())
        assert meta["version"] == 2 and set(meta["sha256"]) == {"tensors", "config"}
        assert entry["sha256"] == {n: sha256_file(folder / n) for n in (entry["file"], entry["config"])}
        assert {k: v for k, v in entry.items() if k != "sha256"} == {
            k: v for k, v in before["models"][kind].items() if k != "sha256"
        }
    assert record["evaluations"] == before["evaluations"]
    assert (folder / MODEL_CARD).read_text() == model_card(record)
    load_model(folder / "gctn-smoke.safetensors", "gctn")
    assert not capsys.readouterr().err  # verified now: no warning


def test_a_failed_upgrade_puts_back_every_models_files(folder, monkeypatch):
    files = sorted(p for p in folder.iterdir() if p.suffix in (".safetensors", ".json"))
    before = {p: p.read_bytes() for p in files}
    real = shipping.save_weights

    def second_fails(path, *args, **kwargs):
        if "vf" in path.name:  # the second model: the first one's files are already rewritten
            raise OSError("disk trouble")
        real(path, *args, **kwargs)
        config_path(path).write_text("{}")  # a changed config, to be put back

    monkeypatch.setattr(shipping, "save_weights", second_fails)
    with pytest.raises(OSError, match="disk trouble"):
        upgrade_weights(folder)
    assert {p: p.read_bytes() for p in files} == before


def test_the_committed_model_card_is_what_the_generator_writes(tmp_path, monkeypatch):
    committed = (WEIGHTS_DIR / MODEL_CARD).read_text()
    assert committed == model_card(provenance()), "regenerate: tvf.experiment.shipping.write_model_card()"
    assert (
        "| TVF-L, paper rules | test (odd, from 1 000 001) | 20 | 56.2 % [49–64] |" in committed
    )  # results.md
    monkeypatch.setattr(tvf.weights, "WEIGHTS_DIR", tmp_path)
    (tmp_path / PROVENANCE).write_text(json.dumps(provenance(WEIGHTS_DIR)))
    assert write_model_card().read_text() == committed  # the default folder is read at call time
    with pytest.raises(TvfError, match="lists no models"):
        model_card({})

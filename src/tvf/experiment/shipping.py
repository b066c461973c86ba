"""Shipping weights: trained models into a weights folder as safetensors + JSON config, their provenance
with every file's SHA-256, later evaluations of them, and the model card generated from that record.

A weights folder (the package's ``src/tvf/weights`` or an experiment's ``EXP/weights``) holds
``KIND-PRESET.safetensors`` and ``KIND-PRESET.json`` per model, ``provenance.json`` and ``README.md``
(the model card, always :func:`model_card` of the provenance). To ship a new model from Python::

    ship_model("runs/gctn", "gctn")             # a run directory, a .pt checkpoint or weights
    record_evaluation("runs/eval-test/gctn")    # a `tvf eval` of the shipped weights, into the card

`tvf experiment --ship` (`make reproduce`) runs the same code: its weights stage calls
:func:`ship_model` per kind into ``EXP/weights`` and :func:`ship_weights` copies that folder here.
"""

from __future__ import annotations

from pathlib import Path

import tvf.weights as weights
from tvf.errors import TvfError
from tvf.experiment.report import PAPER_UNSEEN_10_DEMOS, group_average
from tvf.io import atomic_write_bytes, atomic_write_json, read_json
from tvf.models.checkpoint import Checkpoint, load_model, preset_of, save_weights
from tvf.policies import label
from tvf.runs import RunDir, resolve_checkpoint
from tvf.seeds import seed_range
from tvf.tasks import BUILTIN, TaskTable
from tvf.weights import MODEL_CARD, PROVENANCE, config_path, sha256_file, shipped_files, shipped_name

STALE = ("results", "evaluations")
"""Provenance entries that measured the former pair of models: dropped when a model is replaced."""
EVAL_KEYS = ("method", "gctn", "vf", "episodes", "seed_start", "step_slack", "weights", "resolved")
"""eval.json fields recorded on their own (``resolved``: every setting, the method's defaults filled in);
the others are the evaluation's planner settings."""


def _folder(folder: str | Path | None) -> Path:
    return Path(weights.WEIGHTS_DIR if folder is None else folder)


def group_results(summary: dict, table: TaskTable = BUILTIN) -> dict:
    """A method's average success over all tasks, the unseen ones and the training ones."""
    out = {"all": summary["average"]}
    for split in ("unseen", "train"):
        average = group_average(summary, [t.name for t in table.resolve(split)])
        if average is not None:
            out[split] = average
    return out


def _run_of(checkpoint: Path) -> RunDir | None:
    """The training run a checkpoint belongs to (RUN/checkpoints/FILE.pt beside RUN/config.json)."""
    run = RunDir(checkpoint.parent.parent)
    return run if checkpoint.parent == run.checkpoints and run.config_path.exists() else None


def _validation(run: RunDir | None, ckpt: Checkpoint) -> dict:
    """The validation record of the checkpoint's step: the run's log, else what the checkpoint kept."""
    last = run.last_validation() if run is not None else {}
    if last.get("step") == ckpt.step:
        return last
    val = ckpt.extra.get("val") or {}
    return {"step": ckpt.step, "split": "val", **val} if val else {}


def _model_entry(checkpoint: Path, out: Path, model, ckpt: Checkpoint) -> dict:
    run = _run_of(checkpoint)
    cfg = run.read_config() if run is not None else {}
    conf = config_path(out)
    return {
        "file": out.name, "config": conf.name, "step": ckpt.step, "preset": preset_of(ckpt).name,
        "data_fingerprint": cfg.get("data_fingerprint", ckpt.extra.get("data_fingerprint")),
        "seed": cfg.get("seed"), "episodes": cfg.get("episodes"), "train": cfg.get("train"),
        "init": cfg.get("init"),
        "parameters": sum(p.numel() for p in model.parameters()), "validation": _validation(run, ckpt),
        "architecture": ckpt.config.get("preset"),
        "sha256": {out.name: sha256_file(out), conf.name: sha256_file(conf)},
        "converted_from": {"file": checkpoint.name, "sha256": sha256_file(checkpoint)},
    }  # fmt: skip


def ship_model(source: str | Path, kind: str, folder: str | Path | None = None) -> Path:
    """Write one trained model (a run directory, a ``.pt`` checkpoint or weights) into a weights folder
    (default: the package's) as ``KIND-PRESET.safetensors`` + ``.json``, named after its preset; record it
    with its SHA-256s in provenance.json, drop the results of the former pair and regenerate the card."""
    folder = _folder(folder)
    checkpoint = resolve_checkpoint(source)
    model, ckpt = load_model(checkpoint, kind)
    out = save_weights(folder / shipped_name(kind, preset_of(ckpt).name), model, ckpt.step, ckpt.config,
                       ckpt.extra)  # fmt: skip
    record = {k: v for k, v in weights.provenance(folder).items() if k not in STALE}
    record.setdefault("models", {})[kind] = _model_entry(checkpoint, out, model, ckpt)
    atomic_write_json(folder / PROVENANCE, record)
    write_model_card(folder)
    return out


def upgrade_weights(folder: str | Path | None = None) -> list[Path]:
    """Rewrite every model of a weights folder (default: the package's) in this tvf's weights format
    from its own files: the same tensors and safetensors bytes, the JSON config as :func:`save_weights`
    writes it now (with its hashes). Their SHA-256s in provenance.json follow; the rest of the record
    (training, evaluations) is kept and the card regenerated. Returns the weights files."""
    folder = _folder(folder)
    record = weights.provenance(folder)
    models = record.get("models", {})
    files = [p for e in models.values() for p in (folder / e["file"], config_path(folder / e["file"]))]
    originals = {p: p.read_bytes() for p in files if p.exists()}
    written = []
    try:
        for kind, entry in models.items():
            path = folder / entry["file"]
            model, ckpt = load_model(path, kind)
            save_weights(path, model, ckpt.step, ckpt.config, ckpt.extra)
            if path.read_bytes() != originals[path]:  # the same tensors: the same bytes
                raise TvfError(f"{path}: re-saving changed its bytes; kept the old files, nothing upgraded")
            entry["sha256"] = {p.name: sha256_file(p) for p in (path, config_path(path))}
            written.append(path)
    except BaseException:
        for p, data in originals.items():  # every model's files as they were: the record still holds
            atomic_write_bytes(p, data)
        raise
    atomic_write_json(folder / PROVENANCE, record)
    write_model_card(folder)
    return written


def check_hashes(folder: Path, record: dict) -> None:
    """Every file provenance.json lists matches its SHA-256; a missing or changed file is a TvfError."""
    for entry in record.get("models", {}).values():
        for name, digest in entry.get("sha256", {}).items():
            path = folder / name
            if not path.exists():
                raise TvfError(f"{path} is missing; run the experiment's weights stage again")
            if sha256_file(path) != digest:
                raise TvfError(f"{path} does not match its SHA-256 in {PROVENANCE}; export it again")


def ship_weights(exp_weights: Path, target: Path, preset: str = weights.SHIPPED_PRESET) -> None:
    """Copy an experiment's weights folder (models of ``preset``, checked against their SHA-256s) into
    ``target`` (the package's shipped weights) and write its model card there."""
    record = weights.provenance(exp_weights)
    for name in shipped_files(preset)[:-1]:  # the card is regenerated, not copied
        if not (exp_weights / name).exists():
            raise TvfError(f"{exp_weights / name} is missing; run the experiment's weights stage first")
    check_hashes(exp_weights, record)
    for name in shipped_files(preset)[:-1]:
        atomic_write_bytes(target / name, (exp_weights / name).read_bytes())
    write_model_card(target)


TASK_KEYS = ("success", "successes", "episodes", "progress", "ci95")
"""What an evaluation records per task (the summary's row), enough for the reports' cells."""


def record_evaluation(
    eval_dir: str | Path, folder: str | Path | None = None, name: str | None = None
) -> dict:  # fmt: skip
    """Add a `tvf eval` output folder (eval.json + summary.json) of the shipped weights to provenance.json
    under ``name`` (default: the method's label), replacing an entry of that name; regenerate the card.

    Only evaluations of this folder's weights qualify, by content as eval.json records it: the shipped
    files, or (``--gctn`` / ``--vf`` RUN) the checkpoints they were converted from bit-identically.
    """
    eval_dir, folder = Path(eval_dir), _folder(folder)
    fix = "pass a folder written by `tvf eval`"
    settings = read_json(eval_dir / "eval.json", fix)
    summary = read_json(eval_dir / "summary.json", fix)
    hashes = settings.get("weights") or {}
    unhashed = [f"--{k}" for k in ("gctn", "vf") if settings.get(k) and k not in hashes]
    if unhashed:
        raise TvfError(f"{eval_dir} evaluated {' and '.join(unhashed)} files it kept no SHA-256 of; "
                       "evaluate again with this tvf and record that folder")  # fmt: skip
    entry = {
        "name": name or label(settings["method"]),
        **{k: settings.get(k) for k in EVAL_KEYS if k not in ("gctn", "vf")},
        "seed_range": seed_range(settings["seed_start"]),
        "settings": {k: v for k, v in settings.items() if k not in EVAL_KEYS},
        "results": group_results(summary),
        "tasks": {r["task"]: {k: r[k] for k in TASK_KEYS if k in r} for r in summary["tasks"]},
    }
    record = weights.provenance(folder)
    if not record.get("models"):
        raise TvfError(f"{folder / PROVENANCE} lists no models; ship weights before recording evaluations")
    _check_evaluated_weights(hashes, record, eval_dir, folder)
    kept = [e for e in record.get("evaluations", []) if e["name"] != entry["name"]]
    record["evaluations"] = [*kept, entry]
    atomic_write_json(folder / PROVENANCE, record)
    write_model_card(folder)
    return entry


def _check_evaluated_weights(hashes: dict[str, str], record: dict, eval_dir: Path, folder: Path) -> None:
    """Refuse an evaluation whose weights files (by content, as eval.json records them) are not the ones
    this folder ships."""
    for kind, digest in hashes.items():
        model = record["models"].get(kind, {})
        shipped = {*model.get("sha256", {}).values(), model.get("converted_from", {}).get("sha256")}
        if model and digest not in shipped:
            raise TvfError(
                f"{eval_dir} evaluated other {kind} weights (content {digest[:8]}…) than {folder} ships; "
                "evaluate the shipped weights again and record that folder"
            )


def write_model_card(folder: str | Path | None = None) -> Path:
    """(Re)write a weights folder's README.md from its provenance.json."""
    folder = _folder(folder)
    path = folder / MODEL_CARD
    atomic_write_bytes(path, model_card(weights.provenance(folder)).encode())
    return path


# ---- the model card: Markdown generated from provenance.json only

MODEL_NAMES = {"gctn": "GCTN (goal-conditioned Transporter)", "vf": "VF (visual foresight)"}


def _pct(x: float) -> str:
    return f"{100 * x:.1f} %"


def _int(n: int) -> str:
    """``14 000``: thousands apart by a space."""
    return f"{n:,}".replace(",", " ")


def _cell(entry: dict | None) -> str:
    """``"63.7 % [56–71]"``: success and its Wilson 95 % interval, or "–"."""
    if not entry:
        return "–"
    lo, hi = entry["ci95"]
    return f"{_pct(entry['success'])} [{100 * lo:.0f}–{100 * hi:.0f}]"


def _seeds(seed_start: int | None) -> str:
    if seed_start is None:
        return "–"
    return f"{seed_range(seed_start)} (odd, from {_int(seed_start)})"


def _header(models: dict) -> list[str]:
    presets = "/".join(sorted({m.get("preset", "?") for m in models.values()}))
    return [
        f"# tvf `{presets}` weights: GCTN and visual foresight",
        "",
        "<!-- Generated from provenance.json by tvf.experiment.shipping.write_model_card: change the",
        "generator or the record, not this file. -->",
        "",
        "Small networks for Transporters with Visual Foresight (Wu et al., IROS 2022), trained with tvf:",
        "the goal-conditioned Transporter (GCTN) chooses a pick and a place from a top-down colour +",
        "height image and a goal image; the visual-foresight model (VF) predicts the image after a",
        "pick-and-place; TVF's tree search combines the two (docs/planner.md). Every tvf command loads",
        "these when no `--gctn` / `--vf` is given.",
    ]


def _files(models: dict) -> list[str]:
    head = "| model | weights | config | parameters | training steps | SHA-256 of the weights |"
    lines = ["", "## Files", "", head, "|---|---|---|---|---|---|"]
    for kind, m in models.items():
        digest = m.get("sha256", {}).get(m["file"], "–")
        numbers = f"{_int(m.get('parameters', 0))} | {_int(m['step'])}"
        lines.append(f"| {MODEL_NAMES.get(kind, kind)} | `{m['file']}` | `{m.get('config', '–')}` | "
                     f"{numbers} | `{digest}` |")  # fmt: skip
    return [
        *lines,
        "",
        "The weights are [safetensors](https://github.com/huggingface/safetensors) files, read without",
        "pickle; the JSON config beside each names the model kind, its preset (the architecture",
        "hyper-parameters), the training step, the format version and the SHA-256 of the tensors and of",
        "itself, checked at every load. `provenance.json` holds the SHA-256 of every file and everything",
        "below.",
        "",
        "```python",
        "from tvf.models.checkpoint import load_trained",
        "",
        'gctn = load_trained(None, "gctn")  # the shipped file; or a run folder, a .pt or .safetensors path',
        "```",
    ]


def _episodes(episodes: list) -> dict[str, list[int]]:
    out: dict[str, list[int]] = {}
    for task, seed in episodes or []:
        out.setdefault(task, []).append(seed)
    return out


def _data(models: dict) -> list[str]:
    by_task = _episodes(next((m["episodes"] for m in models.values() if m.get("episodes")), []))
    fingerprints = ", ".join(sorted({str(m.get("data_fingerprint")) for m in models.values()}))
    lines = [
        "",
        "## Training data",
        "",
        "Demonstrations of the scripted expert in the PyBullet tabletop (a Franka Panda with a suction",
        "cup, 4 cm red cubes; docs/world.md), seen by three simulated RGB-D cameras fused into a",
        "160 × 160 top-down colour + height map (docs/observation.md). Both models learnt from the same",
        f"episodes (data fingerprint `{fingerprints}`):",
        "",
        "| task | episodes | seeds |",
        "|---|---|---|",
        *(f"| {task} | {len(seeds)} | {', '.join(map(str, seeds))} |" for task, seeds in by_task.items()),
    ]
    unseen = [t.name for t in BUILTIN.resolve("unseen") if t.name not in by_task]
    if by_task and unseen:
        lines += ["", f"Never trained on (the unseen tasks): {', '.join(unseen)}."]
    return lines


def _recipe(record: dict) -> list[str]:
    models = record["models"]
    head = "| model | preset | steps | batch | learning rate | schedule | warm-up | seed | last validation |"
    lines = ["", "## Recipe", "", head, "|---|---|---|---|---|---|---|---|---|"]
    for kind, m in models.items():
        t = m.get("train") or {}
        val = {k: v for k, v in (m.get("validation") or {}).items() if k not in ("step", "split")}
        shown = ", ".join(f"{k} {v:.4g}" for k, v in val.items()) or "–"
        cells = [t.get(k, "–") for k in ("steps", "batch", "lr", "schedule", "warmup", "seed")]
        lines.append(f"| {kind} | {m.get('preset')} | " + " | ".join(map(str, cells)) + f" | {shown} |")
    lines += _fine_tunes(models)
    lines += ["", "Architecture (`tvf.models.presets.ModelPreset`, also in each JSON config):", ""]
    for kind, m in models.items():
        arch = ", ".join(f"{k}={v}" for k, v in (m.get("architecture") or {}).items())
        lines.append(f"* {kind}: `{arch or '–'}`")
    commands = (record.get("experiment") or {}).get("commands") or []
    if commands:
        lines += ["", "Made by:", "", "```bash", *commands, "```"]
    return lines


TUNE_FLAGS = {"vf_head": None, "vf_changed_weight": 0, "vf_rollout": 1, "turns": 1}
"""Training flags a fine-tune may set, with the value that means "not set"."""


def _fine_tunes(models: dict) -> list[str]:
    """One line per model trained from other weights (``--init``): the weights it started from (path,
    step, SHA-256 as its run recorded them) and the flags its training set."""
    lines = []
    for kind, m in models.items():
        t = m.get("train") or {}
        if not t.get("init"):
            continue
        source = m.get("init") or {}
        start = [f"step {source['step']}"] if "step" in source else []
        start += [f"SHA-256 `{source['sha256']}`"] if "sha256" in source else []
        flags = [f"--{k.replace('_', '-')} {_flag(t[k])}" for k, unset in TUNE_FLAGS.items()
                 if t.get(k) not in (None, unset)]  # fmt: skip
        line = f"* {kind}: trained from the weights `{t['init']}`"
        line += f" ({', '.join(start)})" if start else ""
        lines.append(line + (f" with {' '.join(flags)}" if flags else "") + ".")
    return ["", *lines] if lines else []


def _flag(value) -> str:
    return f"{value:g}" if isinstance(value, float) else str(value)


def _result_rows(record: dict) -> list[tuple[str, dict, dict]]:
    """(row name, eval settings, results by group): later evaluations first, then the experiment's own."""
    rows = [(e["name"], e, e["results"]) for e in record.get("evaluations", [])]
    exp = record.get("experiment") or {}
    for method, results in (record.get("results") or {}).items():
        rows.append((f"{label(method)} (the experiment)", exp, results))
    return rows


def _results(record: dict) -> list[str]:
    rows = _result_rows(record)
    lines = ["", "## Results", ""]
    if not rows:
        return [*lines, "No closed-loop evaluation is recorded for these weights."]
    lines += [
        "Closed-loop success rate with its Wilson 95 % interval; one pick-and-place per block, no extra",
        "steps (docs/results.md). No choice was made on the test range; the validation range chose the",
        "recipe and the planner's rules.",
        "",
        "| evaluation | seeds | episodes per task | unseen tasks | training tasks |",
        "|---|---|---|---|---|",
    ]
    for name, source, results in rows:
        name += _flags(source.get("settings") or {})
        lines.append(f"| {name} | {_seeds(source.get('seed_start'))} | {source.get('episodes', '–')} | "
                     f"{_cell(results.get('unseen'))} | {_cell(results.get('train'))} |")  # fmt: skip
    paper = ", ".join(f"{label(m)} {_pct(v)}" for m, v in PAPER_UNSEEN_10_DEMOS.items())
    lines += ["", f"The paper (full-size networks, 10 demos per task), unseen tasks: {paper}."]
    return lines + _per_task(record.get("evaluations", []))


def _flags(settings: dict) -> str:
    """`` (--turns 4, --turns-depth 1)``: the planner flags an evaluation set (none: the method's defaults
    when it ran)."""
    given = [f"--{k.replace('_', '-')} {v}" for k, v in settings.items() if v is not None and k != "env"]
    return f" ({', '.join(given)})" if given else ""


def _per_task(evals: list[dict]) -> list[str]:
    if not evals:
        return []
    tasks = list(dict.fromkeys(t for e in evals for t in e["tasks"]))
    sizes = sorted({e["episodes"] for e in evals})
    head = "| task | " + " | ".join(e["name"] for e in evals) + " |"
    lines = ["", f"Per task, the evaluations above ({' or '.join(map(str, sizes))} episodes each):", "",
             head, "|---|" + "---|" * len(evals)]  # fmt: skip
    for task in tasks:
        cells = [f"{100 * e['tasks'][task]['success']:.0f} %" if task in e["tasks"] else "–" for e in evals]
        lines.append(f"| {task} | " + " | ".join(cells) + " |")
    return lines


def _unsolved(evals: list[dict], at_most: float = 0.1) -> list[str]:
    """Tasks on which no evaluation succeeds on more than ``at_most`` of its episodes."""
    tasks = list(dict.fromkeys(t for e in evals for t in e["tasks"]))
    return [t for t in tasks if all(e["tasks"][t]["success"] <= at_most for e in evals if t in e["tasks"])]


def _limits(record: dict) -> list[str]:
    lines = [
        "",
        "## Limits",
        "",
        "* Simulation only: one simulator, one kind of block, the bases of the task table and one camera",
        "  set-up; nothing was tried on a real robot or with other objects, lighting or camera noise.",
        "* Small networks for a CPU: the preset's widths are fractions of the paper's (architecture",
        "  above), trained on a few demonstrations per task.",
    ]
    evals = [e for e in record.get("evaluations", []) if e.get("method") != "oracle"]
    best = max((e["results"]["unseen"]["success"] for e in evals if "unseen" in e["results"]), default=None)
    paper = max(PAPER_UNSEEN_10_DEMOS.values())
    if best is not None and best < paper:
        lines.append(f"* Below the paper: the best recorded method reaches {_pct(best)} on the unseen tasks, "
                     f"the paper's TVF {_pct(paper)}.")  # fmt: skip
    hard = _unsolved(evals)
    if hard:
        lines.append(f"* No recorded method succeeds in more than 10 % of the episodes of {', '.join(hard)}.")
    return lines


def model_card(record: dict) -> str:
    """The model card of a weights folder, in Markdown, from its provenance record alone."""
    models = record.get("models") or {}
    if not models:
        raise TvfError("the provenance record lists no models; ship weights first")
    parts = [_header(models), _files(models), _data(models), _recipe(record), _results(record)]
    return "\n".join(line for part in [*parts, _limits(record)] for line in part) + "\n"

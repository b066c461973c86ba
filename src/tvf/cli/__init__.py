"""The ``tvf`` command line: one entry point, one subcommand per stage of the pipeline.

Each subcommand is a frozen dataclass whose fields are its flags (parsed by tyro) and whose ``run``
method does the work. Errors from bad input print one line and exit with code 2, and so does a full
disk wherever it strikes (``ENOSPC``, also in the forms libraries wrap it in).
"""

from __future__ import annotations

import sys

import tyro

from tvf.cli.data import DataCmd, DemosCmd
from tvf.cli.evaluation import AblateCmd, CompareCmd, EvalCmd, EvalVfCmd
from tvf.cli.experiment import ExperimentCmd
from tvf.cli.plan import PlanCmd
from tvf.cli.quickstart import QuickstartCmd
from tvf.cli.train import TrainCmd, relaunch_command
from tvf.cli.viz import VizCmd
from tvf.cli.world import OracleCmd, RenderCmd, TasksCmd
from tvf.errors import Terminated, TvfError
from tvf.io import as_disk_full

DESCRIPTION = """tvf: Transporters with Visual Foresight.

Pipeline: `tvf tasks` (what can be built) -> `tvf oracle` / `tvf render` (the simulated world and its
expert) -> `tvf demos` (datasets) -> `tvf train gctn|vf` (the models) -> `tvf eval` (closed loop).
`tvf experiment` runs all of it and writes the report; `tvf quickstart` runs TVF-L with the shipped
weights; `tvf plan` plans from a real rig's camera files. Run `tvf COMMAND --help` for each command's
flags."""

COMMANDS: dict[str, type] = {
    "tasks": TasksCmd,
    "oracle": OracleCmd,
    "render": RenderCmd,
    "quickstart": QuickstartCmd,
    "demos": DemosCmd,
    "data": DataCmd,
    "train": TrainCmd,
    "eval": EvalCmd,
    "eval-vf": EvalVfCmd,
    "ablate": AblateCmd,
    "compare": CompareCmd,
    "plan": PlanCmd,
    "viz": VizCmd,
    "experiment": ExperimentCmd,
}


def main(argv: list[str] | None = None) -> None:
    args = sys.argv[1:] if argv is None else list(argv)
    try:
        # `tvf train --config RUN/config.json` takes its defaults from the file, so tyro parses it apart
        command = relaunch_command(args) or tyro.extras.subcommand_cli_from_dict(
            {name: cls for name, cls in COMMANDS.items()}, args=args, description=DESCRIPTION
        )
        command.run()
    except TvfError as exc:
        _fail(exc)
    except KeyboardInterrupt as exc:  # Ctrl-C, or SIGTERM while a pool runs (tvf.errors.Terminated)
        print("tvf: interrupted; finished work is kept, re-run the same command to resume", file=sys.stderr)
        raise SystemExit(143 if isinstance(exc, Terminated) else 130) from None
    except Exception as exc:  # a full disk that no write site named (a library's own file)
        full = as_disk_full(exc)
        if full is None:
            raise
        _fail(full)


def _fail(exc: TvfError) -> None:
    print(f"tvf: error: {' '.join(str(exc).split())}", file=sys.stderr)  # always one line
    raise SystemExit(2) from None


if __name__ == "__main__":
    main()

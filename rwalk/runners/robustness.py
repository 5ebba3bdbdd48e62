"""The robustness benchmark: the base gait and policies under conditions never used in training.

    rwalk-robustness --checkpoint logs/robust/model_600.pt \\
        --checkpoint today=logs/res_t06/model_475.pt --episodes 100 --json docs/robustness.json \\
        --plot docs/robustness.png

Every row of a condition runs the same --episodes paired episodes: episode i
starts like a single env seeded --seed + i, with the same drawn physics and the
same kicks, whichever policy walks (a policy of either task: each walks on an env of its
own task, the base gait on the residual task's). The conditions, floors, table and plot are
``rwalk.robustness``'s: nominal, new maps, rougher ground, low and high friction,
payload, weak servos, pushes and latency. Prints one table per condition with
each policy's floors, writes every row to --json and, with --plot, a bar chart.
With --by-kind, the rows of the new maps are followed by one per kind of tile
('new maps: stones'), of the same episodes.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import tyro

from rwalk import presets
from rwalk.cli import command, one_line_errors, parse, usage_error
from rwalk.config import MAX_ENVS, MAX_SETTLE_STEPS, MAX_STEPS, EnvConfig
from rwalk.evaluation import check_policy
from rwalk.levels import TerrainLevels
from rwalk.rl.checkpoints import atomic_write_text, check_outputs
from rwalk.robustness import CONDITIONS, condition_config, plot, read_rows, run_condition, table
from rwalk.validation import require_at_least, require_at_most

PROG = command("rwalk.runners.robustness")
"""The command in usage lines and error messages."""


@dataclass(frozen=True)
class RobustnessArgs:
    """rwalk-robustness's command line (each field a flag)."""

    checkpoint: Annotated[tuple[str, ...], tyro.conf.UseAppendAction] = ()
    """[LABEL=]PATH of an rwalk-train checkpoint (repeatable; LABEL: its run folder's name)"""
    episodes: int = 100
    """paired episodes per condition"""
    seed: int = 1000
    """first episode's seed"""
    map_level: int = 6
    """level of the 'new maps' condition"""
    max_steps: int = presets.EVALUATION.max_episode_steps
    """episode length (env steps)"""
    settle_steps: int = presets.EVALUATION.settle_steps
    """settling before each episode"""
    conditions: tuple[str, ...] = tuple(CONDITIONS)
    """conditions to run, of these (quote a name with a space)"""
    json: Path | None = None
    """write every row here"""
    plot: Path | None = None
    """write the bar chart here (PNG)"""
    tables: Path | None = None
    """only print the table (and --plot) of a written --json"""
    by_kind: bool = False
    """also a row per kind of tile of a condition on a map of several (new maps), named
    'new maps: stones': the same episodes, those of the envs on that kind (env i walks
    kind i mod the kinds)"""

    def __post_init__(self) -> None:
        require_at_least(self, 1, "episodes", "max_steps")
        require_at_least(self, 0, "seed", "map_level", "settle_steps")
        require_at_most(self, MAX_ENVS, "episodes")
        require_at_most(self, MAX_STEPS, "seed", "max_steps", "map_level")
        require_at_most(self, MAX_SETTLE_STEPS, "settle_steps")
        known = ", ".join(map(repr, CONDITIONS))
        if not self.conditions:
            raise ValueError(f"--conditions needs at least one of {known}")
        unknown = [name for name in self.conditions if name not in CONDITIONS]
        if unknown:
            raise ValueError(f"--conditions must be some of {known}, got {unknown[0]!r}")

    @property
    def checkpoints(self) -> dict[str, Path]:
        """Each --checkpoint by its label (``LABEL=PATH``, or the run folder's name)."""
        out = {}
        for text in self.checkpoint:
            label, _, path = text.rpartition("=")
            out[label or Path(path).parent.name] = Path(path)
        return out


def parse_args(argv: list[str] | None = None) -> RobustnessArgs:
    """``argv`` as rwalk-robustness's arguments, every file checked before any row runs.
    Exits 2 with one line naming a bad flag or file."""
    args = parse(RobustnessArgs, argv, prog=PROG, description=__doc__)
    outputs = {"--plot": args.plot} | ({} if args.tables else {"--json": args.json})
    check_outputs(PROG, outputs)  # before any row runs
    if args.tables:
        return args
    labels = [text.rpartition("=")[0] or Path(text).parent.name for text in args.checkpoint]
    twice = next((label for label in labels if labels.count(label) > 1), None)
    if twice is not None:
        usage_error(PROG, f"--checkpoint: two checkpoints are labelled {twice!r}; give each a "
                          f"LABEL=PATH of its own")  # fmt: skip
    try:
        TerrainLevels().check_level(args.map_level)
    except ValueError as error:
        usage_error(PROG, f"--map-level: {error}")
    for label, path in args.checkpoints.items():  # every file, before any row runs
        if not path.is_file():
            usage_error(PROG, f"--checkpoint {label}: checkpoint {str(path)!r} not found")
        try:
            check_policy(path)
        except (OSError, ValueError) as error:
            usage_error(PROG, f"--checkpoint {label}: {error}")
    return args


@one_line_errors("rwalk.runners.robustness")
def main(argv: list[str] | None = None) -> None:
    """Console script ``rwalk-robustness`` (returns None: its exit status is 0)."""
    args = parse_args(argv)
    if args.tables:
        try:
            rows = read_rows(args.tables)
        except (OSError, ValueError) as error:
            usage_error(PROG, f"--tables: {error}")
    else:
        policies: dict[str, Path | None] = {"base gait": None, **args.checkpoints}
        rows = []
        for name in args.conditions:

            def config(name: str = name, trained: EnvConfig | None = None) -> EnvConfig:
                return condition_config(
                    name, args.map_level, args.max_steps, args.settle_steps, trained
                )

            new = run_condition(name, policies, args.episodes, args.seed, config, args.by_kind)
            rows += new
            print(table(new).split("\n", 2)[2], flush=True)
        if args.json:
            data = {
                "episodes": args.episodes, "seed": args.seed, "map_level": args.map_level,
                "max_steps": args.max_steps, "settle_steps": args.settle_steps,
                "by_kind": args.by_kind,
                "conditions": {name: CONDITIONS[name][0] for name in args.conditions},
                "checkpoints": {label: str(path) for label, path in args.checkpoints.items()},
                "rows": [dataclasses.asdict(r) for r in rows],
            }  # fmt: skip
            args.json.parent.mkdir(parents=True, exist_ok=True)
            atomic_write_text(args.json, json.dumps(data, indent=2))
    print(table(rows))
    if args.plot:
        args.plot.parent.mkdir(parents=True, exist_ok=True)
        plot(rows, args.plot)
        print(f"wrote {args.plot}")


if __name__ == "__main__":  # through the module by name, where tyro reads RobustnessArgs's types
    from rwalk.runners.robustness import main as robustness_main

    robustness_main()

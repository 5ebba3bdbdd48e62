"""A trainer's command line: its training dataclass, every nested field a flag.

The preset's flags (--task, --robust/--no-robust, --costs, --settle-pool-fraction,
--recipe) and --num-envs choose the defaults (``Preset.env``, and the task's recipe's
train fields and --max-iterations: ``Preset.own_recipe``); with --resume the defaults are
the resumed run's own record, so that a flag given on --resume that differs from
the run's is one the user typed (``rwalk.rl.config.resume_conflict``), and the run
goes on in its own folder with its own seed unless --log-dir or --seed says
otherwise. Then every
field is a flag (``rwalk.cli.parse``): ``--env.costs.clearance 3000``,
``--env.randomization.friction 0.5 1.3``; naming a field of a part the defaults
leave out (``--env.pushes.speed 0.1 0.2`` on --no-robust) adds that part at its
defaults first. ``ALIASES`` keep the short names of the common env fields.
"""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path
from typing import Any

from rwalk.cli import parse, usage_error
from rwalk.config import part_type
from rwalk.rl.config import Preset, symmetry_refusal
from rwalk.validation import flag

#: Short flags of common nested fields: the name a user types -> the field's flag.
ALIASES = {
    "--settle-steps": "--env.settle-steps",
    "--settle-reuse": "--env.settle-reuse",
    "--max-episode-steps": "--env.max-episode-steps",
    "--terrain-scale": "--env.terrain-scale",
    "--command-range": "--env.command-range",
    "--start-spread": "--env.start-spread",
    "--gait-action": "--env.gait-action",
    "--clearance-weight": "--env.costs.clearance",
    "--terrain-kinds": "--env.terrain-levels.kinds",
    "--demote": "--env.terrain-levels.demote",
}


def peek(argv: list[str], name: str) -> str | bool | None:
    """The value the last ``--name`` of ``argv`` gives (a bool for ``--name`` /
    ``--no-name`` alone), or None."""
    found: str | bool | None = None
    option, negated = flag(name), "--no-" + flag(name)[2:]
    for i, token in enumerate(argv):
        key, sign, value = token.partition("=")
        if key == negated:
            found = False
        elif key == option:
            following = argv[i + 1] if i + 1 < len(argv) else ""
            found = value if sign else (following if following[:2] != "--" and following
                                        else True)  # fmt: skip
    return found


def with_parts_named(config: Any, argv: list[str], prefix: str = "--") -> Any:
    """``config`` with every part that is None but named by a flag of ``argv``
    (``--env.costs.clearance``) at its type's defaults (``GaitCosts()``)."""
    changes = {}
    for f in dataclasses.fields(config):
        value, name = getattr(config, f.name), f"{prefix}{f.name.replace('_', '-')}"
        kind = part_type(type(config), f.name)
        if value is None and kind and any(t.startswith(name + ".") for t in argv):
            value = changes[f.name] = kind()
        if dataclasses.is_dataclass(value):
            inner = with_parts_named(value, argv, name + ".")
            if inner is not value:
                changes[f.name] = inner
    return dataclasses.replace(config, **changes) if changes else config


def defaults(cls: type, argv: list[str], read_record) -> Any:
    """The training ``cls`` that ``argv``'s preset flags and --num-envs choose, or the
    record of the run --resume names (``read_record(config_json)``, where it reads):
    values stage 2 parses the rest against. Values that are not valid here are left
    to ``parse``, which names them."""
    resume = peek(argv, "resume")
    num_envs = peek(argv, "num_envs")
    own = {f.name: f for f in dataclasses.fields(cls)}
    base = own["num_envs"].default
    num_envs = int(num_envs) if isinstance(num_envs, str) and num_envs.isdigit() else base
    run = own["run"].default_factory()
    if isinstance(resume, str) and resume:
        path = Path(resume)
        folder = path if path.is_dir() else path.parent
        try:
            saved = read_record(folder / "config.json")
        except (OSError, ValueError):
            saved = None  # --resume names it, before any work
        if saved is not None:  # in its own folder with its own seed and length (its last
            # stages count back from its end) and threads (one and two round differently
            # on some CPUs; runs side by side on one each would fight over every core),
            # unless flags say else
            run = dataclasses.replace(run, log_dir=str(folder), seed=saved.run.seed,
                                      max_iterations=saved.run.max_iterations,
                                      threads=saved.run.threads,
                                      share_cores=saved.run.share_cores)  # fmt: skip
            return dataclasses.replace(saved, run=run, num_envs=num_envs)
    values = {}
    for f in dataclasses.fields(Preset):
        given = peek(argv, f.name)
        if given is not None:
            values[f.name] = given if f.type == "bool" or isinstance(given, bool) else (
                float(given) if f.type == "float" else given)  # fmt: skip
    try:
        return _from_preset(cls, dataclasses.replace(own["preset"].default_factory(), **values),
                            argv, num_envs, run)  # fmt: skip
    except (ValueError, TypeError):
        return _from_preset(cls, own["preset"].default_factory(), [], base, run)


def _from_preset(cls: type, preset: Preset, argv: list[str], num_envs: int, run: Any) -> Any:
    """The training ``cls`` that ``preset`` starts for ``num_envs`` envs: its env, and where
    it trains with its task's recipe (``Preset.own_recipe``), the recipe's train fields
    (without its teacher and student where ``argv`` says --no-teacher or --distill, without
    the student's start on its teacher's levels where it says --student-iterations 0) and
    --max-iterations."""
    env = with_parts_named(preset.env(num_envs), argv, "--env.")
    recipe = preset.own_recipe
    if recipe is None:
        return cls(env=env, preset=preset, num_envs=num_envs, run=run)
    teacher = peek(argv, "teacher") is not False and not peek(argv, "distill")
    student = peek(argv, "student_iterations") != "0"
    plain = next(f for f in dataclasses.fields(cls) if f.name == "train").default_factory()
    fields = recipe.train_fields(num_envs, teacher=teacher, student=student)
    train = dataclasses.replace(plain, **fields)
    run = dataclasses.replace(run, max_iterations=recipe.max_iterations)
    return cls(env=env, preset=preset, num_envs=num_envs, train=train, run=run)


def parse_training(cls: type, argv: list[str] | None, prog: str, description: str | None,
                   read_record) -> Any:  # fmt: skip
    """A trainer's command line ``argv`` (None: ``sys.argv[1:]``) as its training ``cls``
    (``Training`` or ``TorchRLTraining``), resolved where it starts a run.

    Raises:
        SystemExit: 0 after --help, 2 after a one-line error naming the flag.
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    expanded = [ALIASES.get(t.partition("=")[0], t.partition("=")[0]) + t.partition("=")[1]
                + t.partition("=")[2] for t in argv]  # fmt: skip
    default = defaults(cls, expanded, read_record)
    kind = cls[type(default.env)]
    text = (description or "") + "\n\nShort names: " + ", ".join(
        f"{alias} = {target}" for alias, target in ALIASES.items())  # fmt: skip
    training = parse(kind, argv, prog=prog, description=text, default=default, aliases=ALIASES)
    if getattr(training.train, "symmetry", False) and "--symmetry" in argv:
        refusal = symmetry_refusal(training.train)  # the default adapts, a flag does not
        if refusal:
            usage_error(prog, refusal)
    try:
        return training.resolved()
    except ValueError as error:  # a rule written out that the flags contradict
        usage_error(prog, str(error))

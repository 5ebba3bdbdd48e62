"""Sim-to-sim: a checkpoint's policy through the torch-free runtime on plain MuJoCo.

    rwalk-sim2sim logs/rwalk/model_299.pt --out sim2sim --json docs/sim2sim.json

Exports the checkpoint (``OUT/exported``: what ``rwalk.deploy.Controller`` loads),
then (1) the closed loop: --episodes of the env's evaluation (starts spread over
the rough world, --steps periods each) beside the runtime driving ``mj_step`` on
the same models and starts, compared bit for bit (``rwalk.sim2sim.closed_loop``);
the gap of the checkpoint's torch policy to its ONNX file on the same inputs;
(2) the runtime alone on each --world XML, under the env's physics and the
fidelity harness's reference physics (0.5 ms, tight solver; each target held
over the finer substeps), each start settled first as the evaluation's are (its
settle steps of the base gait): falls and velocity error, with the reference's
noise band (``rwalk.fidelity.BAND`` standard errors). Prints the tables, writes --json.
A teacher (its actor reads privileged pieces) is refused: only a policy that reads
what the robot senses deploys.
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
from rwalk.config import MAX_ENVS, MAX_STEPS
from rwalk.rl.checkpoints import atomic_write_text, check_outputs
from rwalk.validation import require_at_least, require_at_most

#: The worlds the runtime walks alone by default (the base-gait check's).
WORLDS = ("model/world_flat.xml", "model/world_train.xml")
PROG = command("rwalk.runners.sim2sim")
"""The command in usage lines and error messages."""


@dataclass(frozen=True)
class Sim2SimArgs:
    """rwalk-sim2sim's command line (each field a flag; the checkpoint comes first)."""

    checkpoint: Annotated[Path, tyro.conf.Positional, tyro.conf.arg(metavar="CHECKPOINT")]
    """an rwalk-train checkpoint (either task; not a teacher)"""
    out: Path = Path("sim2sim")
    """folder of the export (OUT/exported)"""
    episodes: int = 10
    """closed-loop episodes"""
    steps: int = presets.EVALUATION.max_episode_steps
    """control periods per episode"""
    seed: int = 1000
    """first episode's seed"""
    world: tuple[Path, ...] = tuple(Path(world) for world in WORLDS)
    """worlds the runtime walks alone (none: skip)"""
    walk_episodes: int = 20
    """episodes per world and physics"""
    latency: int = 0
    """also time this many control steps of the runtime, one thread (a benchmark: run alone)"""
    json: Path | None = None
    """write the results here"""

    def __post_init__(self) -> None:
        require_at_least(self, 1, "episodes", "steps", "walk_episodes")
        require_at_least(self, 0, "seed", "latency")
        require_at_most(self, MAX_ENVS, "episodes")
        require_at_most(self, MAX_STEPS, "steps", "seed", "walk_episodes", "latency")


def parse_args(argv: list[str] | None = None) -> Sim2SimArgs:
    """``argv`` as rwalk-sim2sim's arguments, every file checked before any work. Exits 2
    with one line naming a bad flag, a world or output that cannot be used, or a
    checkpoint that does not deploy."""
    from rwalk.deploy import DEPLOYABLE, TASKS
    from rwalk.evaluation import check_policy

    args = parse(Sim2SimArgs, argv, prog=PROG, description=__doc__)
    for world in args.world:
        if not world.is_file():
            usage_error(PROG, f"--world: {str(world)!r} not found")
    check_outputs(PROG, {"--out": args.out / "exported" / "policy.json", "--json": args.json})
    try:
        record = check_policy(args.checkpoint)
    except (OSError, ValueError) as error:
        usage_error(PROG, f"CHECKPOINT: {error}")
    if record.task not in TASKS:
        usage_error(PROG, f"CHECKPOINT: a {record.task!r} policy; the runtime runs policies "
                          f"of {', '.join(TASKS)}")  # fmt: skip
    privileged = [piece for piece in record.train.policy_obs if piece not in DEPLOYABLE]
    if privileged:
        usage_error(PROG, f"CHECKPOINT: {str(args.checkpoint)!r} is a teacher: its policy "
                          f"reads {tuple(privileged)} (privileged: only the simulator knows "
                          f"them); deploy a student (rwalk-train --distill) that reads "
                          f"{DEPLOYABLE}")  # fmt: skip
    return args


@one_line_errors("rwalk.runners.sim2sim")
def main(argv: list[str] | None = None) -> None:
    """Console script ``rwalk-sim2sim`` (returns None: its exit status is 0)."""
    args = parse_args(argv)

    from rwalk import sim2sim
    from rwalk.envs.torchrl_env import BatchedEnv
    from rwalk.evaluation import evaluation_config, load_policy
    from rwalk.export import export_policy
    from rwalk.fidelity import BAND, CANDIDATES

    config = evaluation_config(args.checkpoint, max_episode_steps=args.steps)
    env = BatchedEnv(args.episodes, config, seed=args.seed)
    for world in args.world:  # before anything is written
        try:
            sim2sim.check_world(world, env.core.world.dt)
        except ValueError as error:
            usage_error(PROG, f"--world: {error}")
    policy = load_policy(args.checkpoint, env)
    folder = args.out / "exported"
    export_policy(policy, folder)
    env.set_seed(args.seed)
    env.core.reset()
    gap = sim2sim.policy_gap(policy, folder)
    traces = sim2sim.closed_loop(folder, env, args.seed, args.steps)
    same = sum(trace.first_difference is None for trace in traces)
    print(f"closed loop: {same}/{len(traces)} episodes bit-identical over "
          f"{sum(t.steps for t in traces)} periods; torch vs ONNX policy on the same inputs: "
          f"max |Δaction| {gap:.2e}")  # fmt: skip
    for trace in traces:
        if trace.first_difference is not None:
            print(f"  episode {trace.env}: first difference after period "
                  f"{trace.first_difference}, max {trace.max_difference:.3g}")  # fmt: skip
    walks = []
    v_target = float(config.expected_velocity)
    settle = sim2sim.Settle.of(env.core)
    for world in args.world:
        for name in ("env", "reference"):
            physics = None if name == "env" else CANDIDATES["reference"]
            result = sim2sim.walk(folder, world, args.walk_episodes, args.steps, v_target,
                                  seed=args.seed, physics=physics, settle=settle)  # fmt: skip
            walks.append({"physics": name, **dataclasses.asdict(result)})
    if walks:
        print(sim2sim.walk_table(walks, BAND))
    latency = None
    if args.latency:
        latency = sim2sim.step_latency(folder, Path(WORLDS[0]), args.latency)
        print(f"one control step of the runtime (policy included, one thread): median "
              f"{latency['median_us']:.0f} µs, 90th percentile {latency['p90_us']:.0f} µs "
              f"over {args.latency} steps")  # fmt: skip
    if args.json:
        atomic_write_text(args.json, json.dumps({
            "checkpoint": str(args.checkpoint), "policy_gap": gap,
            "closed_loop": [dataclasses.asdict(t) for t in traces],
            "settle_steps": config.settle_steps, "walks": walks, "latency": latency,
        }, indent=2) + "\n")  # fmt: skip


if __name__ == "__main__":  # through the module by name, where tyro reads Sim2SimArgs's types
    from rwalk.runners.sim2sim import main as sim2sim_main

    sim2sim_main()

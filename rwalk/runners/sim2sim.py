"""Sim-to-sim: a checkpoint's policy through the torch-free runtime on plain MuJoCo.

    rwalk-sim2sim logs/rwalk/model_299.pt --out sim2sim --json docs/sim2sim.json

Exports the checkpoint (``OUT/exported``: what ``rwalk.deploy.Controller`` loads),
then (1) the closed loop: --episodes of the env's evaluation (starts spread over
the rough world, --steps periods each) beside the runtime driving ``mj_step`` on
the same models and starts, compared bit for bit (``rwalk.sim2sim.closed_loop``);
the gap of the checkpoint's torch policy to its ONNX file on the same inputs;
(2) the runtime alone on each --world XML, under the env's physics and the
fidelity harness's reference physics (0.5 ms, tight solver; each target held
over the finer substeps): falls and velocity error, with the reference's noise
band (``rwalk.fidelity.BAND`` standard errors). Prints the tables, writes --json.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

from rwalk.cli import NATURAL_INT, POSITIVE_INT, command, one_line_errors
from rwalk.rl.checkpoints import atomic_write_text

#: The worlds the runtime walks alone by default (the base-gait check's).
WORLDS = ("model/world_flat.xml", "model/world_train.xml")


@one_line_errors("rwalk.runners.sim2sim")
def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        prog=command("rwalk.runners.sim2sim"), description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )  # fmt: skip
    add = parser.add_argument
    add("checkpoint", type=Path, help="an rwalk-train checkpoint (either task; not a teacher)")
    add("--out", type=Path, default=Path("sim2sim"), help="folder of the export (OUT/exported)")
    add("--episodes", type=POSITIVE_INT, default=10, help="closed-loop episodes")
    add("--steps", type=POSITIVE_INT, default=1000, help="control periods per episode")
    add("--seed", type=NATURAL_INT, default=1000, help="first episode's seed")
    add("--world", nargs="*", default=list(WORLDS), metavar="XML",
        help="worlds the runtime walks alone (none: skip)")  # fmt: skip
    add("--walk-episodes", type=POSITIVE_INT, default=20, help="episodes per world and physics")
    add("--latency", type=NATURAL_INT, default=0, metavar="STEPS",
        help="also time STEPS control steps of the runtime on one thread (a benchmark: "
        "run it alone)")  # fmt: skip
    add("--json", type=Path, help="write the results here")
    args = parser.parse_args(argv)
    for world in args.world:
        if not Path(world).is_file():
            parser.error(f"--world: {world!r} not found")

    from rwalk import presets, sim2sim
    from rwalk.envs.torchrl_env import BatchedEnv
    from rwalk.evaluation import acts_in, check_policy, load_policy
    from rwalk.export import export_policy
    from rwalk.fidelity import BAND, CANDIDATES

    saved = check_policy(args.checkpoint)
    config = presets.evaluation_config(
        **acts_in(args.checkpoint), max_steps=args.steps, command_range=saved.env.commands
    )
    env = BatchedEnv(args.episodes, config, seed=args.seed, task=saved.task)
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
    for world in args.world:
        for name in ("env", "reference"):
            physics = None if name == "env" else CANDIDATES["reference"]
            result = sim2sim.walk(folder, Path(world), args.walk_episodes, args.steps,
                                  v_target, seed=args.seed, physics=physics)  # fmt: skip
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
            "closed_loop": [dataclasses.asdict(t) for t in traces], "walks": walks,
            "latency": latency,
        }, indent=2) + "\n")  # fmt: skip


if __name__ == "__main__":
    main()

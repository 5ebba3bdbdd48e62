"""The code blocks of the docs run as written (the spec's examples with rwalk's imports)."""

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _blocks(name: str) -> list[str]:
    return re.findall(r"```python\n(.*?)```", (ROOT / "docs" / name).read_text(), re.DOTALL)


def test_spec_examples_use_only_rwalk_imports():
    blocks = _blocks("spec_examples.md")
    assert len(blocks) == 5
    code = "\n".join(blocks)
    assert not re.search(r"^\s*(from|import) (envs|gait_controller)\b", code, re.MULTILINE)
    assert (
        "from rwalk import ResidualWalkEnv" in code and "from rwalk import GaitParameters" in code
    )


@pytest.mark.parametrize("index", range(5))
def test_spec_example_runs(index, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)  # the PPO example saves a file
    # test_gym_env trains the PPO example (2048 steps); here only its lines around learn run.
    code = _blocks("spec_examples.md")[index].replace("model.learn(total_timesteps=1_000_000)", "")
    namespace: dict = {}
    exec(compile(code, f"spec_examples.md block {index}", "exec"), namespace)
    assert "env" in namespace
    if "custom_gait" in namespace:
        assert capsys.readouterr().out.strip() == "Expected velocity: 0.125 m/s"


def test_architecture_examples_run_as_registered_tasks(monkeypatch):
    """docs/architecture.md's new term and new task: each one module plus one registry line."""
    import torch

    from rwalk import EnvConfig, ResidualWalkVecEnv
    from rwalk.tasks import TASKS

    heading, stand = _blocks("architecture.md")
    namespace: dict = {}
    exec(compile(heading, "architecture.md heading", "exec"), namespace)
    exec(compile(stand, "architecture.md stand", "exec"), namespace)
    monkeypatch.setitem(TASKS, "heading_walk", namespace["HeadingWalk"])
    monkeypatch.setitem(TASKS, "stand", namespace["Stand"])
    config = EnvConfig(model_path="model/world_flat.xml", settle_steps=5)
    env = ResidualWalkVecEnv(2, config, seed=0, task="heading_walk")
    td = env.rand_step(env.reset())
    assert "heading" in td["next", "reward_terms"]
    stand_env = ResidualWalkVecEnv(2, config, seed=0, task="stand")
    td = stand_env.step(stand_env.reset().set("action", torch.zeros(2, 12)))
    assert not td["next", "terminated"].any()


def test_adaptive_example_runs():
    (code,) = _blocks("adaptive.md")
    namespace: dict = {}
    exec(compile(code, "adaptive.md", "exec"), namespace)
    assert namespace["obs"].shape == (69,) and namespace["td"]["command"].shape == (8, 1)

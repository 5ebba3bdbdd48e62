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


def _architecture() -> dict[str, str]:
    """The worked examples of docs/architecture.md, in order."""
    names = ("term", "piece", "physics_row", "task")
    blocks = _blocks("architecture.md")
    assert len(blocks) == len(names), [block.splitlines()[0] for block in blocks]
    return dict(zip(names, blocks, strict=True))


def _register(monkeypatch, code: str, title: str) -> dict:
    from rwalk.tasks import TASKS

    namespace: dict = {}
    exec(compile(code, f"architecture.md {title}", "exec"), namespace)
    for value in list(namespace.values()):
        name = getattr(value, "name", None)
        if isinstance(value, type) and isinstance(name, str) and name not in TASKS:
            monkeypatch.setitem(TASKS, name, value)
    return namespace


def test_architecture_new_term_reads_new_data_in_every_view(monkeypatch):
    import numpy as np
    import torch

    from rwalk import EnvConfig, ResidualWalkEnv, ResidualWalkVecEnv

    _register(monkeypatch, _architecture()["term"], "term")
    config = EnvConfig(settle_steps=5)  # the rough world: the ground's height varies
    env = ResidualWalkVecEnv(2, config, seed=0, task="tall_walk")
    td = env.rand_step(env.reset())
    terms = td["next", "reward_terms"]
    core = env.core
    height = core.obs[:, 2] - core.terrain.heights_at(core.obs[:, 0], core.obs[:, 1])
    assert bool((core.terrain.heights_at(core.obs[:, 0], core.obs[:, 1]) != 0).all())
    torch.testing.assert_close(terms["torso_clearance"].squeeze(-1), (10.0 * height).float())
    assert bool((height > 0.03).all())
    total = sum(terms[name] for name in terms.keys())  # noqa: SIM118 (TensorDict)
    torch.testing.assert_close(total, td["next", "reward"])
    assert "sum/torso_clearance" in core.episode_log(torch.tensor([0]))
    # The Gymnasium view's float pipeline takes the term as a float of its one env.

    class TallWalkEnv(ResidualWalkEnv):
        task = "tall_walk"

    view = TallWalkEnv(config=config, seed=0)
    view.reset()
    _, reward, _, _, info = view.step(np.zeros(12, dtype=np.float32))
    assert view.single_step is not None
    assert isinstance(info["reward_components"]["torso_clearance"], float)
    assert reward == sum(info["reward_components"].values(), 0.0)


def test_architecture_new_piece_with_noise_is_one_declaration(monkeypatch):
    import torch

    from rwalk import EnvConfig, ObservationNoise, ResidualWalkVecEnv
    from rwalk.wrappers import RslRlVecEnv

    _register(monkeypatch, _architecture()["piece"], "piece")
    config = EnvConfig(model_path="model/world_flat.xml", settle_steps=5,
                       observation_noise=ObservationNoise())  # fmt: skip
    env = ResidualWalkVecEnv(3, config, seed=0, task="height_aware_walk")
    groups = ("observation", "torso_height")
    obs = RslRlVecEnv(env, policy_obs=groups, critic_obs=groups).get_observations()
    assert env.core.piece_size("torso_height") == 1
    height = env.core.piece("torso_height")
    torch.testing.assert_close(height[:, 0], env.core.obs[:, 2])  # flat ground at z = 0
    noise = obs["policy"][:, 65] - obs["critic"][:, 65]
    assert bool((noise.abs() <= 0.005 + 1e-6).all()) and bool((noise != 0).any())
    assert torch.equal(obs["critic"][:, 65], height[:, 0].float())


def test_architecture_new_physics_parameter_is_one_table_row(tmp_path):
    """The row, added to a copy of the package, makes a field, a draw, a model write and a
    column of the physics piece, and passes the table's own test."""
    import shutil
    import subprocess
    import sys

    row = _architecture()["physics_row"]
    shutil.copytree(ROOT / "rwalk", tmp_path / "rwalk", symlinks=True)
    shutil.copytree(ROOT / "model", tmp_path / "model")
    module = tmp_path / "rwalk" / "randomization.py"
    source = module.read_text()
    end = source.index(")  # fmt: skip", source.index("PHYSICS_PARAMS: tuple"))
    module.write_text(source[:end] + row + source[end:])
    check = """
import numpy as np
from rwalk import EnvConfig
from rwalk.core import Core
from rwalk.randomization import PHYSICS_PARAMS, Randomization
assert Randomization().torso_inertia == (0.8, 1.2)
assert Randomization.nominal().torso_inertia == (1.0, 1.0)
core = Core(EnvConfig(model_path="model/world_flat.xml", settle_steps=2,
                      randomization=Randomization()), 2, seed=0)
core.reset()
column = [p.name for p in PHYSICS_PARAMS].index("torso_inertia")
torso = core.model.body("torso").id
for i in range(2):
    value = float(core.physics.params[i, column])
    assert 0.8 <= value <= 1.2
    written = core.sim.batch.get_model(i).body_inertia[torso]
    assert np.array_equal(written, core.model.body_inertia[torso] * value)
assert core.piece("physics").shape == (2, 10)
print("ok")
"""
    env = {**__import__("os").environ, "PYTHONPATH": str(tmp_path)}
    done = subprocess.run([sys.executable, "-c", check], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=300, check=False)  # fmt: skip
    assert done.stdout.strip() == "ok", done.stderr[-2000:]
    table = subprocess.run(
        [sys.executable, "-m", "pytest", "-v", "-p", "no:cacheprovider", "-o", "addopts=",
         str(ROOT / "tests" / "test_randomization.py"), "-k", "physics_table"],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300, check=False,
    )  # fmt: skip
    assert "fields[torso_inertia] PASSED" in table.stdout, table.stdout[-2000:]
    assert table.returncode == 0, table.stdout[-2000:]


def test_architecture_new_task_is_one_module_and_one_line(monkeypatch, tmp_path):
    import json

    import torch

    from rwalk import EnvConfig, ResidualWalkVecEnv
    from rwalk.runners import play, train

    _register(monkeypatch, _architecture()["task"], "task")
    config = EnvConfig(model_path="model/world_flat.xml", settle_steps=5)
    env = ResidualWalkVecEnv(2, config, seed=0, task="stand")
    td = env.step(env.reset().set("action", torch.zeros(2, 12)))
    assert not td["next", "terminated"].any()
    # rwalk-train's defaults (the robust world, symmetry, the export), at tiny sizes
    folder = tmp_path / "stand"
    train.main(["--task", "stand", "--num-envs", "4", "--num-steps-per-env", "4",
                "--settle-steps", "2", "--max-episode-steps", "20", "--hidden-dims", "8",
                "--max-iterations", "2", "--log-dir", str(folder)])  # fmt: skip
    assert json.loads((folder / "config.json").read_text())["preset"]["task"] == "stand"
    layout = json.loads((folder / "exported" / "policy.json").read_text())
    assert (folder / "exported" / "policy.onnx").is_file() and "deploy" not in layout
    rows = play.play(["--checkpoint", str(folder / "model_1.pt"), "--episodes", "2",
                      "--max-steps", "10", "--settle-steps", "2"])  # fmt: skip
    assert rows[0].episodes == 2 and rows[0].mean_length == 10


def test_adaptive_example_runs():
    (code,) = _blocks("adaptive.md")
    namespace: dict = {}
    exec(compile(code, "adaptive.md", "exec"), namespace)
    assert namespace["obs"].shape == (69,) and namespace["td"]["command"].shape == (8, 1)


def _commands(text: str, marker: str) -> list[list[str]]:
    """The rwalk-train commands of ``text``'s bash blocks that contain ``marker``, as
    argv (line continuations joined, comments dropped)."""
    found = []
    for block in re.findall(r"```bash\n(.*?)```", text, re.DOTALL):
        joined = re.sub(r"\\\n\s*", " ", block)
        for line in joined.splitlines():
            line = line.split("#", 1)[0].strip()
            if line.startswith(".venv/bin/rwalk-train") and marker in line:
                found.append(line.split()[1:])
    return found


def test_the_adaptive_default_command_is_the_same_in_the_readme_and_the_docs():
    """README's adaptive default and docs/adaptive.md's "Training: one command" train the
    same run: the teacher, then the GRU student on its teacher's levels, then its fine-tune."""
    from rwalk.runners import train

    section = (ROOT / "docs" / "adaptive.md").read_text().split("## Training: one command")[1]
    (doc,) = _commands(section.split("\n## ", 1)[0], "adaptive_gait")
    (readme,) = _commands((ROOT / "README.md").read_text(), "adaptive_gait")
    assert doc == readme
    args = train.parse_args(doc)
    assert args.task == "adaptive_gait" and args.run.log_dir == "logs/adaptive"
    assert args.train.teacher and args.train.student_iterations == 190
    assert args.train.student_actor == "gru" and args.train.distill_levels
    assert args.env.gait_action == "schedule" and args.env.bounds.step_length.low == 0.04
    # the step pinned to the schedule, 13 mm at v* rising 40 mm per m/s, at a 0.55 duty factor
    assert args.env.schedule_step_rise == 0.04 and args.env.schedule_window[0] == 0.0
    assert args.env.gait.step_height == 0.013 and args.env.gait.duty_factor == 0.55
    assert args.train.finetune_iterations == 150
    # the flags it lists for the recipe, typed with --recipe plain, train the same
    listed = section.split("these flags with `--recipe plain`")[1].split("```")[1]
    typed = train.parse_args([*listed.replace("\\", " ").split(), "--log-dir", "logs/adaptive"])
    assert typed.preset.recipe == "plain" and typed.preset.own_recipe is None
    assert (typed.env, typed.train, typed.run) == (args.env, args.train, args.run)

"""Exported policies (TorchScript and ONNX) outside the runners, and the Gymnasium recipe."""

import contextlib
import dataclasses
import io
import json
import re
import shutil
from pathlib import Path

import numpy as np
import onnx
import onnxruntime
import pytest
import torch
from tensordict import TensorDict

from rwalk import EnvConfig, ResidualWalkEnv, ResidualWalkVecEnv
from rwalk.export import DEFAULT_PIECES, export_policy, input_layout, policy_input
from rwalk.rl.config import TrainArgs as Args
from rwalk.rl.runner import SafeRunner
from rwalk.rl.training import make_env, rsl_rl_config
from rwalk.wrappers import RslRlVecEnv

ARGS = dataclasses.replace(
    Args(), num_envs=4, settle_steps=2, max_episode_steps=30, hidden_dims=(16, 16), robust=False
)
QUICK = EnvConfig(settle_steps=2, max_episode_steps=20)
ROOT = Path(__file__).resolve().parents[1]


def _runner(env) -> SafeRunner:
    with contextlib.redirect_stdout(io.StringIO()):  # rsl-rl prints the architecture
        return SafeRunner(env, rsl_rl_config(ARGS), log_dir=None, device="cpu")


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """A runner whose normaliser has non-trivial statistics, saved and exported."""
    torch.manual_seed(0)
    runner = _runner(make_env(ARGS))
    policy = runner.alg.get_policy()
    policy.train()
    for _ in range(3):  # raw observations far from zero mean / unit std
        policy.obs_normalizer.update(3.0 + 5.0 * torch.randn(64, policy.obs_dim))
    folder = tmp_path_factory.mktemp("run")
    runner.save(str(folder / "model_0.pt"))
    jit_path, onnx_path = export_policy(runner, folder / "exported")
    return folder, jit_path, onnx_path


def _session(path) -> onnxruntime.InferenceSession:
    return onnxruntime.InferenceSession(str(path), providers=["CPUExecutionProvider"])


def test_export_writes_one_self_contained_onnx_and_its_layout(exported):
    folder, jit_path, onnx_path = exported
    assert jit_path == folder / "exported" / "policy.pt"
    assert onnx_path == folder / "exported" / "policy.onnx"
    names = sorted(p.name for p in onnx_path.parent.iterdir())
    assert names == ["policy.json", "policy.onnx", "policy.pt"]  # no .onnx.data, no temp file
    model = onnx.load(str(onnx_path), load_external_data=False)
    assert not any(onnx.external_data_helper.uses_external_data(t) for t in model.graph.initializer)
    (graph_input,) = model.graph.input
    dims = graph_input.type.tensor_type.shape.dim
    assert graph_input.name == "obs" and dims[0].dim_param and dims[1].dim_value == 68
    metadata = {p.key: p.value for p in model.metadata_props}
    assert metadata["input_pieces"] == "observation:65,phase:2,lateral_offset:1"
    layout = json.loads((onnx_path.parent / "policy.json").read_text())
    assert json.loads(metadata["rwalk_layout"]) == layout
    pieces = [(p["name"], p["start"], p["size"]) for p in layout["input"]["pieces"]]
    assert pieces == [("observation", 0, 65), ("phase", 65, 2), ("lateral_offset", 67, 1)]


def test_torchscript_onnx_and_the_checkpoint_agree_on_a_batch(exported):
    folder, jit_path, onnx_path = exported
    obs = 3.0 + 5.0 * torch.randn(5, 68, generator=torch.Generator().manual_seed(1))
    jit_actions = torch.jit.load(str(jit_path))(obs)
    onnx_actions = _session(onnx_path).run(None, {"obs": obs.numpy()})[0]
    np.testing.assert_allclose(onnx_actions, jit_actions.detach().numpy(), atol=1e-5)

    fresh = _runner(make_env(ARGS))
    fresh.load(str(folder / "model_0.pt"))
    policy = fresh.get_inference_policy()
    with torch.inference_mode():
        expected = policy(TensorDict({"policy": obs}, batch_size=[5]))
        without_normaliser = policy.mlp(obs)
    np.testing.assert_allclose(onnx_actions, expected.numpy(), atol=1e-5)
    # The normaliser matters for these inputs: an export without it would fail above.
    assert (expected - without_normaliser).abs().max() > 1e-3


@pytest.mark.parametrize("batch", [1, 7])
def test_exports_take_any_batch_size(exported, batch):
    _, jit_path, onnx_path = exported
    obs = torch.randn(batch, 68)
    onnx_actions = _session(onnx_path).run(None, {"obs": obs.numpy()})[0]
    assert onnx_actions.shape == (batch, 12)
    jit_actions = torch.jit.load(str(jit_path))(obs).detach().numpy()
    np.testing.assert_allclose(onnx_actions, jit_actions, atol=1e-5)


def test_the_layout_follows_the_policy_group(tmp_path):
    vec = ResidualWalkVecEnv(2, QUICK, seed=0)
    runner = _runner(RslRlVecEnv(vec, policy_obs=("phase", "observation")))
    export_policy(runner, tmp_path)
    layout = json.loads((tmp_path / "policy.json").read_text())["input"]
    assert layout["shape"] == ["batch", 67]
    assert [(p["name"], p["start"]) for p in layout["pieces"]] == [
        ("phase", 0),
        ("observation", 2),
    ]
    with pytest.raises(ValueError, match=r"pieces \('observation',\) have 65 values.*67"):
        export_policy(runner, tmp_path / "other", pieces=("observation",))
    with pytest.raises(ValueError, match=r"unknown observation pieces.*'speed'"):
        input_layout(("observation", "speed"))
    with pytest.raises(TypeError, match="got str"):
        export_policy("model.pt", tmp_path)


def test_policy_input_checks_its_arguments():
    obs = np.zeros(65, dtype=np.float32)
    row = policy_input(obs, {"phase": 0.25, "lateral_offset": -0.5})
    assert row.shape == (68,) and row.dtype == np.float32
    np.testing.assert_allclose(row[65:], [1.0, 0.0, -0.5], atol=1e-7)  # sin, cos of 2π/4
    with pytest.raises(ValueError, match=r"shape \(65,\) or \(69,\), got \(68,\)"):
        policy_input(row, {"phase": 0.0, "lateral_offset": 0.0})
    with pytest.raises(KeyError, match="'lateral_offset'"):
        policy_input(obs, {"phase": 0.0})
    assert policy_input(obs, {}, pieces=("observation",)).shape == (65,)
    with pytest.raises(ValueError, match=r"'cycle_speed'.*rwalk\.deploy\.Controller"):
        policy_input(obs, {"phase": 0.0}, pieces=("observation", "cycle_speed"))


def test_policy_input_is_the_rsl_rl_policy_group():
    """The Gymnasium env seeded s is env 0 of a batch seeded s: same rows, step by step.

    Needs the Gymnasium env's info keys "phase" and "lateral_offset" (reset and step)."""
    single = ResidualWalkEnv(config=QUICK)
    batch = RslRlVecEnv(ResidualWalkVecEnv(1, QUICK, seed=3))
    obs, info = single.reset(seed=3)
    actions = np.random.default_rng(0).uniform(-1, 1, (4, 12)).astype(np.float32)
    for action in actions:
        expected = batch.get_observations()["policy"][0].numpy()
        np.testing.assert_allclose(policy_input(obs, info, DEFAULT_PIECES), expected, atol=1e-6)
        obs, _, _, _, info = single.step(action)
        batch.step(torch.from_numpy(action)[None])
    assert abs(info["lateral_offset"]) > 0  # the robot moved sideways a little


def test_an_onnx_policy_runs_an_episode_of_the_gymnasium_env(exported, monkeypatch):
    """The recipe of docs/environment.md, "Running an exported policy", as written there
    (on the exported folder, with a short episode)."""
    _, _, onnx_path = exported
    text = (ROOT / "docs" / "environment.md").read_text()
    section = text.split("## Running an exported policy", 1)[1].split("\n## ", 1)[0]
    code, _ = re.findall(r"```python\n(.*?)```", section, re.DOTALL)
    code = code.replace('"logs/plain/exported"', repr(str(onnx_path.parent)))
    code = code.replace("ResidualWalkEnv()", "ResidualWalkEnv(config=QUICK)")
    steps = []
    original_step = ResidualWalkEnv.step

    def step(self, action):
        assert action.shape == (12,) and np.isfinite(action).all()
        steps.append(action)
        return original_step(self, action)

    monkeypatch.setattr(ResidualWalkEnv, "step", step)
    namespace = {"QUICK": QUICK}
    exec(compile(code, "environment.md", "exec"), namespace)
    assert namespace["done"] and (len(steps) == 20 or namespace["terminated"])
    assert np.abs(np.stack(steps)).max() > 0  # the policy acted


def test_policy_input_builds_the_adaptive_policy_group_with_a_command():
    from rwalk import AdaptiveGaitConfig, AdaptiveGaitEnv, AdaptiveGaitVecEnv

    config = AdaptiveGaitConfig(model_path=QUICK.model_path, settle_steps=5,
                                command_range=(0.1, 0.2))  # fmt: skip
    single = AdaptiveGaitEnv(config=config)
    batch = RslRlVecEnv(AdaptiveGaitVecEnv(1, config, seed=3))
    obs, info = single.reset(seed=3)
    pieces = ("observation", "phase", "lateral_offset", "command")
    for action in np.random.default_rng(0).uniform(-1, 1, (3, 16)).astype(np.float32):
        expected = batch.get_observations()["policy"][0].numpy()
        assert expected.shape == (73,)
        np.testing.assert_allclose(policy_input(obs, info, pieces), expected, atol=1e-6)
        obs, _, _, _, info = single.step(action)
        batch.step(torch.from_numpy(action)[None])


def test_policy_input_reads_the_last_action_as_the_env_does():
    from rwalk import ResidualWalkEnv

    env = ResidualWalkEnv()
    obs, info = env.reset(seed=3)
    pieces = ("observation", "phase", "lateral_offset", "last_action")
    sent = np.zeros(12, dtype=np.float32)  # after reset: the base gait, no action yet
    for action in np.random.default_rng(0).uniform(-1.5, 1.5, (3, 12)).astype(np.float32):
        row = policy_input(obs, info, pieces, last_action=sent)
        expected = env.unwrapped.core.piece("last_action")[0].numpy().astype(np.float32)
        np.testing.assert_array_equal(row[68:], expected)
        obs, *_, info = env.step(action)
        sent = action
    assert np.abs(row[68:]).max() == 1.0 and np.abs(sent).max() > 1.0  # clipped, as the env
    with pytest.raises(ValueError, match="pass last_action"):
        policy_input(obs, info, pieces)
    with pytest.raises(ValueError, match=r"12 finite numbers, got shape \(16,\)"):
        policy_input(obs, info, pieces, last_action=np.zeros(16))
    with pytest.raises(ValueError, match=r"12 finite numbers.*nan"):
        policy_input(obs, info, pieces, last_action=np.full(12, np.nan))


def test_the_observation_from_the_start_reads_the_start_from_info():
    from rwalk import ResidualWalkEnv

    env = ResidualWalkEnv()
    obs, info = env.reset(seed=3)
    for _ in range(5):
        obs, *_, info = env.step(np.full(12, 0.3, dtype=np.float32))
    row = policy_input(obs, info, ("observation_from_start", "lateral_offset"))
    expected = env.unwrapped.core.piece("observation_from_start")[0].numpy().astype(np.float32)
    np.testing.assert_array_equal(row[2:65], expected[2:])
    # x and y come from the float32 observation (x ~ -3.5 m: one float32 step is 2.4e-7 m)
    np.testing.assert_allclose(row[:2], expected[:2], rtol=0, atol=5e-7)
    assert row[1] == pytest.approx(info["lateral_offset"])
    assert row[0] == np.float32(np.float64(obs[0]) - info["start_position"][0])
    with pytest.raises(KeyError, match="start_position"):
        policy_input(obs, {}, ("observation_from_start",))


@pytest.fixture(scope="module")
def recurrent(tmp_path_factory):
    """A GRU policy of a robust run (it reads the observation from the episode's start),
    its normaliser trained on the env's own observations, exported."""
    torch.manual_seed(1)
    args = dataclasses.replace(ARGS, robust=True, actor="gru", rnn_hidden_dim=16)
    with contextlib.redirect_stdout(io.StringIO()):
        runner = SafeRunner(make_env(args), rsl_rl_config(args), log_dir=None, device="cpu")
    policy = runner.alg.get_policy()
    policy.train()
    policy.obs_normalizer.update(runner.env.get_observations()["policy"])
    with torch.no_grad():  # an output that is not 0, so that the state shows
        for parameter in policy.mlp.parameters():
            parameter.add_(0.1 * torch.randn_like(parameter))
    folder = tmp_path_factory.mktemp("gru") / "exported"
    export_policy(runner, folder)
    return runner, folder


def test_a_recurrent_onnx_policy_carries_its_state(recurrent):
    runner, folder = recurrent
    layout = json.loads((folder / "policy.json").read_text())
    state = layout["recurrent"]
    assert state["kind"] == "gru" and state["inputs"] == ["h_in"] and state["hidden"] == 16
    session = _session(folder / "policy.onnx")
    assert [i.name for i in session.get_inputs()] == ["obs", "h_in"]
    policy = runner.alg.get_policy().eval()
    policy.reset()
    env = runner.env
    h = np.zeros((1, 3, 16), np.float32)  # three envs, zeros at the start
    obs = env.get_observations()["policy"][:3]
    for _ in range(4):  # the same inputs: only the state moves the outputs
        with torch.inference_mode():
            want = policy(TensorDict({"policy": obs}, batch_size=[3])).numpy()
        got, h = session.run(None, {"obs": obs.numpy(), "h_in": h})
        np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-6)
    assert not np.allclose(got, session.run(None, {"obs": obs.numpy(), "h_in": 0 * h})[0])
    with pytest.raises(ValueError, match="h_in"):  # run without its state: named
        session.run(None, {"obs": obs.numpy()})


def test_a_recurrent_onnx_policy_runs_an_episode_of_the_gymnasium_env(recurrent, tmp_path):
    """The recurrent recipe of docs/environment.md, as written there (a short episode)."""
    _, exported = recurrent
    folder = tmp_path / "exported"  # a copy whose record says another residual scale
    shutil.copytree(exported, folder)
    layout = json.loads((folder / "policy.json").read_text())
    layout["deploy"]["residual_scale"] = 0.03
    (folder / "policy.json").write_text(json.dumps(layout))
    text = (ROOT / "docs" / "environment.md").read_text()
    section = text.split("## Running an exported policy", 1)[1].split("\n## ", 1)[0]
    _, code = re.findall(r"```python\n(.*?)```", section, re.DOTALL)
    code = code.replace('"logs/rwalk/student/exported"', repr(str(folder)))
    scale = 'residual_scale=layout["deploy"]["residual_scale"]'
    assert f"ResidualWalkEnv({scale})" in code
    code = code.replace(
        f"ResidualWalkEnv({scale})", f"ResidualWalkEnv(config=replace(QUICK, {scale}))"
    )
    namespace = {"QUICK": QUICK, "replace": dataclasses.replace}
    exec(compile(code, "environment.md recurrent", "exec"), namespace)
    assert namespace["done"] and namespace["state"]["h_in"].any()
    assert namespace["env"].core.config.residual_scale == 0.03  # the policy's, not the spec's

import pytest

from rwalk.assets import load_model

FLAT = "model/world_flat.xml"
TRAIN = "model/world_train.xml"


@pytest.fixture(scope="session")
def flat_model():
    return load_model(FLAT)


@pytest.fixture(scope="session")
def train_model():
    return load_model(TRAIN)


def write_run(folder, **changes):
    """An untrained rwalk-train run's checkpoint and the config.json beside it, as
    rwalk-train writes them: tiny defaults (2 envs, hidden (8,)) with ``changes``.
    Returns the checkpoint's path."""
    import contextlib
    import dataclasses
    import io
    import json

    from rwalk.rl.config import TrainArgs
    from rwalk.rl.runner import SafeRunner
    from rwalk.rl.training import make_env, rsl_rl_config

    args = dataclasses.replace(TrainArgs(), num_envs=2, settle_steps=2, max_episode_steps=10,
                               hidden_dims=(8,), **changes)  # fmt: skip
    with contextlib.redirect_stdout(io.StringIO()):  # rsl-rl prints the architecture
        runner = SafeRunner(make_env(args), rsl_rl_config(args), log_dir=None, device="cpu")
    runner.save(str(folder / "model_0.pt"))
    (folder / "config.json").write_text(json.dumps({"args": dataclasses.asdict(args)}))
    return folder / "model_0.pt"

"""Importing rwalk changes no global state of the process."""

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _python(code: str, cwd: Path = ROOT) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-c", code], cwd=cwd, capture_output=True, text=True, timeout=300,
        check=False,
    )  # fmt: skip


def test_import_leaves_multiprocessing_alone_and_loads_torchrl_on_first_use():
    done = _python(
        "import multiprocessing as mp, sys\n"
        "import rwalk\n"
        "from rwalk import EnvConfig, ResidualWalkEnv\n"
        "ResidualWalkEnv(config=EnvConfig(settle_steps=1)).reset(seed=0)\n"
        "print(mp.get_start_method(allow_none=True), 'torchrl' in sys.modules)\n"
        "from rwalk import ResidualWalkVecEnv\n"
        "print('torchrl' in sys.modules, ResidualWalkVecEnv.__name__ in rwalk.__all__)\n"
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["None", "False", "True", "True"]


def test_async_vector_env_works_in_a_script_without_a_main_guard(tmp_path):
    script = tmp_path / "no_guard.py"
    script.write_text(
        "import gymnasium as gym\n"
        "import numpy as np\n"
        "import rwalk\n"
        "envs = gym.make_vec(rwalk.GYM_ID, num_envs=2, vectorization_mode='async',\n"
        "                    settle_steps=1, model_path='model/world_flat.xml')\n"
        "obs, _ = envs.reset(seed=0)\n"
        "obs, *_ = envs.step(np.zeros((2, 12), dtype=np.float32))\n"
        "print(obs.shape)\n"
        "envs.close()\n"
    )
    done = subprocess.run(
        [sys.executable, str(script)], cwd=ROOT, capture_output=True, text=True, timeout=300,
        check=False,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stdout.strip() == "(2, 65)"

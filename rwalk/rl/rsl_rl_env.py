"""``RslRlVecEnv``: rsl-rl-lib 5.x's ``VecEnv`` over a batched env of any task."""

from __future__ import annotations

import dataclasses

import torch
from rsl_rl.env import VecEnv
from tensordict import TensorDict

from rwalk import episodes
from rwalk import mirror as mirrors
from rwalk.envs.torchrl_env import BatchedEnv
from rwalk.mirror import Mirror
from rwalk.threads import SharedCores

#: Groups read with observation noise: the policy's, and a teacher's (it acts on what the
#: student senses, as it did in its own training).
NOISY_GROUPS = ("policy", "teacher")


class RslRlVecEnv(VecEnv):
    """Adapts the batched env to rsl-rl: auto-reset inside ``step``, observation
    groups as a TensorDict, ``extras["time_outs"]`` and ``extras["log"]``.

    Observation groups (each a (N, D) float32 tensor, pieces concatenated):
    ``policy`` and ``critic``, from the task's named pieces: ``observation``
    (the spec's: 65 values, 69 for adaptive_gait), ``phase`` (2, sin/cos of the
    gait phase), ``lateral_offset`` (1, y - y0), and any other piece of the task
    (``command``, ``gait``, ``sensors``, ``physics``, ``heights``). None takes the
    observation and every extra piece of the task, and for the critic also the
    task's privileged pieces (``Task.privileged``: the randomised physics and the
    ground around the feet, when the config varies the world). A distillation adds
    the group ``teacher`` (the frozen teacher's pieces), a PPO with a lag-priced
    smoothness (``rwalk.rl.ppo``) the group ``smoothing`` (``servo_lag`` and
    ``last_action``, which no model reads). The policy and teacher groups carry
    ``EnvConfig.observation_noise`` (the same draw); the others are exact.

    ``extras["log"]`` (means over the episodes that ended this step):
    ``Episode_Reward/<term>`` (per-step mean of each reward term),
    ``Episode/length``, ``Episode/fall_rate``, ``Episode/forward_velocity``,
    ``Episode/velocity_error`` (|mean v_x - v*|), ``Episode/velocity_bias`` (mean v_x -
    v*), ``Episode/step_velocity_error`` (mean |v_x - v*| per step: the evaluations'
    error), ``Episode/velocity_ripple`` (its part within the stride), ``Episode/diverged``, and
    ``Perf/settle_share`` (share of all physics so far spent settling starts);
    on a terrain-levels map also ``Curriculum/terrain_level`` (mean level of all
    envs) and ``Curriculum/level_<kind>`` (of the envs on each kind of tile).

    Args:
        env: the batched env (its core is stepped directly: no TensorDict per step).
        policy_obs: pieces of the policy group.
        critic_obs: pieces of the critic group.
        teacher_obs: pieces of the group ``teacher`` (a distillation's).
        smoothing_obs: pieces of the group ``smoothing`` (what ``rwalk.rl.ppo`` prices).
        reward_scale: rsl-rl sees ``reward * reward_scale`` (the env's reward is the
            spec's, ~300 per step; PPO's value clipping works in absolute units).
    """

    def __init__(
        self,
        env: BatchedEnv,
        policy_obs: tuple[str, ...] | None = None,
        critic_obs: tuple[str, ...] | None = None,
        reward_scale: float = 1.0,
        teacher_obs: tuple[str, ...] = (),
        smoothing_obs: tuple[str, ...] = (),
    ) -> None:
        every = ("observation", *env.core.task.extras())
        policy_obs = every if policy_obs is None else policy_obs
        critic_obs = (*every, *env.core.task.privileged()) if critic_obs is None else critic_obs
        for name in (*policy_obs, *critic_obs, *teacher_obs, *smoothing_obs):
            env.core.piece_size(name)  # raises ValueError naming an unknown piece
        if not reward_scale > 0:
            raise ValueError(f"reward_scale must be > 0, got {reward_scale!r}")
        self.env = env
        self.core = env.core
        groups = {
            "policy": policy_obs,
            "critic": critic_obs,
            "teacher": teacher_obs,
            "smoothing": smoothing_obs,
        }
        self.groups = {name: tuple(pieces) for name, pieces in groups.items() if pieces}
        """The pieces of each observation group (an empty group is left out)."""
        self.reward_scale = float(reward_scale)
        self.num_envs = env.num_envs
        self.num_actions = env.action_spec.shape[-1]
        self.max_episode_length = env.config.max_episode_steps
        self.device = "cpu"
        self.cfg = dataclasses.asdict(env.config)
        self.sharing: SharedCores | None = None
        """Polled at every step when set (the trainers set it): torch's threads follow what
        other processes leave of the cores."""
        if not self.core.started:
            self.core.reset()

    @property
    def episode_length_buf(self) -> torch.Tensor:
        """Steps taken in each env's episode. Shape: (N,)."""
        return self.core.episode_step

    @episode_length_buf.setter
    def episode_length_buf(self, value: torch.Tensor) -> None:
        # rsl-rl's init_at_random_ep_len spreads the first truncations out.
        self.core.episode_step.copy_(value)

    def get_observations(self) -> TensorDict:
        core = self.core
        pieces = {name: core.piece(name) for names in self.groups.values() for name in names}
        noisy = core.observations.noisy  # the same noise for every read within one step
        groups = {
            group: [noisy(name, pieces[name]) if group in NOISY_GROUPS else pieces[name]
                    for name in names]
            for group, names in self.groups.items()
        }  # fmt: skip
        return TensorDict(
            {group: torch.cat(parts, dim=-1).to(torch.float32) for group, parts in groups.items()},
            batch_size=[self.num_envs],
        )

    def step(self, actions: torch.Tensor) -> tuple[TensorDict, torch.Tensor, torch.Tensor, dict]:
        if self.sharing is not None:
            self.sharing.poll()
        result, ended = episodes.step(self.core, actions)
        extras: dict = {"time_outs": result.truncated}
        if ended is not None:
            extras["log"] = self._episode_log(ended.stats)
        reward = (result.reward * self.reward_scale).to(torch.float32)
        return (
            self.get_observations(),
            reward,
            (result.terminated | result.truncated).long(),
            extras,
        )

    def _episode_log(self, stats: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        length = stats["length"]
        log = {
            f"Episode_Reward/{key.removeprefix('sum/')}": (value / length.clamp(min=1)).mean()
            for key, value in stats.items()
            if key.startswith("sum/")
        }
        velocity = stats["forward_velocity"]
        log["Episode/length"] = length.mean()
        log["Episode/fall_rate"] = stats["terminated"].double().mean()
        log["Episode/forward_velocity"] = velocity.mean()
        log["Episode/velocity_error"] = (velocity - stats["target_velocity"]).abs().mean()
        log["Episode/velocity_bias"] = stats["velocity_bias"].mean()
        log["Episode/step_velocity_error"] = stats["velocity_error"].mean()
        log["Episode/velocity_ripple"] = stats["velocity_ripple"].mean()
        log["Episode/diverged"] = stats["diverged"].double().mean()
        log["Perf/settle_share"] = torch.tensor(self.core.settle_share)
        commands = self.core.task.commands
        return log | self.core.curriculum.log() | ({} if commands is None else commands.log())

    # ------------------------------------------------------------ symmetry
    def mirror(self, group: str) -> Mirror:
        """The left-right mirror of an observation group: its pieces' (``rwalk.mirror``).

        Raises:
            ValueError: naming a piece that declares none.
        """
        return mirrors.concat(self.core.observations.mirror(name) for name in self.groups[group])

    def action_mirror(self) -> Mirror:
        """The left-right mirror of an action (the task's).

        Raises:
            ValueError: naming the task, if it declares none.
        """
        return self.core.task.action_mirror()

    # ------------------------------------------------------------ checkpoints
    def state_dict(self) -> dict[str, torch.Tensor]:
        """The env's state a checkpoint keeps beside the policy (the hook ``rwalk.rl.runner``
        calls at each save): ``Core.curriculum_state``, the terrain levels and command
        weights."""
        return self.core.curriculum_state()

    def load_state_dict(self, state: dict[str, torch.Tensor]) -> str | None:
        """Go on from a checkpoint's ``state_dict()`` (``Core.load_curriculum_state``);
        returns a line for the log where it was of another number of envs or command bins.

        Raises:
            ValueError: naming the field, if the state is not what ``state_dict`` writes.
        """
        return self.core.load_curriculum_state(state)

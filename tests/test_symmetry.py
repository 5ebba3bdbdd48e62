"""The robot's left-right mirror (rwalk.mirror): declared per piece and per action, an
involution, and true of the simulation: a mirrored state gives the mirrored observation."""

import numpy as np
import pytest
import torch

from rwalk import AdaptiveGaitConfig, EnvConfig, ObservationNoise, Randomization
from rwalk import mirror as mirrors
from rwalk.constants import JOINT_NAMES
from rwalk.core import Core
from rwalk.envs.torchrl_env import BatchedEnv
from rwalk.levels import TerrainLevels
from rwalk.rl.rsl_rl_env import RslRlVecEnv
from rwalk.rl.symmetry import apply, augment

FLAT = "model/world_flat.xml"


def test_the_model_is_symmetric_about_its_xz_plane():
    """What the mirror assumes of robot.xml: twin legs at mirrored places, the same masses,
    inertias, joints and servos; abduction about x, hip and knee about y."""
    model = Core(EnvConfig(model_path=FLAT, settle_steps=0), 1).model
    for left, right in (("FL", "FR"), ("RL", "RR")):
        for part in ("hip_link", "thigh", "shin"):
            a, b = model.body(f"{left}_{part}"), model.body(f"{right}_{part}")
            assert np.array_equal(a.pos * [1, -1, 1], b.pos), part
            assert a.mass[0] == b.mass[0] and np.array_equal(a.inertia, b.inertia), part
            assert np.array_equal(a.ipos * [1, -1, 1], b.ipos), part
        for kind, axis in (("abduction", [1, 0, 0]), ("hip", [0, 1, 0]), ("knee", [0, 1, 0])):
            a, b = model.joint(f"{left}_{kind}"), model.joint(f"{right}_{kind}")
            assert np.array_equal(a.axis, axis) and np.array_equal(b.axis, axis)
            assert np.array_equal(a.range, b.range if kind != "abduction" else -b.range[::-1])
            assert a.damping[0] == b.damping[0] and a.armature[0] == b.armature[0]
    torso = model.body("torso")
    assert torso.ipos[1] == 0.0 and torso.pos[1] == 0.0


PIECES = ("sensors", "phase", "lateral_offset", "command", "cycle_speed", "physics", "heights",
          "heights_under_feet", "servo_lag", "last_action")  # fmt: skip


@pytest.mark.parametrize("name", [*PIECES, "gait"])
def test_mirroring_twice_is_the_identity(name):
    core = Core(AdaptiveGaitConfig(model_path=FLAT, settle_steps=0), 1)
    mirror = core.observations.mirror(name)
    assert sorted(mirror.index) == list(range(mirror.size))  # a permutation
    assert mirror.size == core.piece_size(name)
    values = torch.randn(5, mirror.size, dtype=torch.float64)
    assert torch.equal(apply(mirror, apply(mirror, values)), values)


def test_the_actions_mirror_twice_to_themselves():
    for task in ("residual_walk", "adaptive_gait"):
        env = BatchedEnv(2, None, seed=0, task=task)
        mirror = env.core.task.action_mirror()
        actions = torch.randn(3, env.core.task.action_dim)
        assert torch.equal(apply(mirror, apply(mirror, actions)), actions)
    left_front = torch.zeros(12)
    left_front[0:3] = torch.tensor([0.1, 0.2, 0.3])  # FL: forward, outward (+y), up
    mirrored = apply(mirrors.RESIDUALS, left_front)
    assert mirrored[3:6].tolist() == pytest.approx([0.1, -0.2, 0.3])  # FR, outward is -y
    assert not mirrored[0:3].any()


def _sense(core: Core) -> None:
    """The sensors of env 0's current state (a step reports those of its last substep's
    start) into the core's observation."""
    core.sim.forward(np.array([0], dtype=np.int32))
    core.obs.copy_(torch.from_numpy(core.sim.sensordata.copy()))
    core.obs[:, 61:65] = (core.obs[:, 61:65] > 0).to(torch.float64)


def _mirrored_state(core: Core, target: Core) -> None:
    """Write the mirror of ``core``'s env 0 (its simulation and its gait half a cycle on) into
    ``target``'s env 0."""
    qpos, qvel = core.sim.qpos[0].copy(), core.sim.qvel[0].copy()
    joints = core.world.joint_qpos
    mirror = mirrors.per_leg((-1, 1, 1))
    index, signs = np.array(mirror.index), np.array(mirror.signs)
    qpos[1] *= -1
    qpos[3:7] *= [1, -1, 1, -1]  # (w, x, y, z) -> (w, -x, y, -z)
    qpos[joints] = qpos[joints][index] * signs
    qvel[1] *= -1
    qvel[3:6] *= [-1, 1, -1]  # the free joint's angular velocity, a pseudovector
    dofs = slice(6, 6 + len(JOINT_NAMES))
    qvel[dofs] = qvel[dofs][index] * signs
    target.sim.qpos[0], target.sim.qvel[0] = qpos, qvel
    _sense(target)
    target.task.tick[0] = (core.task.tick[0] + core.controller.period // 2) % core.controller.period
    target.episodes.x0.copy_(core.episodes.x0)
    target.episodes.y0.copy_(-core.episodes.y0)


def test_a_simulated_mirrored_state_gives_the_mirrored_observation():
    config = EnvConfig(model_path=FLAT, settle_steps=20, randomize=True)
    core, twin = Core(config, 1, seed=3), Core(config, 1, seed=4)
    core.reset()
    twin.reset()
    generator = torch.Generator().manual_seed(0)
    for _ in range(37):  # a generic state: mid-stride, turned, rolling
        core.step(torch.rand(1, 12, generator=generator, dtype=torch.float64) * 2 - 1)
    assert core.sim.qvel[0, 3:6].any() and core.task.tick[0] % 75
    _sense(core)
    _mirrored_state(core, twin)
    # Exact where the arithmetic is sign-symmetric: positions, orientation, velocities,
    # joints, feet, contacts, drift, and the ground under the feet.
    for name in ("sensors", "lateral_offset", "heights", "heights_under_feet"):
        want = apply(core.observations.mirror(name), core.piece(name))
        assert torch.equal(twin.piece(name), want), name
    # The gait's sin, cos half a cycle on: the same up to rounding of exactmath's sin, cos.
    want = apply(core.observations.mirror("phase"), core.piece("phase"))
    torch.testing.assert_close(twin.piece("phase"), want, rtol=0, atol=1e-15)


def test_the_augmentation_mirrors_every_group_and_the_actions():
    config = EnvConfig(model_path=FLAT, settle_steps=2, observation_noise=ObservationNoise(),
                       randomization=Randomization(), terrain_levels=None)  # fmt: skip
    env = RslRlVecEnv(BatchedEnv(3, config, seed=0))
    obs = env.get_observations()
    actions = torch.randn(3, 12)
    both, both_actions = augment(env, obs, actions)
    assert both.batch_size == torch.Size([6]) and both_actions.shape == (6, 12)
    assert torch.equal(both[:3]["critic"], obs["critic"])
    assert torch.equal(both[3:]["critic"], apply(env.mirror("critic"), obs["critic"]))
    assert torch.equal(both_actions[3:], apply(mirrors.RESIDUALS, actions))
    only_actions = augment(env, None, actions)
    assert only_actions[0] is None and torch.equal(only_actions[1], both_actions)


def test_a_piece_without_a_mirror_is_named():
    from rwalk.observations import ObsPiece
    from rwalk.tasks.residual_walk import ResidualWalk

    class Blurry(ResidualWalk):
        name = "blurry"

        @classmethod
        def pieces(cls):
            return super().pieces() | {"blur": ObsPiece(1, lambda s: s.sensors[:, :1], "blur")}

    core = Core(EnvConfig(model_path=FLAT, settle_steps=0), 1, task=Blurry)
    with pytest.raises(ValueError, match="piece 'blur' declares no mirror"):
        core.observations.mirror("blur")


def test_flat_tiles_are_a_kind_of_their_own():
    levels = TerrainLevels(kinds=("flat", "rough", "slopes", "steps", "stones"))
    core = Core(EnvConfig(settle_steps=0, terrain_levels=levels), 10)
    assert (core.terrain_kind == 0).sum() == 2  # a fifth of the envs


def test_mirrored_states_walk_mirrored_under_mirrored_actions():
    """The dynamics keep the symmetry up to rounding (contacts and the solver's warmstart
    are not sign-symmetric to the last bit): 30 steps later, 1e-9 at most."""
    config = EnvConfig(model_path=FLAT, settle_steps=20, randomize=True)
    core, twin = Core(config, 1, seed=3), Core(config, 1, seed=4)
    core.reset()
    twin.reset()
    generator = torch.Generator().manual_seed(0)
    for _ in range(37):
        core.step(torch.rand(1, 12, generator=generator, dtype=torch.float64) * 2 - 1)
    _sense(core)
    _mirrored_state(core, twin)
    mirror = core.observations.mirror("sensors")
    for _ in range(30):
        action = torch.rand(1, 12, generator=generator, dtype=torch.float64) * 2 - 1
        want = apply(mirror, core.step(action).obs)
        got = twin.step(apply(mirrors.RESIDUALS, action)).obs
        torch.testing.assert_close(got, want, rtol=0, atol=1e-9)

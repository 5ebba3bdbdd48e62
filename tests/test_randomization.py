"""Per-env physics, pushes, latency and observation noise (rwalk.randomization)."""

from __future__ import annotations

import math
import pickle

import numpy as np
import pytest
import torch

from rwalk import EnvConfig
from rwalk.constants import FOOT_GEOMS, GROUND_GEOM, JOINT_NAMES, OBS_CONTACT, TORSO_BODY
from rwalk.core import Core
from rwalk.observations import ObservationNoise
from rwalk.perturbations import Pushes
from rwalk.randomization import NOMINAL_PARAMS, PHYSICS_PARAMS, Randomization

FAST = dict(settle_steps=10, model_path="model/world_flat.xml")


def core(n=4, seed=0, **kw):
    c = Core(EnvConfig(**(FAST | kw)), n, seed=seed)
    c.reset()
    return c


@pytest.mark.parametrize(
    "make, field",
    [
        (lambda: Randomization(friction=(1.0, 0.5)), "friction has min > max"),
        (lambda: Randomization(friction=(-0.1, 0.5)), "friction must be >= 0"),
        (lambda: Randomization(kp_scale=(0.0, 1.0)), "kp_scale must be > 0"),
        (lambda: Randomization(force_scale=(-1.0, 1.0)), "force_scale must be > 0"),
        (lambda: Randomization(damping_scale=(-0.5, 1.0)), "damping_scale must be >= 0"),
        (lambda: Randomization(latency=(0.5, 1)), "latency must be a pair of integers"),
        (lambda: Randomization(payload=(0.1, float("nan"))), "payload must be a pair"),
        (lambda: Pushes(interval=(0.0, 1.0)), "Pushes.interval must be > 0"),
        (lambda: Pushes(speed=(-0.1, 0.1)), "Pushes.speed must be >= 0"),
        (lambda: Pushes(speed=(0.2, 0.1)), "Pushes.speed has min > max"),
        (lambda: Pushes(force=(-0.1, 1.0)), "Pushes.force must be >= 0"),
        (lambda: Pushes(force=(0.0, float("inf"))), "Pushes.force must be a pair of finite"),
        (lambda: Pushes(force=(1.0, 0.5)), "Pushes.force has min > max"),
        (lambda: Pushes(force=(0.0, 6.0)), "Pushes.force must be at most 5 N, got .0.0, 6.0."),
        (lambda: ObservationNoise(joint_vel=-0.1), "ObservationNoise.joint_vel must be a scale"),
        (
            lambda: ObservationNoise(torso_forward_speed=-0.1),
            "ObservationNoise.torso_forward_speed must be a scale",
        ),
        (lambda: EnvConfig(pushes=(1.0, 2.0)), "EnvConfig.pushes must be a Pushes"),
    ],
)
def test_bad_ranges_name_the_field(make, field):
    with pytest.raises((ValueError, TypeError), match=field.replace("(", r"\(")):
        make()


def test_payload_and_latency_checked_against_the_robot():
    with pytest.raises(ValueError, match=r"payload \(-0.6, 0.0\) leaves the torso"):
        Core(EnvConfig(**FAST, randomization=Randomization(payload=(-0.6, 0.0))), 1)
    with pytest.raises(ValueError, match=r"latency .* exceeds one control period"):
        Core(EnvConfig(**FAST, randomization=Randomization(latency=(0, 6))), 1)


def test_drawn_physics_reach_each_simulation():
    c = core(n=3, seed=5, randomization=Randomization())
    model = c.model
    torso = model.body(TORSO_BODY).id
    dofs = [int(model.joint(name).dofadr[0]) for name in JOINT_NAMES]
    rand = Randomization()
    for i in range(3):
        friction, payload, cx, cy, kp, force, damping, armature, latency = c.physics.params[i]
        for low_high, value in zip(
            (rand.friction, rand.payload, rand.com_offset, rand.com_offset, rand.kp_scale,
             rand.force_scale, rand.damping_scale, rand.armature_scale),
            (friction, payload, cx, cy, kp, force, damping, armature),
            strict=True,
        ):  # fmt: skip
            assert low_high[0] <= float(value) <= low_high[1]
        assert rand.latency[0] <= int(latency) <= rand.latency[1]
        assert int(c.physics.latency[i]) == int(latency)
        sim = c.sim.batch.get_model(i)
        for geom in (GROUND_GEOM, *FOOT_GEOMS):
            assert sim.geom(geom).friction[0] == float(friction)
        assert sim.body_mass[torso] == model.body_mass[torso] + float(payload)
        assert sim.body_ipos[torso, 0] == model.body_ipos[torso, 0] + float(cx)
        assert sim.body_ipos[torso, 1] == model.body_ipos[torso, 1] + float(cy)
        assert np.array_equal(sim.actuator_gainprm[:, 0], model.actuator_gainprm[:, 0] * float(kp))
        assert np.array_equal(sim.actuator_biasprm[:, 1], model.actuator_biasprm[:, 1] * float(kp))
        assert np.array_equal(sim.actuator_forcerange, model.actuator_forcerange * float(force))
        assert np.array_equal(sim.dof_damping[dofs], model.dof_damping[dofs] * float(damping))
        assert np.array_equal(sim.dof_armature[dofs], model.dof_armature[dofs] * float(armature))
        # set_const followed the mass: the subtree mass of the world holds the payload
        assert sim.body_subtreemass[0] == pytest.approx(model.body_subtreemass[0] + float(payload))
    assert len({tuple(p.tolist()) for p in c.physics.params}) == 3  # each env its own


@pytest.mark.parametrize("row", [p for p in PHYSICS_PARAMS if p.targets], ids=lambda p: p.name)
def test_each_row_of_the_physics_table_writes_its_model_fields(row):
    """The table's own test: a drawn value shows in every model field its row targets."""
    c = core(n=2, seed=1, randomization=Randomization())
    column = PHYSICS_PARAMS.index(row)
    model = c.model
    for i in range(2):
        value = float(c.physics.params[i, column])
        low, high = getattr(Randomization(), row.range)
        assert low <= value <= high and value != row.nominal
        sim = c.sim.batch.get_model(i)
        for target in row.targets:
            index = target.select(model)
            nominal = np.asarray(getattr(model, target.field))[index]
            want = {"set": np.full_like(nominal, value), "add": nominal + value,
                    "scale": nominal * value}[row.op]  # fmt: skip
            assert np.array_equal(np.asarray(getattr(sim, target.field))[index], want)
    assert Randomization.nominal() == Randomization(
        **{p.range: (p.nominal, p.nominal) for p in PHYSICS_PARAMS}
    )


def test_fixed_values_and_a_new_draw_at_each_reset():
    c = core(n=2, randomization=Randomization.nominal(friction=(0.3, 0.3), payload=(0.2, 0.2)))
    expected = torch.tensor(NOMINAL_PARAMS, dtype=torch.float64)
    expected[0], expected[1] = 0.3, 0.2
    assert torch.equal(c.physics.params, expected.repeat(2, 1))
    r = core(n=2, randomization=Randomization())
    before = r.physics.params.clone()
    r.reset(np.array([1]))
    assert torch.equal(r.physics.params[0], before[0])
    assert not torch.equal(r.physics.params[1], before[1])


def test_narrowed_ranges_reach_new_episodes_only():
    c = core(n=2, randomization=Randomization())
    before = c.physics.params.clone()
    c.physics.set_ranges(Randomization.nominal())
    c.reset(np.array([1]))
    assert torch.equal(c.physics.params[0], before[0])  # a running episode keeps its physics
    assert torch.equal(c.physics.params[1], torch.tensor(NOMINAL_PARAMS, dtype=torch.float64))
    assert c.physics.latency[1] == 0 and c.physics.randomization == Randomization.nominal()
    with pytest.raises(ValueError, match=r"payload \(-0.6, 0.0\) leaves the torso"):
        c.physics.set_ranges(Randomization(payload=(-0.6, 0.0)))
    with pytest.raises(ValueError, match="built without physics randomisation"):
        core(n=1).physics.set_ranges(Randomization.nominal())


def test_nominal_randomization_changes_no_bit():
    plain = core(n=2, seed=3)
    nominal = core(n=2, seed=3, randomization=Randomization.nominal())
    for _ in range(20):
        a = torch.rand(2, 12, generator=torch.Generator().manual_seed(_)) * 2 - 1
        assert torch.equal(plain.step(a).obs, nominal.step(a).obs)


def test_env_i_draws_like_a_batch_seeded_s_plus_i_at_any_thread_count():
    kw = dict(randomization=Randomization(), pushes=Pushes(interval=(0.05, 0.1), force=(0, 1)))
    batch = core(n=4, seed=10, num_threads=2, **kw)
    alone = core(n=1, seed=12, num_threads=1, **kw)
    assert torch.equal(batch.physics.params[2], alone.physics.params[0])
    assert torch.equal(batch.pushes.force[2], alone.pushes.force[0])
    other = core(n=4, seed=10, num_threads=1, **kw)
    zeros = torch.zeros(4, 12)
    for _ in range(15):
        assert torch.equal(batch.step(zeros).obs, other.step(zeros).obs)
        alone.step(torch.zeros(1, 12))
    assert batch.pushes.done > 0
    assert torch.equal(batch.obs[2], alone.obs[0])


def test_latency_delays_the_targets_by_whole_substeps():
    c = core(n=3, randomization=Randomization.nominal(latency=(0, 5)))
    c.physics.latency[:] = torch.tensor([0, 2, 5])
    k = c.decimation
    previous = np.arange(3 * k * 12, dtype=np.float64).reshape(3, k, 12)
    current = -previous - 1.0
    c.physics.delay(previous)  # held: this period's targets
    applied = c.physics.delay(current)
    assert np.array_equal(applied[0], current[0])
    assert np.array_equal(applied[1], np.concatenate((previous[1, k - 2 :], current[1, : k - 2])))
    assert np.array_equal(applied[2], previous[2])


def test_a_push_changes_the_torso_velocity_by_the_drawn_kick():
    speed = 0.2
    c = core(n=3, pushes=Pushes(speed=(speed, speed), interval=(0.02, 0.02)))
    before = np.array(c.sim.qvel[:, :2])
    kick = c.pushes.kick.clone()
    c.pushes.before_step()  # every env is due: one control step per interval
    assert np.array_equal(c.sim.qvel[:, :2], before + kick.numpy())
    assert torch.allclose(kick.norm(dim=-1), torch.full((3,), speed, dtype=torch.float64))
    assert c.pushes.done == 3
    assert not torch.equal(c.pushes.kick, kick)  # the next kick is a new draw


def test_a_force_range_leaves_the_kicks_as_they_were():
    kicks = core(n=3, pushes=Pushes()).pushes.kick
    assert torch.equal(core(n=3, pushes=Pushes(force=(0.5, 1.0))).pushes.kick, kicks)


def test_each_episode_draws_its_steady_force_within_the_range():
    c = core(n=200, pushes=Pushes(force=(0.5, 1.5)))
    size = c.pushes.force.norm(dim=-1)
    assert bool((size >= 0.5 - 1e-12).all() and (size <= 1.5 + 1e-12).all())
    angle = torch.atan2(c.pushes.force[:, 1], c.pushes.force[:, 0])
    assert bool((torch.histc(angle, bins=4, min=-math.pi, max=math.pi) > 30).all())
    first = c.pushes.force.clone()
    c.reset(np.array([0, 1]))
    assert not torch.equal(c.pushes.force[:2], first[:2])  # a new episode, a new draw
    assert torch.equal(c.pushes.force[2:], first[2:])
    assert not core(n=2, pushes=Pushes()).pushes.force.any()  # (0, 0): none


def test_the_steady_force_pushes_the_robot_by_f_over_m():
    """In the air (no contact), the steady force F on the torso changes the whole robot's
    momentum by F t over a step of t = 20 ms: its centre of mass's velocity by F t / M
    against the same robot without it. The force stays on through the step's substeps."""
    import mujoco

    f = np.array([0.6, -0.3])
    moved = []
    for force in (f, np.zeros(2)):
        c = core(n=1, pushes=Pushes(speed=(0.0, 0.0), force=(0.5, 0.5)))
        c.pushes.force[:] = torch.from_numpy(force)
        c.sim.qpos[0, 2] += 1.0  # lifted a metre: no contact during the step
        c.step(torch.zeros(1, 12))
        data = mujoco.MjData(c.model)
        mujoco.mj_setState(c.model, data, c.sim.state[0], mujoco.mjtState.mjSTATE_INTEGRATION)
        assert np.array_equal(data.xfrc_applied[c.model.body(TORSO_BODY).id, :2], force)
        mujoco.mj_forward(c.model, data)
        mujoco.mj_subtreeVel(c.model, data)
        moved.append(data.subtree_linvel[0, :2].copy())
    mass = float(c.model.body_subtreemass[0])
    expected = f * c.control_dt / mass
    # Within 1%, not to the bit: the integrator conserves momentum only to its step's
    # order while the legs swing (measured 0.07% here); a force on for one substep of the
    # step's five would be 80% off.
    assert np.allclose(moved[0] - moved[1], expected, rtol=0.01, atol=0)


def test_pushes_at_their_interval():
    c = core(n=2, pushes=Pushes(speed=(0.1, 0.1), interval=(0.1, 0.1)))  # every 5 steps
    for _ in range(20):
        c.step(torch.zeros(2, 12))
    assert c.pushes.done == 2 * 4


def test_noise_on_the_policy_group_only():
    from rwalk import ResidualWalkVecEnv
    from rwalk.wrappers import RslRlVecEnv

    noise = ObservationNoise()
    cfg = EnvConfig(**FAST, observation_noise=noise, randomization=Randomization())
    env = RslRlVecEnv(ResidualWalkVecEnv(3, cfg, seed=1))
    assert env.groups["critic"] == ("observation", "phase", "lateral_offset", "physics", "heights")
    obs = env.get_observations()
    exact = env.core.piece("observation").float()
    policy, critic = obs["policy"], obs["critic"]
    assert torch.equal(critic[:, :65], exact)
    difference = (policy[:, :65] - exact).abs()
    scales = noise.sensor_scales().float()
    assert bool((difference <= scales + 1e-6).all()) and bool(difference.any())
    assert torch.equal(policy[:, OBS_CONTACT], exact[:, OBS_CONTACT])
    assert torch.equal(env.get_observations()["policy"], policy)  # one draw per step
    env.step(torch.zeros(3, 12))
    assert not torch.equal(env.get_observations()["policy"][:, :7], policy[:, :7])
    again = RslRlVecEnv(ResidualWalkVecEnv(3, cfg, seed=1)).get_observations()
    assert torch.equal(again["policy"], policy)  # the seed fixes the noise


def test_forward_speed_noise_alone():
    """The torso velocity's x gets torso_forward_speed's half-width, y and z torso_linvel's;
    unset, x gets torso_linvel's too. The cycle speed (a forward speed) follows x."""
    from rwalk.observations import COMMON_PIECES

    default = ObservationNoise().sensor_scales()
    assert default[7:10].tolist() == [0.015, 0.015, 0.015]
    scales = ObservationNoise(torso_forward_speed=0.045).sensor_scales()
    assert scales[7:10].tolist() == [0.045, 0.015, 0.015]
    assert torch.equal(scales[10:], default[10:]) and torch.equal(scales[:7], default[:7])
    cycle = COMMON_PIECES["cycle_speed"].noise
    assert cycle(ObservationNoise(torso_forward_speed=0.04)) == 0.01
    assert cycle(ObservationNoise(torso_linvel=0.04)) == 0.01


def test_env_i_sees_the_noise_of_a_single_env_seeded_s_plus_i():
    """Noise keyed per env: env 1 of a batch of 7 seeded 3 and env 0 of a batch of 2 seeded 4
    (and a single env seeded 4) see the same noisy policy group, step after step."""
    from rwalk import ResidualWalkVecEnv
    from rwalk.wrappers import RslRlVecEnv

    cfg = EnvConfig(**FAST, observation_noise=ObservationNoise())
    envs = [RslRlVecEnv(ResidualWalkVecEnv(n, cfg, seed=s)) for n, s in ((7, 3), (2, 4), (1, 4))]
    rows = (1, 0, 0)
    for _ in range(6):
        policies = [
            env.get_observations()["policy"][row] for env, row in zip(envs, rows, strict=True)
        ]
        assert torch.equal(policies[0], policies[1]) and torch.equal(policies[0], policies[2])
        for env in envs:
            env.step(torch.zeros(env.num_envs, 12))


def test_physics_piece_is_centred_and_scaled():
    c = core(n=1, randomization=Randomization.nominal(friction=(0.5, 0.5), latency=(2, 2)))
    piece = c.piece("physics")[0]
    assert piece[0].item() == pytest.approx((0.5 - 0.9) / 0.4)
    assert piece[8].item() == pytest.approx(1.0)
    assert piece[4].item() == 0.0


def test_pickled_core_continues_identically():
    kw = dict(randomization=Randomization(), pushes=Pushes(interval=(0.05, 0.2), force=(0, 1)))
    c = core(n=2, **kw)
    copy = pickle.loads(pickle.dumps(c))
    assert torch.equal(copy.pushes.force, c.pushes.force)
    assert torch.equal(copy.physics.params, c.physics.params)
    for _ in range(10):
        assert torch.equal(c.step(torch.zeros(2, 12)).obs, copy.step(torch.zeros(2, 12)).obs)


def test_terrain_scale_refused_with_per_env_physics():
    c = Core(EnvConfig(settle_steps=0, randomization=Randomization()), 1)
    with pytest.raises(ValueError, match="set_terrain_scale cannot change the ground"):
        c.set_terrain_scale(0.5)


def test_kick_direction_is_uniform_on_the_circle():
    c = core(n=400, pushes=Pushes(speed=(1.0, 1.0)))
    angle = torch.atan2(c.pushes.kick[:, 1], c.pushes.kick[:, 0])
    quadrants = torch.histc(angle, bins=4, min=-math.pi, max=math.pi)
    assert bool((quadrants > 60).all())

"""Bit-exactness: env i of a batch steps like a single env, on any CPU.

The hard-coded bit patterns below were computed once (float.hex); a CPU whose
vector kernels rounded differently would fail them. The subprocess tests rerun
the same computations under torch's other CPU kernel sets (ATEN_CPU_CAPABILITY).
"""

import dataclasses
import json
import math
import os
import subprocess
import sys

import mpmath
import pytest
import torch

from rwalk import EnvConfig, ResidualWalkCore, exactmath
from rwalk.gait import BezierGaitController
from rwalk.kinematics import LegGeometry, leg_ik
from rwalk.rewards import TERM_NAMES

F64 = torch.float64
# Rough world, short settles, perturbed starts, one physics thread.
CONFIG = dataclasses.replace(EnvConfig(), settle_steps=5, randomize=True, num_threads=1)


# ------------------------------------------------------------------ exactmath accuracy
def _sample(n: int, seed: int) -> torch.Tensor:
    """Random float64 values over many magnitudes, both signs."""
    gen = torch.Generator().manual_seed(seed)
    mantissa = torch.rand(n, generator=gen, dtype=F64) * 2.0 - 1.0
    exponent = torch.randint(-30, 30, (n,), generator=gen).to(F64)
    return mantissa * torch.pow(2.0, exponent)


EDGES = [0.0, -0.0, 1.0, -1.0, 0.5, -0.5, 1e-300, -1e-300, 5e-324, 1e300, -1e300]
EDGES += [math.inf, -math.inf, math.pi, -math.pi, math.pi / 2, math.pi / 4, 1.0 - 2**-53]


def _ulps(got: torch.Tensor, want: torch.Tensor) -> torch.Tensor:
    """|got - want| in units of the last place of want."""
    spacing = torch.nextafter(want.abs(), torch.tensor(math.inf, dtype=F64)) - want.abs()
    return (got - want).abs() / spacing


@pytest.mark.parametrize(
    ("name", "reference", "domain"),
    [
        ("sin", torch.sin, 1e5),
        ("cos", torch.cos, 1e5),
        ("atan", torch.atan, None),
        ("asin", torch.asin, 1.0),
        ("acos", torch.acos, 1.0),
    ],
)
def test_exactmath_matches_torch_within_a_few_ulp(name, reference, domain):
    x = _sample(100_000, seed=1)
    if domain is not None:
        x = torch.remainder(x, 2.0 * domain) - domain  # fold into [-domain, domain)
    got, want = getattr(exactmath, name)(x), reference(x)
    # 4e-16, or an ulp of the largest value (acos reaches π, whose ulp is 4.4e-16).
    assert (got - want).abs().max() <= max(4e-16, math.ulp(want.abs().max().item()))
    if name in ("sin", "cos"):
        # Near the zeros of sin and cos only the absolute error is small.
        keep = want.abs() > 1e-3
        got, want = got[keep], want[keep]
    assert _ulps(got, want).max() <= 2.5


def test_exactmath_atan2_matches_torch_in_every_quadrant():
    y, x = _sample(100_000, seed=2), _sample(100_000, seed=3)
    got, want = exactmath.atan2(y, x), torch.atan2(y, x)
    assert (got - want).abs().max() <= math.ulp(math.pi)
    assert _ulps(got, want).max() <= 2.5


def test_exactmath_is_close_to_the_true_value():
    # torch itself is off by up to an ulp: check a few points against mpmath too.
    mpmath.mp.prec = 200
    x = _sample(300, seed=4).remainder(2.0) - 1.0
    for name, fn in (("sin", mpmath.sin), ("cos", mpmath.cos), ("asin", mpmath.asin)):
        got = getattr(exactmath, name)(x).tolist()
        for value, xi in zip(got, x.tolist(), strict=True):
            true = fn(xi)
            assert abs(mpmath.mpf(value) - true) <= 1.5 * math.ulp(float(true)), (name, xi)


def _same(got: torch.Tensor, want: torch.Tensor) -> bool:
    """Equal values, signed zeros and NaNs alike."""
    nan = torch.isnan(want)
    return bool(
        torch.equal(torch.isnan(got), nan)
        and torch.equal(got[~nan], want[~nan])
        and torch.equal(torch.signbit(got[~nan]), torch.signbit(want[~nan]))
    )


@pytest.mark.parametrize("name", ["atan", "asin", "acos"])
def test_exactmath_edge_cases_match_torch(name):
    x = torch.tensor([*EDGES, math.nan, 1.5, -1.5], dtype=F64)
    got, want = getattr(exactmath, name)(x), getattr(torch, name)(x)
    # Zeros, ±1, tiny, infinite and NaN cases exactly; the others within an ulp.
    special = ~torch.isfinite(want) | (x.abs() == 1.0) | (x.abs() < 1e-200)
    assert _same(got[special], want[special])
    assert _ulps(got[~special], want[~special]).max() <= 1.0


def test_exactmath_atan2_axes_zeros_and_infinities_match_torch():
    values = torch.tensor([0.0, -0.0, 1.0, -1.0, 1e-300, 1e300, math.inf, -math.inf, math.nan])
    y, x = torch.meshgrid(values.to(F64), values.to(F64), indexing="ij")
    assert _same(exactmath.atan2(y, x), torch.atan2(y, x))


def test_exactmath_sin_cos_edges():
    x = torch.tensor([0.0, -0.0, 5e-324, -1e-300, math.inf, -math.inf, math.nan, 1e7], dtype=F64)
    for name in ("sin", "cos"):
        got, want = getattr(exactmath, name)(x), getattr(torch, name)(x)
        assert _same(got[:4], want[:4])
        assert torch.isnan(got[4:]).all()  # not finite, or beyond SIN_COS_LIMIT


# ------------------------------------------------------------------ fixed bit patterns
def _bit_patterns() -> dict[str, list[str]]:
    """Hex bits of exactmath, gait tables and an IK solution at a few inputs."""
    angles = torch.tensor([0.5, -2.75, 1.2345e-3, 123.456, 1e5], dtype=F64)
    ratios = torch.tensor([0.5, -0.75, 1.2345e-3, 0.9999, -0.3], dtype=F64)
    out = {f: [v.hex() for v in getattr(exactmath, f)(angles).tolist()] for f in ("sin", "cos")}
    out |= {f: [v.hex() for v in getattr(exactmath, f)(ratios).tolist()] for f in ("asin", "acos")}
    out["atan"] = [v.hex() for v in exactmath.atan(angles).tolist()]
    out["atan2"] = [v.hex() for v in exactmath.atan2(angles, ratios).tolist()]
    controller = BezierGaitController()
    out["table"] = [v.hex() for v in controller.target_table[217, 0].tolist()]
    out["phase"] = [v.hex() for v in controller.phase_table[37].tolist()]
    feet = controller.target_table[217] + 0.003
    out["ik"] = [v.hex() for v in leg_ik(feet, LegGeometry())[0][3].tolist()]
    return out


# Computed once with this code on an AVX-512 machine (float.hex).
PINNED = {
    "sin": [
        "0x1.eaee8744b05f0p-2",
        "-0x1.86d2239c183fbp-2",
        "0x1.439ddf1ee6f3dp-10",
        "-0x1.9b9dadc41aeb6p-1",
        "0x1.24daa9c527e96p-5",
    ],
    "cos": [
        "0x1.c1528065b7d50p-1",
        "-0x1.d93e294faed14p-1",
        "0x1.ffffe66e83366p-1",
        "-0x1.307e5980a1559p-1",
        "-0x1.ffac3841b3da7p-1",
    ],
    "asin": [
        "0x1.0c152382d7366p-1",
        "-0x1.b235315c680dcp-1",
        "0x1.439de9e503c15p-10",
        "0x1.8e80e1a01556ap+0",
        "-0x1.380159e14f6ffp-2",
    ],
    "acos": [
        "0x1.0c152382d7365p+0",
        "0x1.359d26f93b6c3p+1",
        "0x1.91cecdc9c9909p+0",
        "0x1.cf69d216bd74bp-7",
        "0x1.e0200bbc96ad8p+0",
    ],
    "atan": [
        "0x1.dac670561bb4fp-2",
        "-0x1.38d6a6ce13353p+0",
        "0x1.439dd9bbd946fp-10",
        "0x1.900cdfeb560b4p+0",
        "0x1.921f0d7e968a8p+0",
    ],
    "atan2": [
        "0x1.921fb54442d18p-1",
        "-0x1.d648cd67db72bp+0",
        "0x1.921fb54442d18p-1",
        "0x1.900ced820dbd0p+0",
        "0x1.921fe79929b3ap+0",
    ],
    "table": [
        "-0x1.a1fadc1d78681p-6",
        "0x1.89374bc6a7efap-7",
        "-0x1.c9018fc909a64p-5",
    ],
    "phase": [
        "0x1.663a45fb6e16ap-1",
        "0x1.6dcf5cf1d116ap-1",
    ],
    "ik": [
        "0x1.d41ac5ef62650p-5",
        "0x1.9806ea9baf542p+0",
        "-0x1.08e5b6abc5486p+1",
    ],
}


def test_results_have_fixed_bit_patterns():
    assert _bit_patterns() == PINNED


@pytest.mark.parametrize("capability", ["default", "avx2"])
def test_other_cpu_kernels_give_the_same_bits(capability):
    # torch picks its vector kernels by CPU; force the others and compare.
    env = dict(os.environ, ATEN_CPU_CAPABILITY=capability)
    code = "import json, tests.test_exact as t; print(json.dumps(t._bit_patterns()))"
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    done = subprocess.run(
        [sys.executable, "-c", code], env=env, cwd=root, capture_output=True, text=True, check=True
    )
    assert json.loads(done.stdout) == PINNED


# ------------------------------------------------------------------ batch-size independence
def test_ik_row_is_the_same_in_any_batch():
    gen = torch.Generator().manual_seed(0)
    feet = BezierGaitController().target_table[torch.randint(0, 300, (4097,), generator=gen)]
    feet = feet + (torch.rand(4097, 4, 3, generator=gen, dtype=F64) - 0.5) * 0.04
    joints, ok = leg_ik(feet, LegGeometry())
    for row in (0, 1, 17, 4096):
        alone, alone_ok = leg_ik(feet[row : row + 1], LegGeometry())
        assert torch.equal(alone[0], joints[row]) and torch.equal(alone_ok[0], ok[row])


def _run(num_envs: int, seed: int, steps: int, every: int | None) -> dict[str, torch.Tensor]:
    """Random-action steps of a core, resetting envs that fall and, if ``every`` is given,
    each env every ``every`` steps on a schedule of its own.

    Env i's actions and reset schedule are keyed by its own seed, seed + i.
    Returns per-step traces. Each shape: (T, N, ...).
    """
    core = ResidualWalkCore(CONFIG, num_envs, seed=seed)
    core.reset()
    env_seeds = seed + torch.arange(num_envs)
    gens = [torch.Generator().manual_seed(seed + i) for i in range(num_envs)]
    trace: dict[str, list[torch.Tensor]] = {"obs": [], "reward": [], "terminated": []}
    trace |= {name: [] for name in TERM_NAMES}
    for step in range(steps):
        action = torch.stack([torch.rand(12, generator=g, dtype=F64) * 2.0 - 1.0 for g in gens])
        result = core.step(action)
        trace["reward"].append(result.reward.clone())
        trace["terminated"].append(result.terminated.clone())
        for name, term in result.terms.items():
            trace[name].append(term.clone())
        done = result.terminated | result.truncated
        if every is not None:
            done |= (step + env_seeds) % every == 0
        if bool(done.any()):
            core.reset(done.nonzero()[:, 0])
        trace["obs"].append(core.obs.clone())  # after any reset
    return {name: torch.stack(values) for name, values in trace.items()}


def _check_envs_step_like_single_envs(
    num_envs: int,
    steps: int,
    envs: list[int],
    seed: int = 11,
    falls: bool = False,
    every: int | None = None,
):
    batch = _run(num_envs, seed, steps, every)
    if falls:
        assert batch["terminated"].any(), "no env fell: resets after falls went untested"
    for i in envs:
        single = _run(1, seed + i, steps, every)
        for name, values in single.items():
            assert torch.equal(batch[name][:, i], values[:, 0]), (num_envs, i, name)


@pytest.mark.parametrize("num_envs", [2, 7, 64])
def test_whole_episodes_are_bit_exact_at_any_batch_size(num_envs):
    # 1000 steps with resets only where an env falls: whole episodes of up to 1000 steps.
    # The last env of the batch (the slow test also checks the first of 1000).
    _check_envs_step_like_single_envs(num_envs, 1000, [num_envs - 1], falls=num_envs >= 64)


def test_partial_resets_mid_episode_keep_envs_bit_exact():
    # Each env also resets every 41 steps of its own schedule, while the others walk on.
    _check_envs_step_like_single_envs(7, 200, [0, 6], every=41)


@pytest.mark.slow
def test_whole_episodes_are_bit_exact_in_a_batch_of_1000():
    _check_envs_step_like_single_envs(1000, 1000, [0, 999], falls=True)

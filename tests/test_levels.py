"""Terrain levels: the map's tiles by hand, its world model, and the bilinear ground lookup."""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np
import pytest
import torch

from rwalk.levels import (
    KNOWN_KINDS,
    TerrainLevels,
    build_model,
    generate,
    hfield_encoding,
    tile_heights,
    update_levels,
)
from rwalk.terrain import Terrain

# 3 levels (d = 0, 0.5, 1); tiles 2 m x 0.5 m = 40 x 10 cells of 5 cm; border 4 cells.
SMALL = TerrainLevels(
    levels=3,
    tile_length=2.0,
    tile_width=0.5,
    pad_length=0.4,
    cell=0.05,
    border=0.2,
    taper=0.1,
    stone_size=0.15,
    stone_gap=0.1,
)
MID_ROW = 5  # y = 0.25 m: the tile's centre line, no taper


@pytest.fixture(scope="module")
def small_map():
    return generate(SMALL)


@pytest.fixture(scope="module")
def small_world():
    return build_model("model/world_train.xml", SMALL)


def test_level_0_is_flat():
    for kind in KNOWN_KINDS:
        assert not tile_heights(SMALL, 0, kind).any(), kind


def test_slope_rises_at_d_times_slope():
    # column 20: x = 1.0 m, 0.6 m past the pad, up the ramp (run 1.6 m, peak at 0.8 m)
    for level, d in ((1, 0.5), (2, 1.0)):
        tile = tile_heights(SMALL, level, "slopes")
        assert tile[MID_ROW, 20] == pytest.approx(d * 0.12 * 0.6, abs=1e-12)
        # and down again: 0.2 m before the tile's end (x = 1.8 m)
        assert tile[MID_ROW, 36] == pytest.approx(d * 0.12 * 0.2, abs=1e-12)


def test_steps_rise_by_d_times_step_height():
    tile = tile_heights(SMALL, 2, "steps")
    # 0.1 m past the pad: first tread at 0; 0.3 m: one step (2 cm); 0.6 m: two steps
    assert tile[MID_ROW, 10] == 0.0
    assert tile[MID_ROW, 14] == pytest.approx(0.02, abs=1e-12)
    assert tile[MID_ROW, 20] == pytest.approx(0.04, abs=1e-12)
    assert tile_heights(SMALL, 1, "steps")[MID_ROW, 20] == pytest.approx(0.02, abs=1e-12)


def first_gap(row: np.ndarray) -> tuple[int, int]:
    """(first column below 0, how many columns in a row are below 0 there)."""
    low = np.flatnonzero(row < 0)
    start = int(low[0])
    width = 0
    while row[start + width] < 0:
        width += 1
    return start, width


def test_stone_gaps_are_whole_cells():
    # stones 3 cells (0.15 m); gaps round(d * 0.1 m / 0.05 m): 1 cell at d = 0.5, 2 at d = 1.
    # The pad ends at column 8 (x = 0.4 m): stones on columns 9..11, the first gap from 12.
    for level, width in ((1, 1), (2, 2)):
        tile = tile_heights(SMALL, level, "stones")
        assert first_gap(tile[MID_ROW]) == (12, width)
        assert tile[MID_ROW, 12] == -0.05  # full gap_depth away from the edges
    tiny = dataclasses.replace(SMALL, stone_gap=0.02)  # 0.02 / 0.05 = 0.4 cells: no gaps
    assert not tile_heights(tiny, 2, "stones").any()


def test_gap_ramp_deepens_one_cell_gaps_level_by_level():
    # With the ramp, stones have gaps from level 1: round(0.5 * 0.04 / 0.05) = 0 cells
    # without it (flat stones), at least 1 with it, d * gap_depth deep: 0.5 * 0.05 at
    # level 1 of 3; level 2 (d = 1) is the full depth and round(0.04 / 0.05) = 1 cell.
    ramp = dataclasses.replace(SMALL, stone_gap=0.04, gap_ramp=True)
    assert not tile_heights(dataclasses.replace(ramp, gap_ramp=False), 1, "stones").any()
    for level, depth in ((1, 0.025), (2, 0.05)):
        tile = tile_heights(ramp, level, "stones")
        assert first_gap(tile[MID_ROW]) == (12, 1)
        assert tile[MID_ROW, 12] == -depth
        assert tile.min() == -depth
    assert not tile_heights(ramp, 0, "stones").any()  # level 0 stays flat
    with pytest.raises(ValueError, match="gap_ramp must be a bool, got 'yes'"):
        TerrainLevels(gap_ramp="yes")


def test_rough_is_smooth_noise_of_d_times_roughness():
    tile = tile_heights(SMALL, 2, "rough")
    assert 0.5 * 0.07 < np.ptp(tile) <= 0.07
    assert np.ptp(tile_heights(SMALL, 1, "rough")) <= 0.035


def test_map_layout_and_pads(small_map):
    # rows: 2 * 4 + 3 * 10 + 1; cols: 2 * 4 + 4 * 40 + 1
    assert small_map.heights.shape == (39, 169)
    assert small_map.heights.dtype == np.float64
    assert (small_map.size_x, small_map.size_y) == pytest.approx((8.4, 1.9))
    # pad centre of tile (0, 0): x = -4.2 + 0.2 + 0.2, y = -0.95 + 0.2 + 0.25
    assert small_map.origin(0, 0) == pytest.approx((-3.8, -0.5))
    assert small_map.origin(2, 3) == pytest.approx((-3.8 + 3 * 2.0, -0.5 + 2 * 0.5))
    # every pad (columns 0..8 of each tile) is at height 0
    for k in range(4):
        c0 = 4 + 40 * k
        assert not small_map.heights[:, c0 : c0 + 9].any()


def test_origins_match_origin(small_map):
    levels = np.array([0, 1, 2, 2, 0])
    kinds = np.array([0, 3, 1, 2, 3])
    both = small_map.origins(levels, kinds)
    assert both.shape == (5, 2)
    for i in range(5):
        assert tuple(both[i]) == small_map.origin(int(levels[i]), int(kinds[i]))
    with pytest.raises(ValueError, match="outside the map"):
        small_map.origins(np.array([3]), np.array([0]))
    with pytest.raises(ValueError, match="kind index 4"):
        small_map.origin(0, 4)


def test_tiles_join_at_zero(small_map):
    h = small_map.heights
    for c in range(4, 169, 40):  # tile edges along x
        assert not h[:, c].any()
    for r in range(4, 39, 10):  # band edges along y
        assert not h[r, :].any()
    assert not h[:4].any() and not h[-4:].any() and not h[:, :4].any() and not h[:, -4:].any()
    # the taper keeps neighbouring samples close: no cliff next to an edge
    assert np.abs(np.diff(h, axis=0)).max() < 0.06


def test_same_seed_same_map_new_seed_new_rough():
    again = generate(SMALL).heights
    assert np.array_equal(generate(SMALL).heights, again)
    other = dataclasses.replace(SMALL, seed=1)
    assert not np.array_equal(tile_heights(other, 2, "rough"), tile_heights(SMALL, 2, "rough"))
    assert np.array_equal(tile_heights(other, 2, "slopes"), tile_heights(SMALL, 2, "slopes"))
    # a tile does not depend on the map around it
    alone = dataclasses.replace(SMALL, kinds=("rough",), levels=3)
    assert np.array_equal(tile_heights(alone, 2, "rough"), tile_heights(SMALL, 2, "rough"))


def test_build_model_reads_back_the_map(small_world):
    model, terrain_map = small_world
    h = terrain_map.heights
    terrain = Terrain(model)
    assert terrain.heights.shape == h.shape
    assert terrain.size[:2] == pytest.approx((4.2, 0.95))
    assert terrain.origin == pytest.approx((0.0, 0.0, h.min()), abs=1e-9)
    assert model.geom("floor").pos[2] == terrain.origin[2]
    world = terrain.origin[2] + terrain.size[2] * terrain.heights
    span = h.max() - h.min()
    assert np.abs(world - h).max() <= span * 2.0**-23
    assert np.array_equal(world == 0.0, h == 0.0)  # height 0 is exact
    pads = terrain_map.origins(np.repeat(np.arange(3), 4), np.tile(np.arange(4), 3))
    assert not terrain.max_height(pads[:, 0], pads[:, 1], 0.05).any()
    under = terrain.heights_at(torch.from_numpy(pads[:, 0]), torch.from_numpy(pads[:, 1]))
    assert not under.any()


def test_build_model_needs_a_terrain_hfield():
    with pytest.raises(ValueError, match=r"world_flat\.xml.*'terrain'"):
        build_model("model/world_flat.xml", SMALL)


def test_hfield_encoding_limits():
    heights = np.array([[-0.03, 0.0, 0.01], [0.1 / 3, 0.0, 0.07]])
    samples, base, span = hfield_encoding(heights)
    assert samples.dtype == np.float32 and samples.min() == 0.0 and samples.max() == 1.0
    back = base + span * samples.astype(np.float64)
    assert back[0, 1] == 0.0 and back[1, 1] == 0.0
    assert np.abs(back - heights).max() <= 0.1 * 2.0**-23
    flat, base, span = hfield_encoding(np.zeros((2, 2)))
    assert not flat.any() and base == 0.0 and span > 0


GRID_WORLD = """
<mujoco>
  <asset>
    <hfield name="t" nrow="3" ncol="3" size="1 1 2 0.1"
            elevation="0.75 0.25 0.5  0.5 1 0  0 0.25 0.5"/>
  </asset>
  <worldbody>
    <geom name="ground" type="hfield" hfield="t" pos="0.5 0 0.25"/>
  </worldbody>
</mujoco>
"""


def test_heights_at_bilinear_on_a_known_grid():
    terrain = Terrain(mujoco.MjModel.from_xml_string(GRID_WORLD))
    # MuJoCo reads the elevation's first row as the +y edge, as in an image
    grid = np.array([[0, 0.25, 0.5], [0.5, 1, 0], [0.75, 0.25, 0.5]])
    assert np.array_equal(terrain.heights, grid)  # samples at x = -0.5, 0.5, 1.5; y = -1, 0, 1
    # (0, -0.5): halfway between rows 0, 1 and columns 0, 1: mean 0.4375 -> 0.25 + 2 * 0.4375
    # (1.25, 0): row 1, 3/4 from column 1 (1) to column 2 (0): 0.25 -> 0.25 + 2 * 0.25
    # (5, -7): beyond the map, clamped to its corner row 0, column 2: 0.5 -> 1.25
    x = torch.tensor([0.0, 1.25, 5.0], dtype=torch.float64)
    y = torch.tensor([-0.5, 0.0, -7.0], dtype=torch.float64)
    assert terrain.heights_at(x, y).tolist() == [1.125, 0.75, 1.25]
    xs, ys = torch.meshgrid(
        torch.tensor([-0.5, 0.5, 1.5], dtype=torch.float64),
        torch.tensor([-1.0, 0.0, 1.0], dtype=torch.float64),
        indexing="xy",
    )
    exact = terrain.heights_at(xs, ys)
    assert exact.shape == (3, 3) and exact.dtype == torch.float64
    assert torch.equal(exact, torch.from_numpy(0.25 + 2.0 * grid))


def test_heights_at_on_a_plane():
    plane = mujoco.MjModel.from_xml_string(
        '<mujoco><worldbody><geom name="ground" type="plane" size="1 1 0.1" pos="0 0 0.3"/>'
        "</worldbody></mujoco>"
    )
    out = Terrain(plane).heights_at(torch.zeros(2, 3), torch.ones(2, 3))
    assert out.shape == (2, 3) and torch.all(out == 0.3)


def test_update_levels():
    levels = torch.tensor([0, 1, 1, 1, 2, 0])
    expected = torch.full((6,), 2.0)
    distance = torch.tensor([1.8, 1.6, 1.0, 0.6, 2.0, 0.1])  # 0.9, 0.8, 0.5, 0.3, 1.0, 0.05
    fell = torch.tensor([False, False, False, False, True, False])
    after = update_levels(levels, distance, expected, fell, SMALL)
    assert after.tolist() == [1, 2, 1, 0, 1, 0]  # up, up, stay, down, fell: down, clamped at 0
    top = update_levels(
        torch.tensor([2]), torch.tensor([2.0]), torch.tensor([2.0]), torch.tensor([False]), SMALL
    )
    assert top.tolist() == [2]  # clamped at the top level
    frozen = dataclasses.replace(SMALL, curriculum=False)
    assert torch.equal(update_levels(levels, distance, expected, fell, frozen), levels)


def test_update_levels_stops_at_each_env_s_floor():
    levels = torch.tensor([1, 2, 1, 1])
    distance = torch.tensor([2.0, 0.1, 2.0, 1.8])  # of 2 m: 1.0, 0.05, 1.0, 0.9
    fell = torch.tensor([True, False, True, False])
    floor = torch.tensor([1, 1, 0, 1])
    after = update_levels(levels, distance, torch.full((4,), 2.0), fell, SMALL, floor=floor)
    assert after.tolist() == [1, 1, 0, 2]  # fell: held at 1; short: 2 to 1; fell to 0; up


def test_check_level():
    SMALL.check_level(2)
    for level in (-1, 3):
        with pytest.raises(ValueError, match=f"level {level} is a terrain level outside the map"):
            SMALL.check_level(level)


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("levels", 0, "levels"),
        ("levels", 2.0, "levels"),
        ("kinds", (), "kinds"),
        ("kinds", ("rough", "ice"), r"kinds \('rough', 'ice'\): unknown kind 'ice'"),
        ("kinds", ("rough", "rough"), "kinds must not repeat"),
        ("seed", -1, "seed"),
        ("seed", 1.5, "seed"),
        ("tile_length", 0.0, "tile_length"),
        ("tile_length", 6.01, "tile_length must be a whole number of cells"),
        ("tile_width", -1.0, "tile_width"),
        ("cell", 0.0, "cell"),
        ("pad_length", 6.0, "pad_length"),
        ("border", -0.1, "border"),
        ("roughness", -0.01, "roughness"),
        ("slope", -0.1, "slope"),
        ("step_height", -0.02, "step_height"),
        ("stone_gap", -0.04, "stone_gap"),
        ("gap_depth", -0.05, "gap_depth"),
        ("start_level", 10, "start_level 10 is a terrain level outside the map"),
        ("start_level", -1, "start_level -1 is a terrain level outside the map"),
        ("promote", 1.5, "promote"),
        ("demote", -0.1, "demote"),
        ("demote", 0.9, r"demote \(0.9\) must not exceed promote"),
        ("floor_kinds", ("ice",), "floor_kinds must be kinds of this map's tiles"),
        ("floor_kinds", ("stones", "stones"), "each once"),
        ("floor_kinds", "stones", "floor_kinds must be kinds"),
        ("floor_level", 10, "floor_level 10 is a terrain level outside the map"),
        ("floor_level", 3, "floor_level 3 needs floor_kinds"),
    ],
)
def test_bad_config_names_its_field(field, value, message):
    with pytest.raises(ValueError, match=message) as error:
        TerrainLevels(**{field: value})
    assert repr(value) in str(error.value)

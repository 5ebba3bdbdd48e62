"""Terrain levels: a map of difficulty bands for a terrain curriculum (legged_gym style).

The map is ``levels`` bands along y (band l holds level l, difficulty ``d = l / (levels - 1)``,
level 0 flat) by ``len(kinds)`` tiles along x (tile k holds kind k), inside a flat border.
Each env keeps one kind and moves between levels at its resets (:func:`update_levels`).

Every tile starts with a flat pad at height 0 at its -x end, where robots start and then walk
towards +x; its profile tapers linearly to 0 along all four edges (over ``taper`` metres), so
neighbouring tiles join at height 0 without cliffs. A tile's heights depend only on
(seed, level, kind) and the config, and are reproducible bit for bit from the seed.

Kinds, at difficulty d (maxima in :class:`TerrainLevels`):

- ``rough``: smooth random bumps ~10 cm apart, ``d * roughness`` peak to peak, mean 0.
- ``slopes``: one ramp up then down along x, rise over run ``d * slope``.
- ``steps``: stairs up then down along x, treads ``step_tread`` long, rise ``d * step_height``.
- ``stones``: square stones ``stone_size`` wide at height 0 with gaps ``gap_depth`` deep and
  ``round(d * stone_gap / cell)`` samples wide (none below half a cell); with ``gap_ramp``,
  gaps at least one sample wide from level 1 and ``d * gap_depth`` deep.
- ``flat``: flat at every level (not in the default map: ``kinds=("flat", *DEFAULT_KINDS)``
  keeps a fifth of the envs on flat ground, as mjlab's and legged_gym's maps keep some).

:func:`build_model` puts a map into ``model/world_train.xml``'s heightfield, with map height 0
at world z 0 and the map's centre at world (0, 0), so map coordinates are world x, y.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

import mujoco
import numpy as np
import torch

from rwalk.assets import resolve_model_path, validate_model
from rwalk.constants import FLOOR_GEOM, GROUND_GEOM, TERRAIN_HFIELD
from rwalk.terrain import CORRELATION_LENGTH, generate_heightmap

#: Most height samples of a map (the default map has 441 x 1001).
MAX_MAP_SAMPLES = 1 << 24
#: Every kind of tile, in the order that keys their random streams.
KNOWN_KINDS: tuple[str, ...] = ("rough", "slopes", "steps", "stones", "flat")
#: The kinds of the default map (a ``flat`` kind adds flat tiles at every level: with the
#: four others, a fifth of the envs walk on flat ground).
DEFAULT_KINDS: tuple[str, ...] = ("rough", "slopes", "steps", "stones")


@dataclass(frozen=True)
class TerrainLevels:
    """The map of terrain levels and the curriculum that moves envs between them."""

    levels: int = 10
    """Difficulty bands along y; level l has difficulty l / (levels - 1), level 0 flat."""
    kinds: tuple[str, ...] = DEFAULT_KINDS
    """Tiles along x, one per kind (from ``KNOWN_KINDS``); each env keeps one kind."""
    seed: int = 0
    """Map seed: a fresh seed gives a new map of the same difficulty."""
    tile_length: float = 6.0
    """x extent of a tile, m (a whole number of cells)."""
    tile_width: float = 1.0
    """y extent of a tile (one band), m (a whole number of cells)."""
    pad_length: float = 0.8
    """Flat start pad at height 0 at the -x end of each tile, m."""
    cell: float = 0.025
    """Distance between heightfield samples, m."""
    border: float = 0.5
    """Flat margin at height 0 around the tiles, m (a whole number of cells)."""
    taper: float = 0.1
    """Length over which a tile's profile blends linearly to 0 at its edges and pad, m."""
    roughness: float = 0.07
    """Peak-to-peak height of the rough tile's bumps at difficulty 1 (before the taper), m."""
    slope: float = 0.12
    """Rise over run of the ramps at difficulty 1 (dimensionless)."""
    step_height: float = 0.02
    """Rise of each stair at difficulty 1, m."""
    step_tread: float = 0.25
    """Length of each stair along x, m."""
    stone_size: float = 0.12
    """Side of the square stepping stones, m (rounded to whole cells, at least one)."""
    stone_gap: float = 0.04
    """Width of the gaps between stones at difficulty 1, m (rounded to whole cells)."""
    gap_depth: float = 0.05
    """Depth of the gaps between stones, m (at every level that has gaps)."""
    gap_ramp: bool = False
    """Stones: gaps at least one sample wide from level 1, ``d * gap_depth`` deep, so that
    the gaps deepen level by level as the other kinds' obstacles grow; False: the full
    depth wherever a gap is a sample or more wide (the default map: flat stones at levels
    0-2, gaps 5 cm deep from level 3)."""
    start_level: int = 0
    """Level of every env at its first reset."""
    curriculum: bool = True
    """Move envs between levels at their resets (False: every env stays at start_level)."""
    promote: float = 0.7
    """Walked at least this fraction of the expected distance without falling: one level up."""
    demote: float = 0.35
    """Fell, or walked less than this fraction of the expected distance: one level down."""
    recycle: bool = True
    """An env promoted beyond the top level restarts at a uniformly drawn level (legged_gym's
    rule), so that easy ground stays in the mix; False: it stays at the top."""
    review: float = 0.0
    """Share of episodes that start on a level drawn uniformly from 0 to the env's own, so that
    ground already passed stays in every batch; such an episode does not move the env's
    level. 0: every episode on the env's own level (legged_gym's rule)."""
    floor_kinds: tuple[str, ...] = ()
    """Kinds of tile whose envs never walk below ``floor_level``: they start there at the
    latest, a demotion stops there, and their redrawn and review levels are drawn from
    ``floor_level`` up (the stones' gaps begin at level 3 of the default map: envs kept on
    them practise the gaps instead of bouncing back to flat stones)."""
    floor_level: int = 0
    """The lowest level of the envs on ``floor_kinds``."""

    def __post_init__(self) -> None:
        def is_int(value: object) -> bool:
            return isinstance(value, (int, np.integer)) and not isinstance(value, bool)

        if not is_int(self.levels) or self.levels < 1:
            raise ValueError(f"levels must be an int >= 1, got {self.levels!r}")
        if not is_int(self.seed) or self.seed < 0:
            raise ValueError(f"seed must be an int >= 0, got {self.seed!r}")
        if not isinstance(self.kinds, tuple) or not self.kinds:
            raise ValueError(
                f"kinds must be a non-empty tuple of {KNOWN_KINDS}, got {self.kinds!r}"
            )
        unknown = [kind for kind in self.kinds if kind not in KNOWN_KINDS]
        if unknown:
            raise ValueError(
                f"kinds {self.kinds!r}: unknown kind {unknown[0]!r} (known: {KNOWN_KINDS})"
            )
        if len(set(self.kinds)) != len(self.kinds):
            raise ValueError(f"kinds must not repeat a kind, got {self.kinds!r}")
        for name in ("tile_length", "tile_width", "pad_length", "cell", "taper"):
            self._check_number(name, positive=True)
        for name in ("border", "step_tread", "stone_size"):
            self._check_number(name, positive=name != "border")
        for name in ("roughness", "slope", "step_height", "stone_gap", "gap_depth"):
            self._check_number(name, positive=False)
        for name in ("tile_length", "tile_width", "border"):
            value = getattr(self, name)
            if abs(value / self.cell - round(value / self.cell)) > 1e-6:
                raise ValueError(
                    f"{name} must be a whole number of cells (cell {self.cell!r}), got {value!r}"
                )
        if self.pad_length >= self.tile_length:
            raise ValueError(
                f"pad_length ({self.pad_length!r}) must be shorter than tile_length "
                f"({self.tile_length!r})"
            )
        if not is_int(self.start_level) or not 0 <= self.start_level < self.levels:
            raise ValueError(
                f"TerrainLevels.start_level {self.start_level!r} is a terrain level outside "
                f"the map (levels 0..{self.levels - 1})"
            )
        floor_kinds = self.floor_kinds if isinstance(self.floor_kinds, tuple) else None
        if (
            floor_kinds is None
            or not set(floor_kinds) <= set(self.kinds)
            or (len(set(floor_kinds)) != len(floor_kinds))
        ):
            raise ValueError(f"TerrainLevels.floor_kinds must be kinds of this map's tiles "
                             f"{self.kinds}, each once, got {self.floor_kinds!r}")  # fmt: skip
        if not is_int(self.floor_level) or not 0 <= self.floor_level < self.levels:
            raise ValueError(
                f"TerrainLevels.floor_level {self.floor_level!r} is a terrain level outside "
                f"the map (levels 0..{self.levels - 1})"
            )
        if self.floor_level and not self.floor_kinds:
            raise ValueError(f"TerrainLevels.floor_level {self.floor_level!r} needs "
                             f"floor_kinds (the kinds of tile it holds), got none")  # fmt: skip
        for name in ("curriculum", "recycle", "gap_ramp"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"{name} must be a bool, got {getattr(self, name)!r}")
        for name in ("promote", "demote", "review"):
            value = getattr(self, name)
            if not isinstance(value, (int, float)) or not 0.0 <= value <= 1.0:
                raise ValueError(f"{name} must be a fraction in [0, 1], got {value!r}")
        if self.demote > self.promote:
            raise ValueError(f"demote ({self.demote!r}) must not exceed promote ({self.promote!r})")
        rows, cols = self.shape
        if rows * cols > MAX_MAP_SAMPLES:
            raise ValueError(
                f"the map would hold {rows} x {cols} height samples (levels {self.levels!r}, "
                f"{len(self.kinds)} kinds of {self.tile_length!r} x {self.tile_width!r} m tiles, "
                f"border {self.border!r} m, cell {self.cell!r} m), more than {MAX_MAP_SAMPLES}: "
                "use fewer levels, smaller tiles or a larger cell"
            )

    @property
    def shape(self) -> tuple[int, int]:
        """(rows along y, columns along x) of the map's heightfield."""
        border = 2 * self.cells(self.border) + 1
        return (
            border + self.levels * self.cells(self.tile_width),
            border + len(self.kinds) * self.cells(self.tile_length),
        )

    def _check_number(self, name: str, positive: bool) -> None:
        value = getattr(self, name)
        ok = (
            isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
        )
        if not ok or (value <= 0 if positive else value < 0):
            bound = "> 0" if positive else ">= 0"
            raise ValueError(f"{name} must be a finite number {bound}, got {value!r}")

    def check_level(self, level: int) -> None:
        """Raise ValueError for a level outside the map (0..levels-1)."""
        if isinstance(level, bool) or not isinstance(level, (int, np.integer)):
            raise ValueError(f"level must be an int, got {level!r}")
        if not 0 <= level < self.levels:
            raise ValueError(
                f"level {level!r} is a terrain level outside the map (levels 0..{self.levels - 1})"
            )

    def difficulty(self, level: int) -> float:
        """Difficulty of a level: 0 (flat) .. 1 (the maxima in this config)."""
        self.check_level(level)
        return level / (self.levels - 1) if self.levels > 1 else 0.0

    def cells(self, length: float) -> int:
        """A length in whole cells (for lengths checked to be whole numbers of cells)."""
        return round(length / self.cell)


class TerrainMap:
    """Heights of a generated map of terrain levels (built by :func:`generate`).

    Map coordinates: metres, the map's centre at (0, 0), x along the tiles, y across the bands;
    :func:`build_model` makes them world coordinates.

    Attributes:
        heights: metres. Shape: (rows, cols), float64; row 0 is the -y edge, column 0 the -x edge.
        cell: distance between samples, m.
        size_x, size_y: extent of the map from its first to its last sample, m.
        config: the :class:`TerrainLevels` it was generated from.
    """

    def __init__(self, heights: np.ndarray, config: TerrainLevels) -> None:
        self.heights = heights
        self.config = config
        self.cell = config.cell
        rows, cols = heights.shape
        self.size_x = (cols - 1) * config.cell
        self.size_y = (rows - 1) * config.cell

    def origin(self, level: int, kind: int) -> tuple[float, float]:
        """Centre of the start pad of tile (level, kind index into ``config.kinds``), m."""
        self.config.check_level(level)
        self._check_kinds(np.asarray([kind]))
        x, y = self.origins(np.asarray([level]), np.asarray([kind]))[0]
        return float(x), float(y)

    def origins(self, levels: np.ndarray, kinds: np.ndarray) -> np.ndarray:
        """Centres of the start pads of many tiles, m.

        Shape: (M,), (M,) -> (M, 2); ``kinds`` are indices into ``config.kinds``.
        """
        cfg = self.config
        levels, kinds = np.asarray(levels), np.asarray(kinds)
        if levels.shape != kinds.shape:
            raise ValueError(f"levels {levels.shape} and kinds {kinds.shape} differ in shape")
        if levels.size and (levels.min() < 0 or levels.max() >= cfg.levels):
            bad = levels[(levels < 0) | (levels >= cfg.levels)][0].item()
            raise ValueError(
                f"level {bad!r} is a terrain level outside the map (levels 0..{cfg.levels - 1})"
            )
        self._check_kinds(kinds)
        x = -self.size_x / 2 + cfg.border + kinds * cfg.tile_length + cfg.pad_length / 2
        y = -self.size_y / 2 + cfg.border + (levels + 0.5) * cfg.tile_width
        return np.stack([x, y], axis=-1).astype(float)

    def _check_kinds(self, kinds: np.ndarray) -> None:
        count = len(self.config.kinds)
        if kinds.size and (kinds.min() < 0 or kinds.max() >= count):
            bad = kinds[(kinds < 0) | (kinds >= count)][0].item()
            raise ValueError(f"kind index {bad!r} outside 0..{count - 1} ({self.config.kinds})")


def tile_heights(cfg: TerrainLevels, level: int, kind: str) -> np.ndarray:
    """Heights of one tile, m. Shape: (tile_width / cell + 1, tile_length / cell + 1).

    Row i is at y = i * cell from the tile's -y edge, column j at x = j * cell from its -x edge.
    Depends only on (cfg.seed, level, kind) and the config's sizes and maxima.
    """
    d = cfg.difficulty(level)
    if kind not in KNOWN_KINDS:
        raise ValueError(f"kind {kind!r} is unknown (known: {KNOWN_KINDS})")
    rows, cols = cfg.cells(cfg.tile_width) + 1, cfg.cells(cfg.tile_length) + 1
    x = np.arange(cols) * cfg.cell
    y = np.arange(rows) * cfg.cell
    s = x - cfg.pad_length  # distance past the pad
    on_pad = np.arange(cols) <= math.floor(cfg.pad_length / cfg.cell + 1e-9)
    run = cfg.tile_length - cfg.pad_length
    if kind == "rough":
        seed = np.random.SeedSequence([cfg.seed, level, KNOWN_KINDS.index(kind)])
        noise = generate_heightmap(
            int(seed.generate_state(1)[0]), rows, cols, cfg.cell, CORRELATION_LENGTH
        )
        profile = d * cfg.roughness * (noise - noise.mean())
    elif kind == "slopes":
        profile = np.broadcast_to(d * cfg.slope * np.minimum(s, run - s), (rows, cols))
    elif kind == "steps":
        stair = np.floor(np.minimum(s, run - s) / cfg.step_tread)
        profile = np.broadcast_to(d * cfg.step_height * stair, (rows, cols))
    elif kind == "flat":
        profile = np.zeros((rows, cols))
    else:  # stones
        stone = max(1, round(cfg.stone_size / cfg.cell))
        gap, depth = round(d * cfg.stone_gap / cfg.cell), cfg.gap_depth
        if cfg.gap_ramp and d > 0:
            gap, depth = max(gap, 1), d * cfg.gap_depth
        period = stone + gap
        past_pad = np.maximum(np.arange(cols) - int(on_pad.sum()), 0)  # 0: first stone
        in_gap = (past_pad[None, :] % period >= stone) | (
            np.arange(rows)[:, None] % period >= stone
        )
        profile = np.where(in_gap, -depth, 0.0)
    edge = np.minimum(
        np.minimum(s, cfg.tile_length - x)[None, :], np.minimum(y, cfg.tile_width - y)[:, None]
    )
    blend = np.clip(edge / cfg.taper, 0.0, 1.0)
    heights = np.where(on_pad[None, :], 0.0, profile * blend)
    return heights + 0.0  # no negative zeros


def generate(cfg: TerrainLevels) -> TerrainMap:
    """The map of terrain levels for a config: tiles in their bands, a flat border around."""
    tile_rows, tile_cols = cfg.cells(cfg.tile_width), cfg.cells(cfg.tile_length)
    border = cfg.cells(cfg.border)
    heights = np.zeros(cfg.shape)
    for level in range(cfg.levels):
        for k, kind in enumerate(cfg.kinds):
            r0, c0 = border + level * tile_rows, border + k * tile_cols
            heights[r0 : r0 + tile_rows + 1, c0 : c0 + tile_cols + 1] = tile_heights(
                cfg, level, kind
            )
    return TerrainMap(heights, cfg)


def hfield_encoding(heights: np.ndarray) -> tuple[np.ndarray, float, float]:
    """Heights as a MuJoCo heightfield: samples in [0, 1], base z and elevation size.

    Returns ``(samples, base, span)`` with samples float32 of the heights' shape, its minimum
    exactly 0 and maximum exactly 1 (so that MuJoCo's own normalisation leaves them unchanged).
    ``base + span * samples`` (in float64) gives back the heights within ``2**-23 * span``, and
    samples at height 0 exactly: base and span are nudged so that the float32 sample nearest
    to height 0 maps back to exactly 0.
    """
    lo, hi = float(heights.min()), float(heights.max())
    if hi == lo:  # flat: any positive span
        return np.zeros(heights.shape, np.float32), lo, 1.0
    span = hi - lo
    samples = np.clip((heights - lo) / span, 0.0, 1.0).astype(np.float32)
    if lo < 0.0 < hi:
        zero = float(np.float32(-lo / span))
        span = -lo / zero
        lo = -(span * zero)
    return samples, lo, span


def build_model(
    model_path: str | os.PathLike[str], cfg: TerrainLevels
) -> tuple[mujoco.MjModel, TerrainMap]:
    """A world with its heightfield replaced by the map of ``cfg``, and that map.

    The ``ground`` geom is placed so that map height 0 is world z 0 and the map's centre is
    world (0, 0); the ``floor`` plane, if any, is moved to the map's lowest level.

    Raises:
        FileNotFoundError: for a model file that does not exist.
        ValueError: naming the file if it has no hfield ``terrain`` or no geom ``ground``, or
            if the compiled model lacks what rwalk needs.
    """
    resolved = resolve_model_path(model_path)
    spec = mujoco.MjSpec.from_file(str(resolved))
    hfield = spec.hfield(TERRAIN_HFIELD)
    ground = spec.geom(GROUND_GEOM)
    if hfield is None or ground is None:
        raise ValueError(
            f"{resolved}: terrain levels need an hfield {TERRAIN_HFIELD!r} and a geom "
            f"{GROUND_GEOM!r} (as in model/world_train.xml)"
        )
    terrain_map = generate(cfg)
    samples, base, span = hfield_encoding(terrain_map.heights)
    rows, cols = samples.shape
    hfield.file = ""
    hfield.nrow, hfield.ncol = rows, cols
    hfield.size = [terrain_map.size_x / 2, terrain_map.size_y / 2, span, hfield.size[3]]
    hfield.userdata = samples.ravel()
    ground.pos = [0.0, 0.0, base]
    floor = spec.geom(FLOOR_GEOM)
    if floor is not None:
        floor.pos = [0.0, 0.0, base]
    model = spec.compile()
    validate_model(model, source=str(resolved))
    return model, terrain_map


def update_levels(
    levels: torch.Tensor,
    distance: torch.Tensor,
    expected: torch.Tensor,
    fell: torch.Tensor,
    cfg: TerrainLevels,
    redraw: torch.Tensor | None = None,
    floor: torch.Tensor | int = 0,
) -> torch.Tensor:
    """Levels after an episode: one up for a walk of at least ``promote * expected`` without
    falling, one down for a fall or a walk shorter than ``demote * expected``, clamped to the
    map and to each env's ``floor`` (``TerrainLevels.floor_level`` on its floor kinds, else
    0); with ``cfg.recycle``, an env promoted beyond the top takes its ``redraw`` level
    instead; unchanged when ``cfg.curriculum`` is False.

    Shape: (N,) int64, (N,) m, (N,) m, (N,) bool, optional (N,) int64, (N,) int64 or an int
    -> (N,) int64.
    """
    if not cfg.curriculum:
        return levels.clone()
    up = ~fell & (distance >= cfg.promote * expected)
    down = fell | (distance < cfg.demote * expected)
    step = up.long() - down.long()  # never both: demote <= promote
    moved = torch.clamp(torch.clamp(levels + step, max=cfg.levels - 1), min=floor)
    if cfg.recycle and redraw is not None:
        moved = torch.where(up & (levels == cfg.levels - 1), redraw, moved)
    return moved


__all__ = [
    "DEFAULT_KINDS",
    "KNOWN_KINDS",
    "TerrainLevels",
    "TerrainMap",
    "build_model",
    "generate",
    "hfield_encoding",
    "tile_heights",
    "update_levels",
]

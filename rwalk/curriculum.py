"""The terrain curriculum: each env's level and kind of tile on a map of terrain levels.

At each reset of an env that walked an episode, ``move`` takes it a level up or
down by how far it walked against the distance its target velocity asks for
(``rwalk.levels.update_levels``); envs promoted past the top restart at a level
drawn from the key (seed + i, "terrain_level", k) of ``rwalk.rng``. ``origins``
says where each env starts: its tile's pad on a map, else the config's start
position. ``state``/``load_state`` carry the levels through checkpoints, so a
resumed training goes on with its curriculum.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from rwalk import rng
from rwalk.levels import TerrainLevels, TerrainMap, update_levels

#: Random stream of the levels of envs that pass the top of a terrain map.
LEVEL_STREAM = "terrain_level"
#: Random stream of the review episodes (``TerrainLevels.review``): whether, and which level.
REVIEW_STREAM = "terrain_review"


class Curriculum:
    """Levels, kinds and start origins of N envs.

    Args:
        levels: the map's config (None: no map, every env at level 0 of kind 0).
        terrain_map: the generated map of ``levels`` (None without one).
        num_envs: N.
        start_position: (x, y) of every start without a map. Metres.
    """

    def __init__(
        self,
        levels: TerrainLevels | None,
        terrain_map: TerrainMap | None,
        num_envs: int,
        start_position: tuple[float, float],
    ) -> None:
        self.levels = levels
        self.terrain_map = terrain_map
        self._start = np.asarray(start_position, dtype=np.float64)
        kinds = len(levels.kinds) if levels is not None else 1
        self.terrain_kind = torch.arange(num_envs, dtype=torch.long) % kinds
        """Each env's kind of tile, an index into ``levels.kinds``. Shape: (N,)."""
        self.floor = torch.zeros(num_envs, dtype=torch.long)
        """Each env's lowest level (``levels.floor_level`` on its floor kinds, else 0).
        Shape: (N,)."""
        if levels is not None and levels.floor_kinds:
            self.floor[self.of_kinds(levels.floor_kinds)] = levels.floor_level
        start = levels.start_level if levels is not None else 0
        self.terrain_level = torch.clamp(torch.full((num_envs,), start), min=self.floor)
        """Each env's terrain level (0 without a map). Shape: (N,)."""
        self.draws = torch.zeros(num_envs, dtype=torch.long)
        """Levels drawn so far by each env (recycled past the top). Shape: (N,)."""
        self.reviewing = torch.zeros(num_envs, dtype=torch.bool)
        """Whether each env's episode runs on a level drawn at or below its own
        (``levels.review``) instead of its own. Shape: (N,)."""
        self.review_level = torch.zeros(num_envs, dtype=torch.long)
        """The level of each reviewing env's episode. Shape: (N,)."""
        self.reviews = torch.zeros(num_envs, dtype=torch.long)
        """Review draws so far by each env. Shape: (N,)."""
        self.flat = torch.zeros(num_envs, dtype=torch.bool)
        """Whether each env walks its tile's level 0 (flat at every kind) from now on
        (``flatten``): its level neither moves nor reviews. Shape: (N,)."""
        self._seed = 0

    def seed(self, seed: int) -> None:
        """Key the level draws by ``seed`` (env i draws from seed + i) and restart them."""
        self._seed = seed
        self.draws.zero_()
        self.reviews.zero_()

    def flatten(self, kinds: tuple[str, ...]) -> Tensor:
        """From their next episode on, the envs on ``kinds`` of tile walk level 0 (flat
        at every kind) and stay there until ``release`` (rwalk-train's --flat-kinds
        window). Returns those envs' mask. Shape: (N,) bool.

        Raises:
            ValueError: naming the kind, if the map has none of it (or there is no map).
        """
        rows = self.of_kinds(kinds, "flatten")
        self.flat |= rows
        self.terrain_level[rows] = 0
        self.reviewing[rows] = False
        return rows

    def release(self, kinds: tuple[str, ...]) -> Tensor:
        """From their next episode on, the envs on ``kinds`` of tile walk the curriculum
        again, each from a level drawn uniformly from the map's (as an env passing the
        top does: its next draw of the key (seed + i, "terrain_level", k)), so that they
        do not climb the flat levels one episode at a time. Returns their mask. Shape:
        (N,) bool."""
        mask = self.of_kinds(kinds, "flatten")
        rows = torch.nonzero(mask).flatten()
        u = rng.uniform_rows(self._seed, rows, LEVEL_STREAM, self.draws, 1)[:, 0]
        self.terrain_level[rows] = self._above_floor(rows, u, self.levels.levels - 1)
        self.flat &= ~mask
        return mask

    def of_kinds(self, kinds: tuple[str, ...], use: str = "select") -> Tensor:
        """Mask of the envs on ``kinds`` of tile. Shape: (N,) bool.

        Raises:
            ValueError: naming the kind and ``use``, if the map has none of it.
        """
        known = self.levels.kinds if self.levels is not None else ()
        for kind in kinds:
            if kind not in known:
                raise ValueError(f"no {kind!r} tiles to {use}: the map's kinds are "
                                 f"{known or 'none (no terrain-levels map)'}")  # fmt: skip
        return torch.isin(self.terrain_kind, torch.tensor([known.index(k) for k in kinds]))

    def _above_floor(self, rows: Tensor, u: Tensor, top: Tensor | int) -> Tensor:
        """Levels drawn uniformly from each env's floor to ``top`` (the map's, or each env's
        own) by uniforms ``u``. Shape: (M,), (M,), (M,) or an int -> (M,) int64."""
        floor = self.floor[rows]
        return floor + torch.floor(u * (top + 1 - floor)).to(torch.long)

    def move(
        self,
        rows: Tensor,
        walked: Tensor,
        distance: Tensor,
        fell: Tensor,
        target: Tensor | float,
        control_dt: float,
    ) -> None:
        """Move the envs of ``rows`` that walked an episode on their own level a level up
        or down, then draw the level of each one's next episode (``levels.review``).

        Args:
            rows: env indices. Shape: (M,).
            walked, distance, fell: every env's steps walked, distance (m) and fall
                in the episode now ending. Each shape: (N,).
            target: velocity each env tracked (m/s): a float, or per env (N,).
        """
        levels = self.levels
        if levels is None:
            return
        self._move(rows, walked, distance, fell, target, control_dt)
        if levels.review > 0:  # env i's k-th draw from the key (seed + i, REVIEW_STREAM, k)
            u = rng.uniform_rows(self._seed, rows, REVIEW_STREAM, self.reviews, 2)
            self.reviewing[rows] = (u[:, 0] < levels.review) & ~self.flat[rows]
            self.review_level[rows] = self._above_floor(rows, u[:, 1], self.terrain_level[rows])

    def _move(self, rows: Tensor, walked: Tensor, distance: Tensor, fell: Tensor,
              target: Tensor | float, control_dt: float) -> None:  # fmt: skip
        levels = self.levels
        if not levels.curriculum:
            return
        rows = rows[(walked[rows] > 0) & ~self.reviewing[rows] & ~self.flat[rows]]  # first
        # resets end no episode; flattened envs stay at level 0
        if rows.numel() == 0:
            return
        target = target[rows] if isinstance(target, Tensor) else target
        expected = target * walked[rows].to(torch.float64) * control_dt
        redraw = None
        if levels.recycle:  # env i's k-th draw from the key (seed + i, LEVEL_STREAM, k)
            u = rng.uniform_rows(self._seed, rows, LEVEL_STREAM, self.draws, 1)[:, 0]
            redraw = self._above_floor(rows, u, levels.levels - 1)
        self.terrain_level[rows] = update_levels(self.terrain_level[rows], distance[rows],
                                                 expected, fell[rows], levels, redraw,
                                                 self.floor[rows])  # fmt: skip

    def origins(self, ids: np.ndarray | None) -> np.ndarray:
        """Nominal start (x, y) of envs ``ids``: their tiles' pads on a map, else the
        start position; None: where the settled-start pool starts (the pad of tile (0, 0)).
        Shape: (M, 2) or (2,). Metres."""
        if self.terrain_map is None:
            return self._start
        if ids is None:
            return np.asarray(self.terrain_map.origin(0, 0), dtype=np.float64)
        level = torch.where(self.reviewing[ids], self.review_level[ids], self.terrain_level[ids])
        return self.terrain_map.origins(level.numpy(), self.terrain_kind[ids].numpy())

    def log(self) -> dict[str, Tensor]:
        """TensorBoard scalars: ``Curriculum/terrain_level`` (mean level of all envs) and
        ``Curriculum/level_<kind>`` (of the envs on each kind); empty without a map."""
        if self.terrain_map is None:
            return {}
        level = self.terrain_level.to(torch.float64)
        log = {"Curriculum/terrain_level": level.mean()}
        for index, kind in enumerate(self.levels.kinds):
            log[f"Curriculum/level_{kind}"] = level[self.terrain_kind == index].mean()
        return log

    def state(self) -> dict[str, Tensor]:
        """Per-env tensors to keep when the core is pickled."""
        return {"terrain_level": self.terrain_level, "draws": self.draws,
                "reviewing": self.reviewing, "review_level": self.review_level,
                "reviews": self.reviews, "flat": self.flat}  # fmt: skip

    def checkpoint(self) -> dict[str, Tensor]:
        """What a checkpoint keeps of the curriculum: the levels (empty without a map)."""
        if self.terrain_map is None:
            return {}
        return {"terrain_level": self.terrain_level.clone()}

    def load_checkpoint(self, state: dict[str, Tensor]) -> str | None:
        """Go on from a checkpoint's ``checkpoint()``: each env's next start is on its
        saved level. A checkpoint of another number of envs gives each env the level of a
        saved env on its kind of tile (env j of kind k = j mod K takes the saved envs of
        kind k in turn: a subset, or each repeated), so the curriculum's levels per kind
        carry over. Returns a line for the log where the number of envs differed, else
        None.

        Raises:
            ValueError: naming the field, if the levels are not integers.
        """
        saved = state.get("terrain_level")
        if self.terrain_map is None or saved is None:
            return None
        if not isinstance(saved, Tensor) or saved.dtype not in (torch.int32, torch.int64):
            raise ValueError(
                f"terrain_level must be an integer tensor, got {type(saved).__name__} "
                f"{getattr(saved, 'dtype', '')}".rstrip()
            )
        mine, theirs, kinds = self.terrain_level.numel(), saved.numel(), len(self.levels.kinds)
        note = None
        if saved.shape != self.terrain_level.shape:
            if saved.dim() != 1 or theirs < kinds:
                return (f"terrain levels of shape {tuple(saved.shape)}, this run has "
                        f"{mine} envs on {kinds} kinds of tile: the curriculum starts again "
                        f"at the start level")  # fmt: skip
            env = torch.arange(mine)
            kind = env % kinds
            per_kind = (theirs - kind + kinds - 1) // kinds  # saved envs of each env's kind
            saved = saved[kind + kinds * ((env // kinds) % per_kind)]
            note = (f"terrain levels of {theirs} envs, this run has {mine}: each env starts "
                    f"on the level of a saved env on its kind of tile")  # fmt: skip
        top = self.levels.levels - 1
        self.terrain_level.copy_(torch.clamp(saved.clamp(max=top), min=self.floor))
        self.reviewing.zero_()
        return note

"""Procedural rough terrain for ``model/world_train.xml``, reproducible from a seed.

The heightmap is Gaussian-filtered white noise (isotropic bumps of a given
correlation length), normalised to [0, 1]; MuJoCo scales it by the hfield's
elevation size. ``python -m rwalk.terrain`` rewrites the committed PNG.

Terrain scale s in [0, 1] blends the map towards its mean height:
``h_s = mean + s * (h - mean)``, so 0 is flat (at the terrain's mean height)
and 1 is the full roughness of the committed map.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np
import torch

from rwalk.constants import GROUND_GEOM

#: The committed terrain: seed and layout of model/terrain.png.
TERRAIN_SEED = 0
TERRAIN_ROWS = 160  # along y: 4 m at 2.5 cm
TERRAIN_COLS = 400  # along x: 10 m at 2.5 cm
TERRAIN_CELL = 0.025  # metres per sample
CORRELATION_LENGTH = 0.1  # metres: bumps about a stride apart


def generate_heightmap(
    seed: int,
    rows: int = TERRAIN_ROWS,
    cols: int = TERRAIN_COLS,
    cell: float = TERRAIN_CELL,
    correlation_length: float = CORRELATION_LENGTH,
) -> np.ndarray:
    """Smooth random heights in [0, 1]. Shape: (rows, cols), row-major along y.

    Raises:
        ValueError: for non-positive sizes.
    """
    if rows < 2 or cols < 2:
        raise ValueError(f"heightmap needs at least 2x2 samples, got {rows}x{cols}")
    if cell <= 0 or correlation_length <= 0:
        raise ValueError(
            f"cell ({cell!r}) and correlation_length ({correlation_length!r}) must be > 0"
        )
    rng = np.random.default_rng(seed)
    noise = rng.standard_normal((rows, cols))
    ky = np.fft.fftfreq(rows, d=cell)[:, None]
    kx = np.fft.rfftfreq(cols, d=cell)[None, :]
    sigma = correlation_length / 2.0
    gain = np.exp(-2.0 * (np.pi * sigma) ** 2 * (kx**2 + ky**2))
    smooth = np.fft.irfft2(np.fft.rfft2(noise) * gain, s=(rows, cols))
    lo, hi = smooth.min(), smooth.max()
    return (smooth - lo) / (hi - lo)


def quantize(heights: np.ndarray) -> np.ndarray:
    """Heights in [0, 1] as the 8-bit grey levels stored in the PNG."""
    return np.round(np.clip(heights, 0.0, 1.0) * 255.0).astype(np.uint8)


def write_png(path: Path, grey: np.ndarray) -> None:
    """Write an 8-bit greyscale PNG (no imaging library needed)."""
    rows, cols = grey.shape
    # MuJoCo reads image row 0 as the hfield's far (+y) edge: flip so that
    # array row 0 is the -y edge, as in MjModel.hfield_data.
    raw = b"".join(b"\x00" + row.tobytes() for row in grey[::-1])

    def chunk(tag: bytes, data: bytes) -> bytes:
        body = tag + data
        return struct.pack(">I", len(data)) + body + struct.pack(">I", zlib.crc32(body))

    header = struct.pack(">IIBBBBB", cols, rows, 8, 0, 0, 0, 0)
    png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header)
    png += chunk(b"IDAT", zlib.compress(raw, 9)) + chunk(b"IEND", b"")
    path.write_bytes(png)


def scaled(base: np.ndarray, scale: float) -> np.ndarray:
    """The base heights blended towards their mean: 0 flat, 1 as generated."""
    if not (0.0 <= scale <= 1.0):
        raise ValueError(f"terrain scale must be in [0, 1], got {scale!r}")
    mean = float(base.mean())
    return mean + scale * (base - mean)


@dataclass(frozen=True)
class TerrainArgs:
    """Write the training world's heightfield image (model/terrain.png) from its seed."""

    seed: int = TERRAIN_SEED
    """the heightfield's random seed"""
    out: Path = Path(__file__).resolve().parent / "model" / "terrain.png"
    """the PNG to write"""


def main(argv: list[str] | None = None) -> None:
    """``python -m rwalk.terrain``: regenerate the heightfield image."""
    from rwalk.cli import parse

    args = parse(TerrainArgs, argv, prog="python -m rwalk.terrain", description=__doc__)
    write_png(args.out, quantize(generate_heightmap(args.seed)))
    print(f"wrote {args.out} (seed {args.seed}, {TERRAIN_ROWS}x{TERRAIN_COLS})")


if __name__ == "__main__":  # through the module by name, where tyro reads TerrainArgs's types
    from rwalk.terrain import main as terrain_main

    terrain_main()


class Terrain:
    """The ground of a compiled world: a plane, or a heightfield with scalable roughness.

    Args:
        model: a world with a geom named ``ground`` (plane or hfield).
    """

    def __init__(self, model: mujoco.MjModel) -> None:
        geom = model.geom(GROUND_GEOM)
        self.origin = np.array(geom.pos, dtype=float)
        self.is_heightfield = int(geom.type[0]) == mujoco.mjtGeom.mjGEOM_HFIELD
        self.scale = 1.0 if self.is_heightfield else 0.0
        """Roughness in force: 0 flat .. 1 as stored; always 0 for a plane."""
        if self.is_heightfield:
            self.hfield_id = int(geom.dataid[0])
            rows = int(model.hfield_nrow[self.hfield_id])
            cols = int(model.hfield_ncol[self.hfield_id])
            adr = int(model.hfield_adr[self.hfield_id])
            self._slice = slice(adr, adr + rows * cols)
            self.base = np.array(model.hfield_data[self._slice], dtype=float).reshape(rows, cols)
            self.size = np.array(model.hfield_size[self.hfield_id], dtype=float)
            self.heights = self.base.copy()

    def set_scale(self, model: mujoco.MjModel, scale: float) -> None:
        """Scale the roughness in ``model`` (0 flat .. 1 as stored).

        Raises:
            ValueError: for a scale outside [0, 1], or on a plane (nothing to scale).
        """
        if not (isinstance(scale, (int, float)) and 0.0 <= scale <= 1.0):
            raise ValueError(f"terrain scale must be a number in [0, 1], got {scale!r}")
        if not self.is_heightfield:
            raise ValueError(
                f"the ground is a plane, not a heightfield: terrain scale {scale!r} would "
                "change nothing (use a world with a heightfield, e.g. model/world_train.xml)"
            )
        self.scale = float(scale)
        self.heights = scaled(self.base, self.scale)
        model.hfield_data[self._slice] = self.heights.ravel()

    def max_height(self, x: np.ndarray, y: np.ndarray, radius: float) -> np.ndarray:
        """Highest ground point within a square of half-width ``radius`` around each (x, y).

        Shape: (M,), (M,) -> (M,). Metres, world frame.
        """
        x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
        if not self.is_heightfield:
            return np.full(x.shape, self.origin[2])
        rows, cols = self.heights.shape
        sx, sy, sz = self.size[:3]
        col = (x - self.origin[0] + sx) / (2 * sx) * (cols - 1)
        row = (y - self.origin[1] + sy) / (2 * sy) * (rows - 1)
        reach_c = int(np.ceil(radius / (2 * sx) * (cols - 1)))
        reach_r = int(np.ceil(radius / (2 * sy) * (rows - 1)))
        dc = np.arange(-reach_c, reach_c + 2)
        dr = np.arange(-reach_r, reach_r + 2)
        cc = np.clip(np.floor(col)[:, None, None] + dc[None, None, :], 0, cols - 1).astype(int)
        rr = np.clip(np.floor(row)[:, None, None] + dr[None, :, None], 0, rows - 1).astype(int)
        top = self.heights[rr, cc].reshape(len(x), -1).max(axis=1)
        return self.origin[2] + sz * top

    def heights_at(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        """Ground height under each (x, y): bilinear between the heightfield's samples.

        Shape: any, same as ``y`` -> the same, float64. Metres, world frame. Points beyond the
        map read its edge; a plane reads its height everywhere. Only elementwise torch ops
        (no fused multiply-add), so the result is the same bit for bit on any CPU, and equals
        the stored sample exactly at a grid point whose column and row come out whole.
        """
        x = torch.as_tensor(x, dtype=torch.float64)
        y = torch.as_tensor(y, dtype=torch.float64)
        if not self.is_heightfield:
            return torch.full(torch.broadcast_shapes(x.shape, y.shape), float(self.origin[2]))
        heights = torch.from_numpy(self.heights)
        rows, cols = heights.shape
        sx, sy, sz = (float(v) for v in self.size[:3])
        col = (x - (float(self.origin[0]) - sx)) / (2 * sx) * (cols - 1)
        row = (y - (float(self.origin[1]) - sy)) / (2 * sy) * (rows - 1)
        col = torch.clamp(col, 0.0, float(cols - 1))
        row = torch.clamp(row, 0.0, float(rows - 1))
        c0 = torch.clamp(torch.floor(col), max=float(cols - 2))
        r0 = torch.clamp(torch.floor(row), max=float(rows - 2))
        fx, fy = col - c0, row - r0
        c0, r0 = c0.long(), r0.long()
        h00, h01 = heights[r0, c0], heights[r0, c0 + 1]
        h10, h11 = heights[r0 + 1, c0], heights[r0 + 1, c0 + 1]
        low = h00 * (1.0 - fx) + h01 * fx
        high = h10 * (1.0 - fx) + h11 * fx
        return float(self.origin[2]) + sz * (low * (1.0 - fy) + high * fy)

"""Rendered frames as files: a GIF with one shared palette and exact frame durations, or
an H.264 MP4 through imageio's ffmpeg."""

from __future__ import annotations

import itertools
from collections.abc import Iterator
from fractions import Fraction
from pathlib import Path

import numpy as np


# ----------------------------------------------------------------- writers
def gif_durations(count: int, seconds_per_frame: float) -> list[int]:
    """Per-frame delays in ms; GIFs store centiseconds, so the rounding error is spread
    over frames (e.g. 30 fps -> 30, 40, 30 ms) instead of speeding the clip up."""
    ticks = [round(i * seconds_per_frame * 100) for i in range(count + 1)]
    return [max(1, b - a) * 10 for a, b in itertools.pairwise(ticks)]


class PaletteMapper:
    """Exact nearest-colour mapping of RGB frames onto one fixed palette.

    Pillow's own palette mapping goes through a coarse colour cache (white comes out as
    252 grey); here every distinct 24-bit colour is looked up once and then cached.
    """

    def __init__(self, palette: np.ndarray) -> None:
        self.palette = palette.astype(np.int32)  # (N, 3)
        self.lut = np.zeros(1 << 24, dtype=np.uint16)  # 0: not seen yet, else index + 1

    def __call__(self, frame: np.ndarray) -> np.ndarray:
        f = frame.astype(np.uint32)
        key = (f[..., 0] << 16) | (f[..., 1] << 8) | f[..., 2]
        idx = self.lut[key]
        if not idx.all():
            new = np.unique(key[idx == 0])
            rgb = np.stack([new >> 16, (new >> 8) & 255, new & 255], axis=-1).astype(np.int32)
            for i in range(0, len(new), 4096):  # bounded memory for the distance table
                d = ((rgb[i : i + 4096, None, :] - self.palette[None]) ** 2).sum(-1)
                self.lut[new[i : i + 4096]] = d.argmin(1) + 1
            idx = self.lut[key]
        return (idx - 1).astype(np.uint8)


def write_gif(frames: Iterator[np.ndarray], path: Path, durations: list[int]) -> None:
    from PIL import Image

    # one palette (median cut of the first frame) for all frames: no colour flicker
    first = next(frames)
    quantized = Image.fromarray(first).quantize(
        256, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE
    )
    palette = np.asarray(quantized.getpalette() or [], dtype=np.uint8).reshape(-1, 3)
    to_index = PaletteMapper(palette)

    def indexed(frame: np.ndarray) -> Image.Image:
        img = Image.frombytes("P", (frame.shape[1], frame.shape[0]), to_index(frame).tobytes())
        img.putpalette(palette.tobytes())
        return img

    indexed(first).save(
        path,
        format="GIF",
        save_all=True,
        append_images=(indexed(frame) for frame in frames),
        duration=durations,
        loop=0,
    )


def write_mp4(frames: Iterator[np.ndarray], path: Path, size: tuple[int, int], fps: float) -> None:
    import imageio_ffmpeg

    writer = imageio_ffmpeg.write_frames(
        str(path),
        size,
        fps=Fraction(fps).limit_denominator(10000),
        codec="libx264",
        pix_fmt_out="yuv420p",
        quality=7,
        macro_block_size=1,
        ffmpeg_log_level="error",
        output_params=["-f", "mp4", "-movflags", "+faststart"],
    )
    writer.send(None)
    try:
        for frame in frames:
            writer.send(frame)
    finally:
        writer.close()

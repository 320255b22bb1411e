"""MP4 writing (imageio-ffmpeg's bundled ffmpeg, libx264) for rendered cameras."""

from __future__ import annotations

from pathlib import Path

import imageio_ffmpeg
import numpy as np


class Mp4Writer:
    """Streams RGB uint8 frames ``(H, W, 3)`` into an H.264 MP4; a context manager
    (``with Mp4Writer(...) as w: w.write(frame)``) that closes the file on the way out.

    ``crf`` 12 is visually lossless; marker centroids measured on the decoded video
    move by well under 0.05 px (see tests), so the real-video entry point of the
    pipeline sees what the in-memory path sees.
    """

    def __init__(self, path: str | Path, width: int, height: int, fps: float, crf: int = 12) -> None:
        self.path = Path(path)
        self._gen = imageio_ffmpeg.write_frames(
            str(self.path), (width, height), fps=fps, codec="libx264", pix_fmt_in="rgb24",
            pix_fmt_out="yuv420p", output_params=["-crf", str(crf), "-preset", "veryfast"],
            macro_block_size=1, ffmpeg_log_level="error",
        )
        self._gen.send(None)

    def write(self, frame: np.ndarray) -> None:
        self._gen.send(np.ascontiguousarray(frame, dtype=np.uint8))

    def close(self) -> None:
        self._gen.close()

    def __enter__(self) -> "Mp4Writer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

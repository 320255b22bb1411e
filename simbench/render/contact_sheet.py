"""One PNG showing every camera at a few instants, labelled, for a quick look."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np


def contact_sheet(frames: dict[tuple[int, str], np.ndarray], times: dict[int, float], path: str | Path,
                  scale: float = 0.5, overlays: dict[tuple[int, str], np.ndarray] | None = None) -> None:
    """Write a grid: rows are frames, columns cameras.

    frames : (frame index, camera name) -> RGB uint8 image
    overlays : optional (frame, camera) -> (N, 2) pixel points drawn as small circles
        (e.g. projected ground-truth markers)
    """
    rows = sorted({k for k, _ in frames})
    cols = list(dict.fromkeys(c for _, c in frames))
    first = next(iter(frames.values()))
    h, w = int(first.shape[0] * scale), int(first.shape[1] * scale)
    pad, head = 4, 18
    sheet = np.full((len(rows) * (h + head + pad) + pad, len(cols) * (w + pad) + pad, 3), 30, np.uint8)
    for r, k in enumerate(rows):
        for c, name in enumerate(cols):
            img = frames.get((k, name))
            if img is None:
                continue
            small = cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA)
            if overlays and (k, name) in overlays:
                for x, y in np.asarray(overlays[(k, name)]).reshape(-1, 2):
                    if np.isfinite(x) and np.isfinite(y):
                        cv2.circle(small, (int(round(x * scale)), int(round(y * scale))), 4, (255, 60, 60), 1, cv2.LINE_AA)
            y0 = pad + r * (h + head + pad) + head
            x0 = pad + c * (w + pad)
            sheet[y0:y0 + h, x0:x0 + w] = small
            cv2.putText(sheet, f"{name}  frame {k}  t={times.get(k, 0):.2f}s", (x0 + 2, y0 - 5),
                        cv2.FONT_HERSHEY_SIMPLEX, 0.42, (230, 230, 230), 1, cv2.LINE_AA)
    path = Path(path)
    cv2.imwrite(str(path), sheet[..., ::-1])

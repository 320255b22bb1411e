"""Video plans: the marker paths of each category (slow and rapid zigzags, accelerations,
an occluding barrier, two markers crossing), drawn from the study's seed (:func:`plan_video`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mocap.tracker_trials import CATEGORIES
from simbench.studies.trackers.config import IMAGE_H, IMAGE_W, AccelerationDifficulty, OcclusionDifficulty, StudyConfig, SwapDifficulty, ZigzagDifficulty, _CATEGORY_CODE


MARGIN_PX = 25.0


@dataclass(frozen=True)
class Barrier:
    """The occluding box as seen in the image: centre (2,) px, width and height px."""

    centre_px: tuple[float, float]
    width_px: float
    height_px: float

    def hides(self, xy: np.ndarray) -> np.ndarray:
        """(...,) bool: image points ``xy`` (..., 2) px inside the barrier's rectangle."""
        d = np.abs(np.asarray(xy) - np.asarray(self.centre_px))
        return (d[..., 0] < self.width_px / 2) & (d[..., 1] < self.height_px / 2)


@dataclass
class VideoPlan:
    """One test video before rendering: marker paths in pixels, continuous in time.

    Attributes
    ----------
    category : str
    index : int
        Video number within its category.
    knot_t : (K,) float
        Increasing times, s, covering every frame's exposure.
    knot_xy : (K, M, 2) float
        Marker image positions at ``knot_t``, px (piecewise linear in between: exact for
        zigzag legs, densely sampled for smooth paths).
    depth_m : (M,) float
        Distance of each marker's plane from the camera.
    barrier : Barrier or None
    params : dict
        The drawn parameters (speeds, angles, ...), for the logs.
    render_seed : int
        Seed of the sensor noise.
    """

    category: str
    index: int
    knot_t: np.ndarray
    knot_xy: np.ndarray
    depth_m: np.ndarray
    barrier: Barrier | None
    params: dict
    render_seed: int

    @property
    def n_markers(self) -> int:
        return self.knot_xy.shape[1]

    def xy_at(self, times: np.ndarray) -> np.ndarray:
        """(T, M, 2) image positions, px, at ``times`` (T,) s."""
        t = np.asarray(times, dtype=np.float64)
        K, M, _ = self.knot_xy.shape
        flat = self.knot_xy.reshape(K, M * 2)
        out = np.stack([np.interp(t, self.knot_t, flat[:, j]) for j in range(M * 2)], axis=-1)
        return out.reshape(len(t), M, 2)


def video_rng(config: StudyConfig, category: str, index: int) -> np.random.Generator:
    """The generator of one video's drawn parameters (independent of every other video)."""
    return np.random.default_rng(np.random.SeedSequence([config.seed, _CATEGORY_CODE[category], index]))


def _inside(xy: np.ndarray, margin: float = MARGIN_PX) -> bool:
    xy = np.asarray(xy)
    return bool(np.all((xy[..., 0] >= margin) & (xy[..., 0] <= IMAGE_W - 1 - margin)
                       & (xy[..., 1] >= margin) & (xy[..., 1] <= IMAGE_H - 1 - margin)))


def _ray_room(p: np.ndarray, heading: float, margin: float = MARGIN_PX) -> float:
    """Distance, px, from ``p`` along ``heading`` to the image margin."""
    d = np.array([np.cos(heading), np.sin(heading)])
    lo = np.array([margin, margin])
    hi = np.array([IMAGE_W - 1 - margin, IMAGE_H - 1 - margin])
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(d > 1e-12, (hi - p) / d, np.where(d < -1e-12, (lo - p) / d, np.inf))
    return float(max(0.0, t.min()))


def _zigzag(rng: np.random.Generator, duration_s: float, fps: float, d: ZigzagDifficulty) -> tuple[np.ndarray, np.ndarray, dict]:
    """Piecewise-linear zigzag: corner times (K,) s and positions (K, 2) px."""
    v = rng.uniform(*d.speed_px_per_frame) * fps  # px/s
    p = np.array([rng.uniform(200, IMAGE_W - 200), rng.uniform(150, IMAGE_H - 150)])
    heading = rng.uniform(0, 2 * np.pi)
    times, points, turns = [0.0], [p.copy()], []
    t = 0.0
    first = True
    while t < duration_s:
        if not first:
            turn = np.radians(rng.uniform(*d.turn_deg))
            cand = (heading + turn, heading - turn)
            rooms = [_ray_room(p, h) for h in cand]
            k = int(rng.integers(2)) if min(rooms) > 60 else int(np.argmax(rooms))
            heading = cand[k]
            turns.append(float(np.degrees(turn)) * (1 if k == 0 else -1))
            if rooms[k] < 5.0:  # cornered: head for the image centre
                heading = float(np.arctan2(IMAGE_H / 2 - p[1], IMAGE_W / 2 - p[0]))
        first = False
        length = rng.uniform(*d.leg_frames) * v / fps  # px
        length = min(length, _ray_room(p, heading))
        length = max(length, 1.0)
        p = p + length * np.array([np.cos(heading), np.sin(heading)])
        t += length / v
        times.append(t)
        points.append(p.copy())
    params = {"speed_px_per_frame": v / fps, "legs": len(times) - 1,
              "mean_abs_turn_deg": float(np.mean(np.abs(turns))) if turns else 0.0}
    return np.array(times), np.array(points), params


def _integrate_path(t: np.ndarray, speed_px_s: np.ndarray, heading: np.ndarray, start: np.ndarray) -> np.ndarray:
    """(T, 2) positions from speeds (px/s) and headings (rad) on the time grid ``t``."""
    dt = np.diff(t, prepend=t[0])
    step = np.stack([speed_px_s * np.cos(heading), speed_px_s * np.sin(heading)], axis=1) * dt[:, None]
    return start + np.cumsum(step, axis=0)


def _centre_path(xy: np.ndarray, rng: np.random.Generator, jitter_px: float = 40.0) -> np.ndarray | None:
    """Shift a path (T, ..., 2) to the image centre (plus jitter), None if it does not fit."""
    lo, hi = xy.reshape(-1, 2).min(axis=0), xy.reshape(-1, 2).max(axis=0)
    room = np.array([IMAGE_W - 1, IMAGE_H - 1]) - 2 * MARGIN_PX - (hi - lo)
    if np.any(room < 0):
        return None
    shift = np.array([MARGIN_PX, MARGIN_PX]) + room / 2 - lo
    shift += np.clip(rng.uniform(-jitter_px, jitter_px, 2), -room / 2, room / 2)
    return xy + shift


def _fine_grid(duration_s: float, fps: float) -> np.ndarray:
    return np.linspace(0.0, duration_s, int(np.ceil(duration_s * fps * 20)) + 1)


def _plan_acceleration(rng: np.random.Generator, duration_s: float, fps: float,
                       d: AccelerationDifficulty) -> tuple[np.ndarray, np.ndarray, dict]:
    t = _fine_grid(duration_s, fps)
    T = t[-1]
    kind = ["speed_up", "brake", "oscillate"][int(rng.integers(3))]
    for _ in range(200):
        if kind == "oscillate":
            peak = rng.uniform(*d.top_speed_px_per_frame) * fps  # px/s
            period = rng.uniform(*d.period_s)
            amp = peak * period / (2 * np.pi)
            phase = rng.uniform(0, 2 * np.pi)
            ang = rng.uniform(0, np.pi)
            s = amp * np.sin(2 * np.pi * t / period + phase)
            drift = rng.uniform(-1.0, 1.0) * fps  # px/s across the swing
            e = np.array([np.cos(ang), np.sin(ang)])
            n = np.array([-e[1], e[0]])
            xy = s[:, None] * e + (drift * t)[:, None] * n
            params = {"kind": kind, "peak_speed_px_per_frame": peak / fps, "period_s": period, "amplitude_px": amp}
        else:
            s0, s1 = rng.uniform(*d.start_speed_px_per_frame), rng.uniform(*d.top_speed_px_per_frame)
            power = rng.uniform(*d.ramp_power)
            speed = (s0 + (s1 - s0) * (t / T) ** power) * fps
            if kind == "brake":
                speed = speed[::-1]
            curvature = rng.uniform(-1.0, 1.0) * np.radians(d.bend_deg) / (0.5 * (s0 + s1) * fps * T)  # rad/px
            dist = np.concatenate([[0.0], np.cumsum(speed[1:] * np.diff(t))])
            heading = rng.uniform(0, 2 * np.pi) + curvature * dist
            xy = _integrate_path(t, speed, heading, np.zeros(2))
            params = {"kind": kind, "start_speed_px_per_frame": float(speed[0] / fps),
                      "end_speed_px_per_frame": float(speed[-1] / fps), "power": power,
                      "turn_deg": float(np.degrees(curvature * dist[-1]))}
        placed = _centre_path(xy, rng)
        if placed is not None:
            return t, placed, params
    raise RuntimeError("could not fit an acceleration path in the image; lower difficulty.acceleration.top_speed_px_per_frame")


def _plan_occlusion(rng: np.random.Generator, duration_s: float, fps: float,
                    d: OcclusionDifficulty) -> tuple[np.ndarray, np.ndarray, Barrier, dict]:
    """A marker crossing the barrier on a straight, arc or wavy path. It starts inside the
    image, at least 6 frames before the barrier; a fast one may leave the image later
    (it is not scored outside)."""
    t = _fine_grid(duration_s, fps)
    frames = np.arange(int(round(duration_s * fps))) / fps
    for _ in range(1000):
        speed = rng.uniform(*d.speed_px_per_frame) * fps  # px/s
        width = rng.uniform(*d.barrier_width_px)
        hide = width * fps / speed  # frames behind the barrier, roughly
        height = rng.uniform(*d.barrier_height_px)
        centre = np.array([IMAGE_W / 2 + rng.uniform(-60, 60), IMAGE_H / 2 + rng.uniform(-40, 40)])
        barrier = Barrier((float(centre[0]), float(centre[1])), float(width), float(height))
        heading0 = rng.uniform(-np.radians(25), np.radians(25)) + (np.pi if rng.random() < 0.5 else 0.0)
        shape = ["linear", "arc", "wave"][int(rng.integers(3))]
        t_cross = rng.uniform(6.0 + hide / 2, max(6.0 + hide / 2, 0.5 * duration_s * fps + 9.0)) / fps
        u = speed * (t - t_cross)  # arc length from the crossing, px
        e = np.array([np.cos(heading0), np.sin(heading0)])
        n = np.array([-e[1], e[0]])
        if shape == "linear":
            off = np.zeros_like(u)
            extra = {}
        elif shape == "arc":
            bend = rng.uniform(20.0, 60.0) * rng.choice([-1.0, 1.0])  # deg over the video
            kappa = np.radians(bend) / (speed * duration_s)  # 1/px
            off = 0.5 * kappa * u**2  # parabola ~ arc for small angles
            extra = {"bend_deg": float(bend)}
        else:
            amp = rng.uniform(15.0, 40.0)
            period = rng.uniform(0.8, 2.0)
            off = amp * np.sin(2 * np.pi * (t - t_cross) / period + rng.uniform(0, 2 * np.pi))
            extra = {"wave_amplitude_px": float(amp), "wave_period_s": float(period)}
        xy = centre + u[:, None] * e + off[:, None] * n
        xf = np.stack([np.interp(frames, t, xy[:, k]) for k in range(2)], axis=1)
        inside = _inside_mask(xf)
        hidden = barrier.hides(xf) & inside
        seen_after = inside & ~hidden & (frames > t_cross)
        if not inside[:3].all() or hidden[:3].any() or hidden.sum() < 1 or seen_after.sum() < 3:
            continue
        params = {"shape": shape, "speed_px_per_frame": speed / fps, "barrier_width_px": width,
                  "barrier_height_px": height, "hidden_frames": int(hidden.sum()),
                  "frames_in_image": int(inside.sum()), **extra}
        return t, xy, barrier, params
    raise RuntimeError("could not draw an occlusion video; lower difficulty.occlusion.speed_px_per_frame")


def _plan_swap(rng: np.random.Generator, duration_s: float, fps: float, min_apart_px: float,
               d: SwapDifficulty) -> tuple[np.ndarray, np.ndarray, dict]:
    """Two markers on straight paths crossing closely, both inside the image from the
    start until 10 frames after the crossing (fast ones may leave the image later)."""
    t = _fine_grid(duration_s, fps)
    frames = np.arange(int(round(duration_s * fps))) / fps
    for _ in range(1000):
        angle = np.radians(rng.uniform(*d.crossing_angle_deg))
        speeds = rng.uniform(*d.speed_px_per_frame, 2) * fps  # px/s
        base = rng.uniform(0, 2 * np.pi)
        miss = rng.uniform(*d.miss_px)
        t_cross = rng.uniform(10.0, max(10.0, 0.5 * duration_s * fps + 8.0)) / fps
        normal = np.array([-np.sin(base), np.cos(base)])
        centre = np.array([IMAGE_W / 2, IMAGE_H / 2]) + rng.uniform(-60, 60, 2)
        xy = np.empty((len(t), 2, 2))
        for k, h in enumerate((base - angle / 2, base + angle / 2)):
            v = speeds[k] * np.array([np.cos(h), np.sin(h)])
            xy[:, k] = centre + (k - 0.5) * miss * normal + (t - t_cross)[:, None] * v
        xf = np.stack([np.stack([np.interp(frames, t, xy[:, m, k]) for k in range(2)], axis=1) for m in range(2)], axis=1)
        sep = np.linalg.norm(xf[:, 0] - xf[:, 1], axis=1)
        until = frames <= t_cross + 10.0 / fps
        if not (_inside_mask(xf[until, 0]).all() and _inside_mask(xf[until, 1]).all()) or sep[0] < min_apart_px:
            continue
        params = {"crossing_angle_deg": float(np.degrees(angle)), "miss_px": float(miss),
                  "speeds_px_per_frame": [float(s / fps) for s in speeds], "crossing_frame": float(t_cross * fps),
                  "labelled": d.labelled}
        return t, xy, params
    raise RuntimeError("could not draw a swap video; lower difficulty.swap.speed_px_per_frame")


def _inside_mask(xy: np.ndarray, margin: float = MARGIN_PX) -> np.ndarray:
    """(T,) bool: points ``xy`` (T, 2) px inside the image margin."""
    return ((xy[:, 0] >= margin) & (xy[:, 0] <= IMAGE_W - 1 - margin)
            & (xy[:, 1] >= margin) & (xy[:, 1] <= IMAGE_H - 1 - margin))


def plan_video(config: StudyConfig, category: str, index: int) -> VideoPlan:
    """Draw one video of a category (deterministic in ``config.seed``, category, index),
    at ``config.difficulty``."""
    if category not in CATEGORIES:
        raise ValueError(f"unknown category {category!r}; expected one of {', '.join(CATEGORIES)}")
    rng = video_rng(config, category, index)
    fps = config.fps
    d = config.difficulty
    duration = (config.n_frames + 1) / fps  # every frame's exposure is inside
    depth = np.array([config.plane_distance_m])
    barrier = None
    if category in ("slow", "rapid"):
        t, xy, params = _zigzag(rng, duration, fps, getattr(d, category))
    elif category == "acceleration":
        t, xy, params = _plan_acceleration(rng, duration, fps, d.acceleration)
    elif category == "occlusion":
        t, xy, barrier, params = _plan_occlusion(rng, duration, fps, d.occlusion)
    else:
        t, xy, params = _plan_swap(rng, duration, fps, 3.0 * config.loss_radius_px, d.swap)
        depth = np.array([config.plane_distance_m, config.plane_distance_m + 0.03])
    if xy.ndim == 2:
        xy = xy[:, None, :]
    render_seed = int(rng.integers(2**31 - 1))
    return VideoPlan(category, index, np.asarray(t, float), np.asarray(xy, float), depth, barrier, params, render_seed)

"""Simulate a scene: kinematic humanoid, physical props, states at any instants.

The humanoid is driven kinematically: before every physics step its qpos is set from
the motion and its qvel from the finite difference over that step
(``mj_differentiatePos``, so the free joint's quaternion is handled exactly); its
segments are made quasi-infinitely heavy in the simulation's copy of the model, so a
ball bounces off a moving limb as off a moving wall and never pushes the body.
Props integrate by MuJoCo physics on a fixed grid ``k * dt`` from t = 0 (their
initial conditions are at t = 0), whatever instants are asked for: a state at time
``t`` between grid points comes from one partial step of length ``t - k dt`` taken on
a scratch copy, so the props' trajectory does not depend on the sampling (blur
sub-frames or not).  Everything is single-threaded MuJoCo: the same inputs give
bitwise identical states.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import mujoco
import numpy as np

from simbench.scenes.humanoid import BODY_NAMES, NQ, NV
from simbench.scenes.props import BallProp, MovingProp
from simbench.scenes.scene import PHYSICS_TIMESTEP_S, Scene

__all__ = ["SceneStates", "simulate", "KINEMATIC_MASS_SCALE"]

# Mass/inertia scale that makes the humanoid's segments immovable for the contact solver.
KINEMATIC_MASS_SCALE = 1e6


@dataclass(frozen=True, eq=False)
class SceneStates:
    """States of a scene at T instants.

    Attributes
    ----------
    times : (T,) float
        Seconds.
    qpos : (T, nq) float
        MuJoCo qpos of the whole scene (humanoid first: ``qpos[:, :40]``).
    body_xpos : (T, nbody, 3) float
        World position of every MuJoCo body (index = :meth:`Scene.body_id`), metres.
    body_xmat : (T, nbody, 3, 3) float
        World orientation of every body.
    marker_xpos : (T, M, 3) float
        Marker centres, world metres, in ``marker_names`` order (M = 0 without markers).
    joint_centres : (T, 16, 3) float
        Humanoid body origins (= joint centres), world metres, in ``BODY_NAMES`` order.
    prop_poses : dict[str, (T, 4, 4) float]
        World pose of each prop's frame (its render mesh is in that frame).
    marker_names : tuple[str, ...]
    body_names : tuple[str, ...]
        Name of every MuJoCo body (index = body id; 0 is ``"world"``).
    """

    times: np.ndarray
    qpos: np.ndarray
    body_xpos: np.ndarray
    body_xmat: np.ndarray
    marker_xpos: np.ndarray
    joint_centres: np.ndarray
    prop_poses: dict
    marker_names: tuple = ()
    body_names: tuple = ()

    def __len__(self) -> int:
        return len(self.times)


def _check_times(times) -> np.ndarray:
    t = np.asarray(times, dtype=np.float64)
    if t.ndim != 1 or len(t) == 0:
        raise ValueError(f"simulate: times must be a non-empty 1-D array of seconds, got shape {t.shape}")
    if not np.isfinite(t).all():
        raise ValueError("simulate: times must be finite")
    if t[0] < 0.0:
        raise ValueError(f"simulate: times start at t = 0 (props' initial state); got {t[0]}")
    if len(t) > 1 and (np.diff(t) < 0).any():
        i = int(np.flatnonzero(np.diff(t) < 0)[0])
        raise ValueError(f"simulate: times must be increasing; times[{i + 1}] = {t[i + 1]} < times[{i}] = {t[i]}")
    return t


def _kinematic_model(scene: Scene) -> mujoco.MjModel:
    """A private copy of the scene's model whose humanoid is immovable by contacts."""
    model = mujoco.MjModel.from_xml_string(scene.mjcf_xml)
    ids = [model.body(n).id for n in BODY_NAMES]
    model.body_mass[ids] *= KINEMATIC_MASS_SCALE
    model.body_inertia[ids] *= KINEMATIC_MASS_SCALE
    mujoco.mj_setConst(model, mujoco.MjData(model))  # refresh the constants derived from masses
    return model


class _Drive:
    """The humanoid's qpos at given times, from a per-time or a vectorised motion function.

    A motion may accept an array of times and return ``(n, 40)`` (e.g. ``Motion.qpos``);
    evaluating the 1 ms physics grid in blocks is then ~100x cheaper than one call per
    step.  That is used only when a probe shows the batched values equal the per-time
    ones bitwise, so the results never depend on it.
    """

    _BLOCK = 1024

    def __init__(self, fn: Callable, probe_times: np.ndarray) -> None:
        self.fn = fn
        self.vectorised = False
        single = np.stack([self.one(t) for t in probe_times])
        try:
            batch = np.asarray(fn(np.asarray(probe_times, dtype=np.float64)), dtype=np.float64)
        except Exception:  # noqa: BLE001 - any failure just means "not vectorised"
            return
        self.vectorised = batch.shape == single.shape and bool(np.array_equal(batch, single))

    def one(self, t: float) -> np.ndarray:
        q = np.asarray(self.fn(float(t)), dtype=np.float64)
        if q.shape != (NQ,) or not np.isfinite(q).all():
            raise ValueError(f"simulate: humanoid_qpos_fn({t}) must return {NQ} finite values, got shape {q.shape}")
        return q

    def many(self, ts: np.ndarray) -> np.ndarray:
        """``(n, 40)`` qpos at the times ``ts``."""
        if not self.vectorised:
            return np.stack([self.one(t) for t in ts]) if len(ts) else np.zeros((0, NQ))
        out = np.empty((len(ts), NQ))
        for a in range(0, len(ts), self._BLOCK):
            q = np.asarray(self.fn(ts[a : a + self._BLOCK]), dtype=np.float64)
            if q.shape != (len(ts[a : a + self._BLOCK]), NQ) or not np.isfinite(q).all():
                raise ValueError(f"simulate: humanoid_qpos_fn returned non-finite values or shape {q.shape} near t = {ts[a]}")
            out[a : a + len(q)] = q
        return out


def simulate(
    scene: Scene,
    humanoid_qpos_fn: Callable[[float], np.ndarray],
    times,
    timestep_s: float = PHYSICS_TIMESTEP_S,
) -> SceneStates:
    """States of the scene at the given instants.

    Parameters
    ----------
    scene : Scene
    humanoid_qpos_fn : callable
        ``f(t: float) -> (40,)`` humanoid MuJoCo qpos at time ``t`` seconds (e.g.
        ``Motion.qpos``).  If it also maps an array of n times to ``(n, 40)`` with
        the same values, it is called in blocks (much faster).
    times : (T,) float
        Increasing instants in seconds, ``>= 0``, any spacing (sub-frame times too).
    timestep_s : float
        Physics step of the props.

    Returns
    -------
    SceneStates
    """
    t_req = _check_times(times)
    if not 1e-5 <= timestep_s <= 0.01:
        raise ValueError(f"simulate: timestep_s = {timestep_s} is out of range (1e-5 .. 0.01 s)")
    model = _kinematic_model(scene)
    model.opt.timestep = timestep_s
    data = mujoco.MjData(model)
    scratch = mujoco.MjData(model)

    drive_fn = _Drive(humanoid_qpos_fn, np.array([0.0, 0.5 * timestep_s, t_req[-1]]))
    q_samples = drive_fn.many(t_req)
    dynamic = _initial_state(model, data, scene, drive_fn.one(0.0))
    physics = _PropPhysics(model, data, drive_fn, timestep_s, t_req[-1]) if dynamic else None

    site_ids = np.array([model.site(m.name).id for m in scene.marker_specs], dtype=np.int64)
    body_ids = np.array([model.body(n).id for n in BODY_NAMES], dtype=np.int64)
    qpos, xpos, xmat, markers = _sample(model, scratch, physics, t_req, q_samples, site_ids)
    return SceneStates(
        times=t_req.copy(),
        qpos=qpos,
        body_xpos=xpos,
        body_xmat=xmat,
        marker_xpos=markers,
        joint_centres=xpos[:, body_ids].copy(),
        prop_poses=_prop_poses(model, scene, xpos, xmat),
        marker_names=tuple(m.name for m in scene.marker_specs),
        body_names=tuple(model.body(b).name for b in range(model.nbody)),
    )


def _initial_state(model: mujoco.MjModel, data: mujoco.MjData, scene: Scene, q0: np.ndarray) -> bool:
    """Put ``data`` at t = 0: the humanoid at ``q0 (40,)``, each ball and moving prop at its initial velocity.

    Returns whether any prop moves (a ball or a moving prop), i.e. whether physics must run.
    """
    data.qpos[:NQ] = q0
    for p in scene.props:
        if isinstance(p, BallProp):
            adr = model.jnt_dofadr[model.joint(f"{p.name}_free").id]
            data.qvel[adr : adr + 6] = p.initial_qvel()
        elif isinstance(p, MovingProp):
            adr = model.jnt_dofadr[model.joint(f"{p.name}_slide").id]
            data.qvel[adr] = p.initial_qvel()[0]
    return any(isinstance(p, (BallProp, MovingProp)) for p in scene.props)


class _PropPhysics:
    """The props' physics on the fixed grid ``k * dt`` from t = 0, the humanoid driven kinematically.

    ``data`` holds the state at grid time ``k * dt``; :meth:`advance` steps it up to a
    requested instant and puts the state at that instant (one partial step) into a scratch copy.
    """

    def __init__(self, model: mujoco.MjModel, data: mujoco.MjData, drive_fn: _Drive, timestep_s: float, t_end: float) -> None:
        self.model, self.data, self.drive_fn, self.dt = model, data, drive_fn, timestep_s
        self.k = 0  # grid index: data holds the state at k * dt
        self.n_grid = int(np.floor(t_end / timestep_s + 1e-9)) + 2
        self._grid_block: dict[int, np.ndarray] = {}
        self._q1 = np.empty(model.nq)
        self._q2 = np.empty(model.nq)
        self._vel = np.empty(model.nv)

    def drive(self, d: mujoco.MjData, qa: np.ndarray, qb: np.ndarray, dt: float) -> None:
        """Put the humanoid of ``d`` at ``qa (40,)`` with the velocity that reaches ``qb (40,)`` after ``dt`` seconds."""
        self._q1[:] = d.qpos
        self._q2[:] = d.qpos
        self._q1[:NQ] = qa
        self._q2[:NQ] = qb
        mujoco.mj_differentiatePos(self.model, self._vel, dt, self._q1, self._q2)
        d.qpos[:NQ] = qa
        d.qvel[:NV] = self._vel[:NV]

    def q_grid(self, k: int) -> np.ndarray:
        """The humanoid's ``(40,)`` qpos at grid time ``k * dt``, evaluated in blocks as the loop needs them."""
        b = k // _Drive._BLOCK
        if b not in self._grid_block:
            self._grid_block.clear()
            ks = np.arange(b * _Drive._BLOCK, min((b + 1) * _Drive._BLOCK, self.n_grid))
            self._grid_block[b] = self.drive_fn.many(ks * self.dt)
        return self._grid_block[b][k - b * _Drive._BLOCK]

    def advance(self, ts: float, q_s: np.ndarray, scratch: mujoco.MjData) -> None:
        """Whole steps on the grid up to ``ts`` seconds, then ``scratch`` = the state at ``ts`` (humanoid at ``q_s (40,)``)."""
        model, data, dt = self.model, self.data, self.dt
        while (self.k + 1) * dt <= ts + 1e-12:
            self.drive(data, self.q_grid(self.k), self.q_grid(self.k + 1), dt)
            mujoco.mj_step(model, data)
            self.k += 1
        tau = ts - self.k * dt
        mujoco.mj_copyData(scratch, model, data)
        if tau > 1e-12:
            self.drive(scratch, self.q_grid(self.k), q_s, tau)
            model.opt.timestep = tau
            mujoco.mj_step(model, scratch)
            model.opt.timestep = dt


def _sample(model: mujoco.MjModel, scratch: mujoco.MjData, physics: _PropPhysics | None, t_req: np.ndarray,
            q_samples: np.ndarray, site_ids: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The scene's kinematics at each requested instant.

    Parameters
    ----------
    physics : _PropPhysics or None
        Steps the props (None: nothing moves but the humanoid).
    t_req : (T,) float
        Seconds, increasing.
    q_samples : (T, 40) float
        The humanoid's qpos at ``t_req``.
    site_ids : (M,) int
        MuJoCo site ids of the markers.

    Returns
    -------
    qpos (T, nq), body xpos (T, nbody, 3) metres, body xmat (T, nbody, 3, 3), markers (T, M, 3) metres.
    """
    T = len(t_req)
    qpos = np.empty((T, model.nq))
    xpos = np.empty((T, model.nbody, 3))
    xmat = np.empty((T, model.nbody, 3, 3))
    markers = np.empty((T, len(site_ids), 3))
    for i, ts in enumerate(t_req):
        q_s = q_samples[i]
        if physics is not None:
            physics.advance(ts, q_s, scratch)
        scratch.qpos[:NQ] = q_s  # the humanoid exactly where the motion puts it at ts
        mujoco.mj_kinematics(model, scratch)
        qpos[i] = scratch.qpos
        xpos[i] = scratch.xpos
        xmat[i] = scratch.xmat.reshape(-1, 3, 3)
        if len(site_ids):
            markers[i] = scratch.site_xpos[site_ids]
    return qpos, xpos, xmat, markers


def _prop_poses(model: mujoco.MjModel, scene: Scene, xpos: np.ndarray, xmat: np.ndarray) -> dict[str, np.ndarray]:
    """``prop name -> (T, 4, 4)`` world pose of its body, from body ``xpos (T, nbody, 3)`` and ``xmat (T, nbody, 3, 3)``."""
    prop_poses = {}
    for p in scene.props:
        bid = model.body(p.name).id
        P = np.zeros((len(xpos), 4, 4))
        P[:, :3, :3] = xmat[:, bid]
        P[:, :3, 3] = xpos[:, bid]
        P[:, 3, 3] = 1.0
        prop_poses[p.name] = P
    return prop_poses

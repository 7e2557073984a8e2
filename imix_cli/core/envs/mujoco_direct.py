"""Gymnasium's MuJoCo v5 locomotion tasks on the ``mujoco`` bindings directly, many episodes at once.

Why: a gymnasium MuJoCo ``step`` wraps one ``mj_step`` call in three wrappers, a dict of infos
and a dozen small numpy calls, and imix's generic evaluator adds a Python loop over members
around it. Here the physics of every member stays one ``mujoco.mj_step(model, data,
nstep=frame_skip)`` call on its own ``MjData`` (the engine does the same arithmetic as under
gymnasium), and everything around it -- observations, rewards, health checks -- is computed
once per env step for the whole batch with numpy.

What is reproduced, and how exactly: for ``Swimmer-v5``, ``Hopper-v5``, ``HalfCheetah-v5``,
``Walker2d-v5`` and ``Ant-v5`` with their default keyword arguments, the model is loaded from
gymnasium's own XML file (``gymnasium/envs/mujoco/assets``) and every quantity is computed as
the v5 classes compute it, operation for operation, so that observations, rewards and
terminations are bit-identical to ``gymnasium.make(id)`` given the same actions
(tests/test_mujoco_direct.py compares them step by step):

* reset: ``mj_resetData``, then ``qpos0 + uniform(-s, s, nq)`` and ``qvel0 + uniform(-s, s, nv)``
  (HalfCheetah and Ant: ``qvel0 + s * standard_normal(nv)``) drawn from
  ``np.random.default_rng(seed)`` -- the generator ``reset(seed=seed)`` seeds, consumed in the
  same order -- then ``mj_forward``;
* step: ``ctrl = action`` (float32, as gymnasium's Box action space), ``mj_step`` with the
  env's ``frame_skip``, then ``mj_rnePostConstraint`` (as ``MujocoEnv`` does: it fills
  ``cfrc_ext``, Ant's contact forces);
* reward: forward velocity ``(x_after - x_before) / dt`` (Swimmer, Ant: the x component of the
  xy velocity; Ant measures the torso body's ``xpos``), plus the healthy reward where the env
  has one, minus ``ctrl_cost_weight * sum(action**2)`` computed in float32 as gymnasium does
  on its float32 action (Ant: minus the contact cost too);
* termination: the v5 health checks (Hopper: state, height and angle ranges; Walker2d: height
  and angle; Ant: finite state and torso height); Swimmer and HalfCheetah never terminate;
* observation: ``qpos`` without the leading x (Swimmer, Ant: x and y) coordinates, ``qvel``
  (Hopper, Walker2d: clipped to [-10, 10]), Ant: the clipped external contact forces of every
  body but the world.

The episode cap (gymnasium's ``TimeLimit``, truncation) is the caller's: the evaluator stops
after ``max_steps``. Any other id, or other keyword arguments, is gymnasium's business.

Two implementations of :meth:`DirectEpisodes.step`, with the same results: for Swimmer, Hopper,
HalfCheetah and Walker2d the whole step of the batch is one numba call
(:mod:`imix_cli.core.envs.mujoco_kernels`, MuJoCo's C functions reached by address); Ant (contact
forces, 8 actions) and a MuJoCo build whose library cannot be found take the Python one: one
``mj_step`` binding call per member, then numpy over the batch. ``DirectEpisodes(id,
compiled=False)`` forces the Python one (the reference the tests hold the compiled one to).
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

__all__ = ["DIRECT_ENV_IDS", "DirectTask", "DirectEpisodes"]


@dataclass(frozen=True)
class DirectTask:
    """The default v5 keyword arguments of one task (each one as in gymnasium's ``<name>_v5.py``)."""

    env_id: str
    xml_file: str
    frame_skip: int
    ctrl_cost_weight: float
    reset_noise_scale: float
    normal_qvel_noise: bool = False  # HalfCheetah, Ant: qvel0 + scale * standard_normal(nv)
    skipped_qpos: int = 1  # leading qpos coordinates left out of the observation
    qvel_clip: float | None = None  # Hopper, Walker2d: the observation's qvel clipped to [-10, 10]
    forward_reward_weight: float = 1.0
    healthy_reward: float | None = None  # None: no healthy reward, never terminates
    healthy_z_range: tuple[float, float] = (-np.inf, np.inf)
    healthy_angle_range: tuple[float, float] | None = None  # Hopper, Walker2d: qpos[2]
    healthy_state_range: tuple[float, float] | None = None  # Hopper: state_vector()[2:]
    contact_cost_weight: float = 0.0  # Ant (and its cfrc_ext in the observation)
    contact_force_range: tuple[float, float] = (-1.0, 1.0)


DIRECT_TASKS: dict[str, DirectTask] = {
    task.env_id: task
    for task in (
        DirectTask("Swimmer-v5", "swimmer.xml", 4, 1e-4, 0.1, skipped_qpos=2),
        DirectTask("Hopper-v5", "hopper.xml", 4, 1e-3, 5e-3, qvel_clip=10.0, healthy_reward=1.0, healthy_z_range=(0.7, float("inf")),
                   healthy_angle_range=(-0.2, 0.2), healthy_state_range=(-100.0, 100.0)),
        DirectTask("HalfCheetah-v5", "half_cheetah.xml", 5, 0.1, 0.1, normal_qvel_noise=True),
        DirectTask("Walker2d-v5", "walker2d_v5.xml", 4, 1e-3, 5e-3, qvel_clip=10.0, healthy_reward=1.0, healthy_z_range=(0.8, 2.0),
                   healthy_angle_range=(-1.0, 1.0)),
        DirectTask("Ant-v5", "ant.xml", 5, 0.5, 0.1, normal_qvel_noise=True, skipped_qpos=2, forward_reward_weight=1, healthy_reward=1.0,
                   healthy_z_range=(0.2, 1.0), contact_cost_weight=5e-4),
    )
}  # fmt: skip

#: The gymnasium ids :class:`DirectEpisodes` reproduces.
DIRECT_ENV_IDS = tuple(DIRECT_TASKS)


def _xml_path(xml_file: str) -> str:
    """gymnasium's own model file (what ``MujocoEnv`` loads), found without importing gymnasium's MuJoCo envs."""
    import importlib.util

    spec = importlib.util.find_spec("gymnasium")
    return os.path.join(os.path.dirname(spec.origin), "envs", "mujoco", "assets", xml_file)


class DirectEpisodes:
    """A batch of episodes of one task: one ``MjData`` per member, stepped together (module docstring).

    ``reset(seeds) -> obs (n, obs_dim)`` starts member i's episode as ``reset(seed=seeds[i])``;
    ``step(rows, actions) -> (obs, rewards, terminated)`` steps the members at ``rows`` (indices
    into the reset batch) with float32 actions (len(rows), act_dim) and returns their new
    observations (float64), rewards (float64) and terminations (bool).
    """

    def __init__(self, env_id: str, compiled: bool | None = None):
        import mujoco

        if env_id not in DIRECT_TASKS:
            raise ValueError(f"{env_id!r} has no direct MuJoCo path (only {', '.join(DIRECT_ENV_IDS)})")
        self.task = task = DIRECT_TASKS[env_id]
        self.env_id = env_id
        self._mj = mujoco
        self.model = mujoco.MjModel.from_xml_path(_xml_path(task.xml_file))
        probe = mujoco.MjData(self.model)
        self.init_qpos, self.init_qvel = probe.qpos.ravel().copy(), probe.qvel.ravel().copy()
        self.nq, self.nv, self.nu = self.model.nq, self.model.nv, self.model.nu
        self.dt = self.model.opt.timestep * task.frame_skip  # MujocoEnv.dt
        bounds = self.model.actuator_ctrlrange.copy().astype(np.float32)  # MujocoEnv._set_action_space
        self.low, self.high = bounds[:, 0], bounds[:, 1]
        self.act_dim = self.nu
        self._contacts = task.contact_cost_weight > 0
        self._ncfrc = (self.model.nbody - 1) * 6 if self._contacts else 0
        self.obs_dim = self.nq - task.skipped_qpos + self.nv + self._ncfrc
        self._datas: list = [probe]
        self._views: list = [self._views_of(probe)]
        self._qpos = self._qvel = self._cfrc = self._xy = None
        self._kernel = self._compiled_step() if compiled is not False else None
        if compiled and self._kernel is None:
            raise ValueError(f"{env_id}: no compiled step (Ant's contact forces and 8 actions, or libmujoco not found)")
        self.compiled = self._kernel is not None

    def _compiled_step(self):
        """The compiled step (:mod:`imix_cli.core.envs.mujoco_kernels`) and its fixed arguments, or None where it does not apply."""
        task = self.task
        if self._contacts or self.nu >= 8:
            return None
        from imix_cli.core.envs import mujoco_kernels

        functions = mujoco_kernels.mujoco_function_addresses(self._mj)
        if functions is None:
            return None
        health = 0 if task.healthy_reward is None else (1 if task.healthy_state_range is not None else 2)
        ranges = [np.array(r if r is not None else (-np.inf, np.inf), dtype=np.float64)
                  for r in (task.healthy_z_range, task.healthy_angle_range, task.healthy_state_range)]  # fmt: skip
        settings = (float(self.dt), float(task.forward_reward_weight), np.float32(task.ctrl_cost_weight), int(task.skipped_qpos),
                    float(task.qvel_clip or 0.0), int(health), float(task.healthy_reward or 0.0), *ranges)  # fmt: skip
        return mujoco_kernels.advance, functions, settings

    def _views_of(self, data):
        """(ctrl, qpos, qvel, cfrc_ext, torso xpos): numpy views of one MjData's buffers, taken once."""
        return data.ctrl, data.qpos, data.qvel, data.cfrc_ext, data.xpos[1]

    def _grow(self, n: int) -> None:
        while len(self._datas) < n:
            data = self._mj.MjData(self.model)
            self._datas.append(data)
            self._views.append(self._views_of(data))

    def reset(self, seeds) -> np.ndarray:
        """Start one episode per seed (as ``reset(seed=s)``): observations (n, obs_dim)."""
        mj, task, model = self._mj, self.task, self.model
        n = len(seeds)
        self._grow(n)
        if self._kernel is not None:  # the buffers' addresses, for the compiled step
            datas = self._datas[:n]
            self._addresses = tuple(
                np.array(a, dtype=np.int64) for a in zip(*[(d._address, d.qpos.ctypes.data, d.qvel.ctypes.data, d.ctrl.ctypes.data) for d in datas])
            )
        self._qpos, self._qvel = np.empty((n, self.nq)), np.empty((n, self.nv))
        self._cfrc = np.empty((n, self.model.nbody, 6)) if self._contacts else None
        self._xy = np.empty((n, 2))
        low, high = -task.reset_noise_scale, task.reset_noise_scale
        for i, seed in enumerate(seeds):
            rng = np.random.default_rng(int(seed))  # = gymnasium's np_random after reset(seed=seed)
            data = self._datas[i]
            mj.mj_resetData(model, data)
            qpos = self.init_qpos + rng.uniform(low=low, high=high, size=self.nq)
            if task.normal_qvel_noise:
                qvel = self.init_qvel + task.reset_noise_scale * rng.standard_normal(self.nv)
            else:
                qvel = self.init_qvel + rng.uniform(low=low, high=high, size=self.nv)
            data.qpos[:] = qpos
            data.qvel[:] = qvel
            mj.mj_forward(model, data)
            self._read(i, i)
        return self._observations(np.arange(n))

    def set_state(self, member: int, qpos, qvel) -> np.ndarray:
        """Put member ``member`` (of the last reset) in state (qpos, qvel), as ``MujocoEnv.set_state``
        (then ``mj_forward``): its observation (obs_dim,). For tests of the health checks at chosen states."""
        data = self._datas[member]
        data.qpos[:] = np.asarray(qpos, dtype=np.float64)
        data.qvel[:] = np.asarray(qvel, dtype=np.float64)
        self._mj.mj_forward(self.model, data)
        self._read(member, member)
        return self._observations(np.array([member]))[0]

    def _read(self, i: int, member: int) -> None:
        _, qpos, qvel, cfrc, xpos = self._views[member]
        self._qpos[i] = qpos
        self._qvel[i] = qvel
        if self._contacts:
            self._cfrc[i] = cfrc
            self._xy[i] = xpos[:2]

    def _observations(self, rows: np.ndarray) -> np.ndarray:
        task = self.task
        qpos, qvel = self._qpos[rows], self._qvel[rows]
        if task.qvel_clip is not None:
            qvel = np.clip(qvel, -task.qvel_clip, task.qvel_clip)
        parts = [qpos[:, task.skipped_qpos :], qvel]
        if self._contacts:
            lo, hi = task.contact_force_range
            parts.append(np.clip(self._cfrc[rows], lo, hi)[:, 1:].reshape(len(rows), -1))
        return np.concatenate(parts, axis=1)

    def step(self, rows, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Step members ``rows`` with float32 ``actions`` (len(rows), act_dim): (obs, rewards, terminated)."""
        mj, task, model, frame_skip = self._mj, self.task, self.model, self.task.frame_skip
        rows = np.asarray(rows)
        if self._kernel is not None:
            kernel, (mj_step, mj_rne), settings = self._kernel
            obs, rewards, terminated = np.empty((len(rows), self.obs_dim)), np.empty(len(rows)), np.empty(len(rows), dtype=np.bool_)
            rows, actions = rows.astype(np.int64), np.ascontiguousarray(actions, dtype=np.float32)
            # the kernel reads raw addresses: a wrong index or shape would read other memory, not raise
            if actions.shape != (len(rows), self.nu) or (rows.size and (rows.min() < 0 or rows.max() >= len(self._addresses[0]))):
                raise ValueError(f"{self.env_id}: step needs rows among the {len(self._addresses[0])} reset members and actions ({len(rows)}, {self.nu})")
            kernel((mj_step, mj_rne), model._address, self._addresses, (self.nq, self.nv, frame_skip), rows, actions, settings, (obs, rewards, terminated))
            return obs, rewards, terminated
        if self._contacts:  # Ant: the torso body's position, before and after
            before = self._xy[rows, 0].copy()
        else:
            before = self._qpos[rows, 0].copy()
        step, rne, views = mj.mj_step, mj.mj_rnePostConstraint, self._views
        qpos_all, qvel_all = self._qpos, self._qvel
        for k, i in enumerate(rows.tolist()):
            data = self._datas[i]
            ctrl, qpos, qvel, cfrc, xpos = views[i]
            ctrl[:] = actions[k]
            step(model, data, nstep=frame_skip)
            rne(model, data)
            qpos_all[i] = qpos
            qvel_all[i] = qvel
            if self._contacts:
                self._cfrc[i] = cfrc
                self._xy[i] = xpos[:2]
        after = self._xy[rows, 0] if self._contacts else self._qpos[rows, 0]
        x_velocity = (after - before) / self.dt
        forward = task.forward_reward_weight * x_velocity
        ctrl_cost = task.ctrl_cost_weight * np.sum(np.square(actions), axis=1)  # float32, as on gymnasium's float32 action
        if task.healthy_reward is None:
            reward = forward - ctrl_cost
            terminated = np.zeros(len(rows), dtype=bool)
        else:
            healthy = self._healthy(rows)
            rewards = forward + healthy * task.healthy_reward
            costs = ctrl_cost
            if self._contacts:
                lo, hi = task.contact_force_range
                costs = ctrl_cost + task.contact_cost_weight * np.sum(np.square(np.clip(self._cfrc[rows], lo, hi)), axis=(1, 2))
            reward = rewards - costs
            terminated = ~healthy
        return self._observations(rows), reward, terminated

    def _healthy(self, rows: np.ndarray) -> np.ndarray:
        task = self.task
        qpos, qvel = self._qpos[rows], self._qvel[rows]
        if self._contacts:  # Ant: finite state and lo <= z <= hi
            lo, hi = task.healthy_z_range
            z = qpos[:, 2]
            return np.isfinite(qpos).all(axis=1) & np.isfinite(qvel).all(axis=1) & (lo <= z) & (z <= hi)
        z, angle = qpos[:, 1], qpos[:, 2]
        lo, hi = task.healthy_z_range
        healthy = (lo < z) & (z < hi)
        lo, hi = task.healthy_angle_range
        healthy &= (lo < angle) & (angle < hi)
        if task.healthy_state_range is not None:
            lo, hi = task.healthy_state_range
            state = np.concatenate([qpos[:, 2:], qvel], axis=1)
            healthy &= np.all((lo < state) & (state < hi), axis=1)
        return healthy

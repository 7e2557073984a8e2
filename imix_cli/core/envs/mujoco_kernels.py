"""One env step of many MuJoCo episodes in one compiled call (numba), MuJoCo's C functions called directly.

Why: :meth:`imix_cli.core.envs.mujoco_direct.DirectEpisodes.step` in Python costs a few
microseconds per member around each ``mj_step`` (binding calls, buffer copies) and a few dozen
numpy calls per env step of the batch; with short episodes (Hopper, Walker2d) and few members
left alive that is a large share of a step. Here the whole step of the batch -- controls,
``mj_step`` x frame_skip, ``mj_rnePostConstraint``, observations, rewards, health checks -- is
one call. The physics is the same C code the bindings call (``libmujoco``'s ``mj_step`` and
``mj_rnePostConstraint`` on the same ``mjModel``/``mjData``, reached by address), and every
other quantity is computed in the order numpy computes it, so the results stay bit-identical to
gymnasium's (tests/test_mujoco_direct.py runs both paths against gymnasium):

* the float32 ctrl cost ``w * sum(action**2)``: numpy sums fewer than 8 float32 values one after
  the other (its pairwise sum starts blocking at 8), hence ``nu < 8`` here (Ant, nu = 8, stays on
  the Python path);
* ``np.clip`` keeps NaN, as the comparisons below do.

The C functions are called through their addresses, passed as integers (not as ctypes
globals), so that numba can cache the machine code on disk. The buffers of each ``mjData``
(qpos, qvel, ctrl) are read and written through their addresses too; the caller keeps the
``MjData`` objects alive.
"""

from __future__ import annotations

import ctypes
import glob
import os

import numba
import numpy as np
from llvmlite import ir
from numba import types
from numba.extending import intrinsic

__all__ = ["mujoco_function_addresses", "advance"]


def mujoco_function_addresses(mujoco) -> tuple[int, int] | None:
    """(address of ``mj_step``, address of ``mj_rnePostConstraint``) in the library the bindings
    loaded, or None if it cannot be found (then the Python path runs)."""
    folder = os.path.dirname(mujoco.__file__)
    candidates = sorted(glob.glob(os.path.join(folder, "libmujoco.so*")) + glob.glob(os.path.join(folder, "libmujoco*.dylib")))
    candidates += glob.glob(os.path.join(folder, "mujoco.dll"))
    for path in candidates:
        try:
            lib = ctypes.CDLL(path)
            return ctypes.cast(lib.mj_step, ctypes.c_void_p).value, ctypes.cast(lib.mj_rnePostConstraint, ctypes.c_void_p).value
        except (OSError, AttributeError):
            continue
    return None


@intrinsic
def _call_model_data(typingctx, function, model, data):
    """``function(model, data)`` for a C function ``void f(const mjModel*, mjData*)`` given by address."""
    sig = types.void(types.int64, types.int64, types.int64)

    def codegen(context, builder, signature, args):
        pointer = ir.IntType(8).as_pointer()
        fn = builder.inttoptr(args[0], ir.FunctionType(ir.VoidType(), [pointer, pointer]).as_pointer())
        builder.call(fn, [builder.inttoptr(args[1], pointer), builder.inttoptr(args[2], pointer)])
        return context.get_dummy_value()

    return sig, codegen


@intrinsic
def _float64_pointer(typingctx, address):
    sig = types.CPointer(types.float64)(types.int64)

    def codegen(context, builder, signature, args):
        return builder.inttoptr(args[0], context.get_value_type(types.CPointer(types.float64)))

    return sig, codegen


@numba.njit(cache=True)
def _inside(value, low, high):
    return low < value and value < high


@numba.njit(cache=True)
def advance(functions, model, buffers, sizes, rows, actions, task, out):
    """Step members ``rows`` with float32 ``actions`` (k, nu); fill ``out``: ``obs`` (k, obs_dim), ``rewards`` and
    ``terminated`` (k,).

    Grouped as the caller holds them (tuples; numba types each field): ``functions`` libmujoco's ``(mj_step,
    mj_rnePostConstraint)`` addresses; ``buffers`` the reset members' ``(MjData, qpos, qvel, ctrl)`` addresses (int64
    arrays); ``sizes`` ``(nq, nv, frame_skip)``; ``task`` the reward's settings ``(dt, forward_weight, ctrl_weight
    (float32), skipped_qpos, qvel_clip, health, healthy_reward, z_range, angle_range, state_range)``.
    ``health``: 0 none (Swimmer, HalfCheetah), 1 Hopper (state, z and angle ranges), 2 Walker2d
    (z and angle). ``qvel_clip`` <= 0: no clipping. Ranges are (low, high) float64 arrays, strict bounds.
    """
    mj_step, mj_rne = functions
    data, qpos_at, qvel_at, ctrl_at = buffers
    nq, nv, frame_skip = sizes
    dt, forward_weight, ctrl_weight, skipped_qpos, qvel_clip, health, healthy_reward, z_range, angle_range, state_range = task
    obs, rewards, terminated = out
    nu = actions.shape[1]
    for k in range(rows.shape[0]):
        i = rows[k]
        qpos = numba.carray(_float64_pointer(qpos_at[i]), (nq,))
        qvel = numba.carray(_float64_pointer(qvel_at[i]), (nv,))
        ctrl = numba.carray(_float64_pointer(ctrl_at[i]), (nu,))
        before = qpos[0]
        for j in range(nu):
            ctrl[j] = np.float64(actions[k, j])
        for _ in range(frame_skip):
            _call_model_data(mj_step, model, data[i])
        _call_model_data(mj_rne, model, data[i])
        x_velocity = (qpos[0] - before) / dt
        cost = actions[k, 0] * actions[k, 0]  # float32 throughout, summed in order (nu < 8)
        for j in range(1, nu):
            cost += actions[k, j] * actions[k, j]
        cost = ctrl_weight * cost
        for j in range(skipped_qpos, nq):
            obs[k, j - skipped_qpos] = qpos[j]
        for j in range(nv):
            v = qvel[j]
            if qvel_clip > 0.0:
                if v < -qvel_clip:
                    v = -qvel_clip
                elif v > qvel_clip:
                    v = qvel_clip
            obs[k, nq - skipped_qpos + j] = v
        forward = forward_weight * x_velocity
        if health == 0:
            rewards[k] = forward - np.float64(cost)
            terminated[k] = False
            continue
        healthy = _inside(qpos[1], z_range[0], z_range[1]) and _inside(qpos[2], angle_range[0], angle_range[1])
        if health == 1:
            for j in range(2, nq):
                healthy = healthy and _inside(qpos[j], state_range[0], state_range[1])
            for j in range(nv):
                healthy = healthy and _inside(qvel[j], state_range[0], state_range[1])
        rewards[k] = (forward + (healthy_reward if healthy else 0.0)) - np.float64(cost)
        terminated[k] = not healthy

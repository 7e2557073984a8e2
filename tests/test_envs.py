"""Compiled environments and evaluator: equivalence with gymnasium (directly: there is no other
implementation to compare with), batch independence, determinism."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest

from imix_cli.core.envs import kernels, seeded_uniform
from imix_cli.core.evaluation import make_evaluator
from imix_cli.core.evaluation.policies import BatchPolicy, act, forward, num_params

MAX_VEL = np.array([4 * np.pi, 9 * np.pi])


# ---------------------------------------------------------------------------------- helpers
def linear_mlp(obs_weights, out_row):
    """MLP params whose decision is sign(obs @ obs_weights), read out with ``out_row`` (8-8 hidden)."""
    obs_weights = np.asarray(obs_weights, dtype=float)
    obs_dim, out_dim = obs_weights.size, len(out_row)
    W1 = np.zeros((obs_dim, 8))
    W1[:, 0] = obs_weights
    W2 = np.zeros((8, 8))
    W2[0, 0] = 1.0
    W3 = np.zeros((8, out_dim))
    W3[0] = out_row
    return np.concatenate([W1.ravel(), np.zeros(8), W2.ravel(), np.zeros(8), W3.ravel(), np.zeros(out_dim)])


def cartpole_params(rng, n_random=12, n_good=12):
    """Random members (short episodes) and noisy balancers (mostly the full 200 steps)."""
    good = linear_mlp([0, 0, 1, 1], [-1, 1]) + 0.05 * rng.standard_normal((n_good, 130))
    return np.vstack([rng.standard_normal((n_random, 130)), good])


def acrobot_params(rng, n_random=8, n_good=12):
    """Random members (mostly 200 steps) and noisy swing-up pumpers (terminate in ~70-130 steps)."""
    good = linear_mlp([0, 0, 0, 0, 0, 1], [-1, 0, 1]) + 0.05 * rng.standard_normal((n_good, 155))
    return np.vstack([2 * rng.standard_normal((n_random, 155)), good])


def reference_outputs(p, obs, sizes):
    """The MLP in plain Python floats (math.tanh, sums in layer order): what the kernels compute."""
    x, k = [float(v) for v in obs], 0
    for layer, (n_in, n_out) in enumerate(zip(sizes[:-1], sizes[1:])):
        y = []
        for j in range(n_out):
            acc = 0.0
            for i in range(n_in):
                acc += float(p[k + i * n_out + j]) * x[i]
            acc = acc + float(p[k + n_in * n_out + j])
            y.append(math.tanh(acc) if layer < len(sizes) - 2 else acc)
        k += n_in * n_out + n_out
        x = y
    return x


def reference_action(p, obs, sizes):
    y = reference_outputs(p, obs, sizes)
    return max(range(len(y)), key=lambda j: (y[j], -j))  # argmax, ties to the lowest index


def random_acrobot_states(rng, n):
    return np.column_stack([rng.uniform(-np.pi, np.pi, (n, 2)), rng.uniform(-MAX_VEL[0], MAX_VEL[0], n), rng.uniform(-MAX_VEL[1], MAX_VEL[1], n)])


# ---------------------------------------------------------------------------------- policies
def test_param_counts():
    assert num_params(4, 2) == 130
    assert num_params(6, 3) == 155
    assert make_evaluator("cartpole").num_params == 130
    assert make_evaluator("acrobot").num_params == 155


@pytest.mark.parametrize("obs_dim,out_dim", [(4, 2), (6, 3), (3, 1)])
def test_policy_layout_and_actions(obs_dim, out_dim):
    rng = np.random.default_rng(0)
    B = 23
    P = rng.standard_normal((B, num_params(obs_dim, out_dim)))
    X = rng.standard_normal((B, obs_dim)).astype(np.float32)
    ref = []
    for p, x in zip(P, X.astype(np.float64)):  # the documented flat layout, sliced by hand
        k = 0
        W1 = p[k : k + obs_dim * 8].reshape(obs_dim, 8)
        k += obs_dim * 8  # noqa: E702
        b1 = p[k : k + 8]
        k += 8  # noqa: E702
        W2 = p[k : k + 64].reshape(8, 8)
        k += 64  # noqa: E702
        b2 = p[k : k + 8]
        k += 8  # noqa: E702
        W3 = p[k : k + 8 * out_dim].reshape(8, out_dim)
        k += 8 * out_dim  # noqa: E702
        b3 = p[k : k + out_dim]
        k += out_dim  # noqa: E702
        assert k == p.size
        ref.append(np.tanh(np.tanh(x @ W1 + b1) @ W2 + b2) @ W3 + b3)
    ref = np.array(ref)
    np.testing.assert_allclose(forward(P, X, out_dim), ref, rtol=0, atol=1e-12)
    a = act(P, X, out_dim)
    assert a.dtype == np.int64 and a.shape == (B,)
    np.testing.assert_array_equal(a, np.argmax(ref, axis=1))
    np.testing.assert_allclose(act(P, X, out_dim, discrete=False), np.tanh(ref), atol=1e-12)
    lo, hi = -2.0, 3.0
    np.testing.assert_allclose(act(P, X, out_dim, discrete=False, low=lo, high=hi), lo + (np.tanh(ref) + 1) * (hi - lo) / 2, atol=1e-12)
    # each member's output is the same alone as in the batch
    for i in (0, 7, B - 1):
        np.testing.assert_array_equal(forward(P[i : i + 1], X[i : i + 1], out_dim)[0], forward(P, X, out_dim)[i])


def test_seeded_uniform_matches_numpy():
    rng = np.random.default_rng(0)
    seeds = np.concatenate(
        [
            np.array([0, 1, 2**32 - 1, 2**32, 2**63, 2**64 - 1], dtype=np.uint64),
            rng.integers(0, 2**64 - 1, 500, dtype=np.uint64, endpoint=True),
            np.arange(200, dtype=np.uint64),
        ]
    )
    for low, high in [(-0.05, 0.05), (-0.1, 0.1)]:
        ref = np.array([np.random.default_rng(int(s)).uniform(low, high, 4) for s in seeds])
        np.testing.assert_array_equal(seeded_uniform(seeds, low, high, 4), ref)
    np.testing.assert_array_equal(seeded_uniform(np.arange(10), -1, 2, 3), [np.random.default_rng(s).uniform(-1, 2, 3) for s in range(10)])


# ---------------------------------------------------------------------------------- policy (compiled)
@pytest.mark.parametrize("sizes", [(4, 8, 8, 2), (6, 8, 8, 3), (4, 8, 8, 1), (3, 5, 2), (4, 16, 7, 9, 2)])
def test_compiled_mlp_is_the_documented_layout(sizes):
    """kernels.mlp_forward == the flat layout of imix_cli.core.evaluation.policies, evaluated in plain Python,
    bit for bit (any layer sizes); and to round-off the numpy BatchPolicy of the generic path."""
    rng = np.random.default_rng(9)
    sizes_arr = np.array(sizes, dtype=np.int64)
    d = num_params(sizes[0], sizes[-1], sizes[1:-1])
    for _ in range(50):
        p = rng.standard_normal(d)
        obs = rng.standard_normal(sizes[0])
        x, y = np.zeros(max(sizes)), np.zeros(max(sizes))
        x[: sizes[0]] = obs
        out = kernels.mlp_forward(p, sizes_arr, x, y)[: sizes[-1]]
        assert list(out) == reference_outputs(p, obs, sizes)
        ref = BatchPolicy(p[None], sizes[0], sizes[-1], hidden=sizes[1:-1]).outputs(obs[None])[0]
        np.testing.assert_allclose(out, ref, rtol=0, atol=1e-12)


# ---------------------------------------------------------------------------------- acrobot
def test_acrobot_dsdt_matches_gymnasium():
    env = gym.make("Acrobot-v1").unwrapped
    rng = np.random.default_rng(1)
    n = 3000
    s_aug = np.column_stack([random_acrobot_states(rng, n) * 1.5, rng.choice([-1.0, 0.0, 1.0], n)])
    ref = np.array([env._dsdt(row)[:4] for row in s_aug], dtype=np.float64)
    got, k = np.empty((n, 4)), np.empty(4)
    for i, row in enumerate(s_aug):
        kernels.acrobot_dsdt(*row, k)
        got[i] = k
    np.testing.assert_allclose(got, ref, rtol=1e-12, atol=1e-12)
    assert np.mean(np.all(got == ref, axis=1)) > 0.99  # only gymnasium's pow(x, 2) rounding differs, rarely


def _acrobot_test_states(rng):
    """Random states over the whole box, plus states visited by swing-up episodes (near the goal)."""
    _, steps, trace = make_evaluator("acrobot").trajectories(acrobot_params(rng, 4, 16), rng.integers(0, 2**32, 20))
    visited = [trace[i, : steps[i]] for i in range(len(steps))]
    return np.vstack([random_acrobot_states(rng, 3000), *visited])


def test_acrobot_steps_match_gymnasium():
    """kernels.acrobot_steps == AcrobotEnv.step from the same states: next states within 1e-12,
    identical terminations, rewards and (float32) observations, over ~6000 states."""
    env = gym.make("Acrobot-v1").unwrapped
    rng = np.random.default_rng(2)
    S = _acrobot_test_states(rng)
    A = rng.integers(0, 3, len(S))
    ref_state, ref_obs, ref_rew, ref_term = [], [], [], []
    for s, a in zip(S, A):
        env.state = s.copy()
        obs, rew, term, trunc, _ = env.step(int(a))
        assert not trunc
        ref_state.append(env.state)
        ref_obs.append(obs)
        ref_rew.append(rew)
        ref_term.append(term)
    ref_state, ref_obs = np.array(ref_state), np.array(ref_obs)
    ref_rew, ref_term = np.array(ref_rew), np.array(ref_term)
    state, obs, term = kernels.acrobot_steps(S, A)
    # the comparison covers terminations, angle wrapping and velocity clipping
    assert len(S) > 4000 and ref_term.sum() > 100
    assert (np.abs(ref_state[:, :2]) > 3.0).sum() > 100 and (np.abs(ref_state[:, 2:]) == MAX_VEL).sum() > 100
    assert np.abs(state - ref_state).max() <= 1e-12
    assert np.mean(np.all(state == ref_state, axis=1)) > 0.99
    np.testing.assert_array_equal(term, ref_term)
    np.testing.assert_array_equal(np.where(term, 0.0, -1.0), ref_rew)
    assert obs.dtype == np.float32
    np.testing.assert_allclose(obs, ref_obs, rtol=0, atol=1e-6)


def _check_episodes_against_gymnasium(env_id, evaluator, P, seeds, act, tolerance):
    """Each member's compiled episode against gymnasium's env from reset(seed=s), step by step.

    At every step the env is put in the kernel's state (so round-off cannot build up in a
    chaotic system), the reference policy ``act(p, obs)`` picks the action from the env's own
    observation, and the env's next state must match the kernel's next state within
    ``tolerance``; terminations, lengths and returns must be identical.
    """
    returns, steps, trace = evaluator.trajectories(P, seeds)
    env = gym.make(env_id, max_episode_steps=evaluator.max_steps)
    worst = 0.0
    for i, seed in enumerate(seeds):
        obs, _ = env.reset(seed=int(seed))
        np.testing.assert_array_equal(env.unwrapped.state, trace[i, 0])  # reset(seed) == the kernel's start
        ret, t, done = 0.0, 0, False
        while not done:
            if t:
                env.unwrapped.state = trace[i, t].copy()
                obs = np.array(env.unwrapped.state, dtype=np.float32) if "CartPole" in env_id else env.unwrapped._get_ob()
            obs, r, term, trunc, _ = env.step(act(P[i], obs))
            ret, t, done = ret + r, t + 1, term or trunc
            worst = max(worst, np.abs(np.asarray(env.unwrapped.state, dtype=np.float64) - trace[i, t]).max())
            assert term == (t == steps[i] and (t < evaluator.max_steps or term)), (i, t)
        assert (t, ret) == (steps[i], returns[i]), i
    assert worst <= tolerance
    return steps


def test_acrobot_episodes_match_gymnasium():
    rng = np.random.default_rng(3)
    P = acrobot_params(rng, 6, 10)
    seeds = rng.integers(0, 2**63, len(P), dtype=np.uint64)
    sizes = (6, 8, 8, 3)
    steps = _check_episodes_against_gymnasium("Acrobot-v1", make_evaluator("acrobot"), P, seeds, lambda p, o: reference_action(p, o, sizes), 1e-12)
    assert sum(s < 200 for s in steps) >= 8  # terminations are exercised


# ---------------------------------------------------------------------------------- cartpole
def test_cartpole_episodes_match_gymnasium_bit_for_bit():
    """Compiled episodes == CartPole-v1 episodes from reset(seed=s), capped at 200, every state exact."""
    rng = np.random.default_rng(4)
    P = cartpole_params(rng, 12, 12)
    seeds = rng.integers(0, 2**63, len(P), dtype=np.uint64)
    sizes = (4, 8, 8, 2)
    steps = _check_episodes_against_gymnasium("CartPole-v1", make_evaluator("cartpole"), P, seeds, lambda p, o: reference_action(p, o, sizes), 0.0)
    assert min(steps) < 50 and max(steps) == 200


@pytest.mark.parametrize("env,env_id", [("cartpole", "CartPole-v1"), ("acrobot", "Acrobot-v1")])
def test_compiled_episodes_follow_the_evaluators_hidden_sizes(env, env_id):
    """The kernels take the layer sizes from the evaluator (``hidden``), any depth and width."""
    ev = make_evaluator(env)
    ev.hidden = (5, 3, 4)
    sizes = (ev.obs_dim, *ev.hidden, ev.out_dim)
    assert ev.num_params == num_params(ev.obs_dim, ev.out_dim, ev.hidden)
    rng = np.random.default_rng(13)
    P = rng.standard_normal((8, ev.num_params))
    steps = _check_episodes_against_gymnasium(
        env_id,
        ev,
        P,
        rng.integers(0, 2**63, 8, dtype=np.uint64),
        lambda p, o: reference_action(p, o, sizes),
        0.0 if env == "cartpole" else 1e-12,
    )
    assert env == "acrobot" or len(set(steps)) > 2  # (random Acrobot policies all hang on for 200 steps)


def test_cartpole_steps_equal_gymnasium_bit_for_bit():
    """kernels.cartpole_steps == CartPoleEnv.step from the same states, bit for bit, over 20000
    random states (both sides of the termination limits, large velocities) and actions."""
    env = gym.make("CartPole-v1").unwrapped
    rng = np.random.default_rng(12)
    n = 20000
    S = rng.uniform(-1, 1, (n, 4)) * np.array([3.0, 4.0, 0.3, 4.0])  # x, x_dot, theta, theta_dot
    A = rng.integers(0, 2, n)
    ref_state, ref_obs, ref_term = [], [], []
    for s, a in zip(S, A):
        env.state, env.steps_beyond_terminated = s.copy(), None
        obs, _, term, _, _ = env.step(int(a))
        ref_state.append(env.state)
        ref_obs.append(obs)
        ref_term.append(term)
    state, term = kernels.cartpole_steps(S, np.where(A == 1, 10.0, -10.0))
    np.testing.assert_array_equal(state, np.array(ref_state))
    np.testing.assert_array_equal(state.astype(np.float32), np.array(ref_obs))
    np.testing.assert_array_equal(term, ref_term)
    assert 0.2 * n < term.sum() < 0.9 * n  # both outcomes exercised


# ---------------------------------------------------------------------------------- evaluator
def _params_for(name, ev, rng):
    if name == "cartpole":
        return cartpole_params(rng, 10, 10)
    if name == "acrobot":
        return acrobot_params(rng, 6, 8)
    return rng.standard_normal((8, ev.num_params))


@pytest.mark.parametrize("name,max_steps", [("cartpole", None), ("acrobot", None), ("MountainCar-v0", None), ("Pendulum-v1", 60)])
def test_batch_independence_and_determinism(name, max_steps):
    rng = np.random.default_rng(5)
    ev = make_evaluator(name, max_steps)
    P = _params_for(name, ev, rng)
    B = len(P)
    seeds = rng.integers(0, 2**63, B, dtype=np.uint64)
    r, s = ev.evaluate(P, seeds)
    assert r.shape == s.shape == (B,) and r.dtype == np.float64 and s.dtype == np.int64
    assert np.all((s >= 1) & (s <= ev.max_steps))
    # determinism
    r2, s2 = ev.evaluate(P, seeds)
    np.testing.assert_array_equal(r2, r)
    np.testing.assert_array_equal(s2, s)
    # alone
    for i in range(B):
        ri, si = ev.evaluate(P[i : i + 1], seeds[i : i + 1])
        assert (ri[0], si[0]) == (r[i], s[i]), i
    # shuffled, and mixed into a larger batch with other members
    perm = rng.permutation(B)
    rp, sp = ev.evaluate(P[perm], seeds[perm])
    np.testing.assert_array_equal(rp, r[perm])
    np.testing.assert_array_equal(sp, s[perm])
    others = _params_for(name, ev, np.random.default_rng(6))
    big_P = np.vstack([others[:3], P, others[3:]])
    other_seeds = rng.integers(0, 2**63, len(others), dtype=np.uint64)
    big_seeds = np.concatenate([other_seeds[:3], seeds, other_seeds[3:]])
    rb, sb = ev.evaluate(big_P, big_seeds)
    np.testing.assert_array_equal(rb[3 : 3 + B], r)
    np.testing.assert_array_equal(sb[3 : 3 + B], s)
    if name == "cartpole":
        assert np.array_equal(r, s) and s.min() < 50 and s.max() == 200
    if name == "Pendulum-v1":
        assert not ev.discrete and np.all(s == 60)


def test_generic_matches_single_env():
    """The generic path plays exactly the single-env episode of reset(seed=s)."""
    rng = np.random.default_rng(7)
    ev = make_evaluator("Pendulum-v1", max_steps=30)
    P = rng.standard_normal((4, ev.num_params))
    seeds = np.arange(4) + 10
    r, s = ev.evaluate(P, seeds)
    env = gym.make("Pendulum-v1", max_episode_steps=30)
    for i in range(4):
        pol = BatchPolicy(P[i : i + 1], 3, 1, discrete=False, low=-2.0, high=2.0)
        o, _ = env.reset(seed=int(seeds[i]))
        ret, t, done = 0.0, 0, False
        while not done:
            o, rew, term, trunc, _ = env.step(pol(o[None])[0].astype(np.float32))
            ret, t, done = ret + rew, t + 1, term or trunc
        assert (t, ret) == (s[i], r[i])


def test_max_steps_and_empty_batch():
    ev = make_evaluator("cartpole", max_steps=20)
    P = cartpole_params(np.random.default_rng(8), 0, 5)
    r, s = ev.evaluate(P, np.arange(5))
    assert np.all(s == 20) and np.all(r == 20)
    r, s = ev.evaluate(np.zeros((0, 130)), np.zeros(0, dtype=np.int64))
    assert r.shape == s.shape == (0,)
    with pytest.raises(ValueError):
        ev.evaluate(P[:, :-1], np.arange(5))
    with pytest.raises(ValueError):
        ev.evaluate(P, np.arange(4))


@pytest.mark.parametrize("bad", ["Foo-v0", "NotAnEnv", "CartPole-v99"])
def test_unknown_env_id(bad):
    with pytest.raises(ValueError) as info:
        make_evaluator(bad)
    msg = str(info.value)
    assert bad in msg and "\n" not in msg


def test_kernels_refuse_params_that_do_not_fit_the_layer_sizes():
    """The kernels read parameters without bounds checks: a layout mismatch must raise, not read past the rows."""
    sizes = np.array([4, 8, 8, 2], dtype=np.int64)
    out, steps = np.empty(1), np.empty(1, dtype=np.int64)
    for d in (129, 131):
        with pytest.raises(ValueError, match="parameter count"):
            kernels.cartpole_episodes(np.zeros((1, d)), np.zeros(1, np.uint64), sizes, False, False, 5, out, steps, np.empty((0, 0, 0)))
    with pytest.raises(ValueError, match="parameter count"):
        kernels.acrobot_episodes(np.zeros((1, 130)), np.zeros((1, 4)), np.zeros((1, 6)), np.array([6, 8, 8, 3]), 5, out, steps, np.empty((0, 0, 0)))


def test_acrobot_episodes_in_lanes_equal_one_at_a_time():
    """From LANES_FROM members on, Acrobot episodes run LANES at a time too (a lane whose episode ends takes the next
    member): every member's return, length and states must be those of its episode run alone, bit for bit, whether
    it ends by swinging up (65-200 steps: noisy energy pumpers) or at the cap (random members). Made to fail by
    not resetting a reused lane's return and by giving a new member's lane the previous member's observation."""
    from imix_cli.core.envs import kernels

    rng = np.random.default_rng(21)
    sizes = np.array([6, 8, 8, 3], dtype=np.int64)
    n = 3 * kernels.LANES_FROM + 5
    pumper = linear_mlp([0, 0, 0, 0, -1, 1], [-1, 0, 1])  # torque along the second joint's relative swing
    params = np.vstack([pumper + 0.05 * rng.standard_normal((n // 2, pumper.size)), rng.standard_normal((n - n // 2, pumper.size))])
    params = params[rng.permutation(n)]
    seeds = rng.integers(0, 2**63, n).astype(np.uint64)
    returns, steps, trace = np.empty(n), np.empty(n, dtype=np.int64), np.full((n, 201, 4), np.nan)
    kernels.acrobot_seeded_episodes(params, seeds, sizes, 200, returns, steps, trace)
    assert steps.min() < 120 and steps.max() == 200
    for i in range(n):
        r1, s1, t1 = np.empty(1), np.empty(1, dtype=np.int64), np.full((1, 201, 4), np.nan)
        kernels.acrobot_seeded_episodes(params[i : i + 1], seeds[i : i + 1], sizes, 200, r1, s1, t1)
        assert (returns[i], steps[i]) == (r1[0], s1[0]), i
        assert np.array_equal(trace[i], t1[0], equal_nan=True), i


def test_acrobot_episodes_equal_steps_computed_afresh_bit_for_bit():
    """The episode kernels, one member at a time and in lanes, must give every member the states, length and return of a
    loop of single steps whose observation is computed afresh (kernels.acrobot_steps, the test entry point), bit for
    bit: the guard for any change to how an episode carries its state (the step's cosines and sines shared with the
    observation were tried this way, and dropped as slower). Made to fail by skipping the observation's refresh on
    every 50th step of the one-at-a-time loop."""
    from imix_cli.core.envs import kernels

    rng = np.random.default_rng(22)
    sizes = np.array([6, 8, 8, 3], dtype=np.int64)
    n = 2 * kernels.LANES_FROM + 3
    pumper = linear_mlp([0, 0, 0, 0, -1, 1], [-1, 0, 1])
    params = np.vstack([pumper + 0.05 * rng.standard_normal((n // 2, pumper.size)), 3 * rng.standard_normal((n - n // 2, pumper.size))])
    seeds = rng.integers(0, 2**63, n).astype(np.uint64)
    s32 = kernels.seeded_uniform_rows(seeds, -0.1, 0.1, 4).astype(np.float32)
    obs0 = kernels.acrobot_first_observations(s32)
    wrapped = 0
    for many in (True, False):  # in lanes (n >= LANES_FROM), then each member alone
        members = [np.arange(n)] if many else [np.array([i]) for i in range(n)]
        for m in members:
            returns, steps, trace = np.empty(len(m)), np.empty(len(m), dtype=np.int64), np.full((len(m), 201, 4), np.nan)
            kernels.acrobot_seeded_episodes(params[m], seeds[m], sizes, 200, returns, steps, trace)
            for row, i in enumerate(m):
                state, x = s32[i : i + 1].astype(np.float64), obs0[i].copy()
                for t in range(200):
                    out = kernels.mlp_forward(params[i], sizes, np.resize(x, 8), np.empty(8))[:3]
                    state, obs, term = kernels.acrobot_steps(state, np.array([int(np.argmax(out))]))
                    assert np.array_equal(state[0], trace[row, t + 1]), (many, i, t)
                    wrapped += int(np.abs(state[0, :2]).max() > 3.0)
                    x = obs[0].astype(np.float64)
                    if term[0]:
                        break
                assert (steps[row], returns[row]) == (t + 1, -float(t + 1 - term[0])), (many, i)
    assert wrapped > 50  # the angles' wrap is exercised


@pytest.mark.parametrize("continuous,sparse", [(False, False), (True, False), (True, True)], ids=["CartPole", "Continuous", "ContinuousHard"])
def test_cartpole_episodes_in_lanes_equal_one_at_a_time(continuous, sparse):
    """From LANES_FROM members on, CartPole episodes run LANES at a time (a lane whose episode ends takes the next
    member): every member's return, length and states must be those of its episode run alone, bit for bit. Made
    to fail by not resetting a reused lane's running total (the sparse return) and by reading the member's
    parameters from the wrong lane."""
    from imix_cli.core.envs import kernels

    rng = np.random.default_rng(12)
    sizes = np.array([4, 8, 8, 1 if continuous else 2], dtype=np.int64)
    n = 3 * kernels.LANES_FROM + 5
    balancer = linear_mlp([0, 0, 1, 1], [1] if continuous else [-1, 1])  # noisy balancers and random members: 8 to 200 steps
    params = np.vstack([balancer + 0.05 * rng.standard_normal((n // 2, balancer.size)), rng.standard_normal((n - n // 2, balancer.size))])
    params = params[rng.permutation(n)]
    seeds = rng.integers(0, 2**63, n).astype(np.int64)
    returns, steps, trace = np.empty(n), np.empty(n, dtype=np.int64), np.full((n, 201, 4), np.nan)
    kernels.cartpole_episodes(params, seeds, sizes, continuous, sparse, 200, returns, steps, trace)
    assert steps.min() < 20 and steps.max() == 200
    for i in range(n):
        r1, s1, t1 = np.empty(1), np.empty(1, dtype=np.int64), np.full((1, 201, 4), np.nan)
        kernels.cartpole_episodes(params[i : i + 1], seeds[i : i + 1], sizes, continuous, sparse, 200, r1, s1, t1)
        assert (returns[i], steps[i]) == (r1[0], s1[0]), i
        assert np.array_equal(trace[i], t1[0], equal_nan=True), i

"""Where does imix's ARS part from sb3-contrib's on Swimmer? The checks behind docs/ars.md's study.

imix's ARS and sb3-contrib's are the same method with the same policy -- driven on one candidate
sequence (``step``) they give the same returns and steps until float rounding parts them -- yet
sb3-contrib reaches the ARS paper's threshold on more Swimmer seeds, and its loop on its env's own
reset stream learns faster than the same loop on seeded resets (``resets``). Each check runs one half
of the pipeline both ways:

* ``hybrid``: sb3-contrib's own ``ARS`` class (its update, its float32 weights, its RNG), with its
  candidates' episodes and the mean policy's measurements made by imix's evaluator -- 300
  iterations (600 episodes) per seed; prints each seed's return after 100 and 600 episodes and
  the episodes to 325;
* ``policy``: the returns of a few fixed random policies over 12 episodes, imix's evaluator against
  sb3-contrib's ``evaluate_policy`` on a ``DummyVecEnv``;
* ``pairs``: the spread of a mirrored pair's r+ - r- over 15 repeats in both loops, at theta = 0
  and at a given trained policy (common random numbers would shrink it);
* ``step``: the loops driven on one candidate sequence, iteration by iteration -- the same zero
  start and the same directions (sb3-contrib's torch draws for the seed) in all, and the same
  ``reset(seed=s)`` for each episode in all but the first: sb3-contrib's own loop as it trains
  (``native``: ``evaluate_policy`` on its ``DummyVecEnv``, episodes from the env's reset stream),
  the same loop with each candidate's reset seeded (``seeded``: ``venv.seed(s)`` before its
  ``evaluate_policy``), the hybrid (``imix``: imix's evaluator) and imix's own ARS (``tell``: whole
  generations of ``imix run env=swimmer +ars=swimmer algo=ars``, ``advance_lockstep``, at sb3-contrib's
  step alpha / sqrt(2), its random streams replaced by ones handing out sb3-contrib's delta and the
  seeds). Prints each iteration's r+ / r- and how far the weights are apart, the first
  iteration where two loops' r+ - r- differ in sign, and each native episode replayed from the start
  state its reset drew (float32 torch policy on a plain gymnasium env);
* ``resets``: sb3-contrib's ARS (its update, its directions) for a number of iterations on four
  rollouts -- native, seeded, seeded with a float64 policy, imix's evaluator (the last three on the
  same seeds) -- and each seed's mean-policy return afterwards (10 episodes, imix's evaluator);
* ``starts``: Swimmer's start states from an env's reset stream (as sb3-contrib trains) and from
  ``reset(seed=s)``: both uniform on +-0.1?

    python benchmarks/ars_sb3_gap.py hybrid [first_seed last_seed]
    python benchmarks/ars_sb3_gap.py policy
    python benchmarks/ars_sb3_gap.py pairs [policy_<k>_mean.npz]
    python benchmarks/ars_sb3_gap.py step [seed iterations]              # default 0 30
    python benchmarks/ars_sb3_gap.py resets [first_seed last_seed iterations]  # default 0 10 50
    python benchmarks/ars_sb3_gap.py starts [count]                       # default 4000

Needs the ars and mujoco extras (sb3-contrib, torch, mujoco).
"""

from __future__ import annotations

import sys

import numpy as np

SWIMMER, OBS, ACT, THRESHOLD = "Swimmer-v5", 8, 2, 325.0


def _imix_evaluator():
    from imix_cli.core.evaluation import make_evaluator

    return make_evaluator(SWIMMER, None, hidden=(), output="clip")


def _as_imix(weights) -> np.ndarray:
    """sb3-contrib's LinearPolicy weights (nn.Linear(8, 2).weight, (2, 8), flattened) as imix parameters."""
    from imix_cli.core.evaluation.policies import with_zero_biases

    w = np.asarray(weights, dtype=np.float64).reshape(-1, ACT, OBS).transpose(0, 2, 1).reshape(-1, OBS * ACT)
    return with_zero_biases(w, OBS, ACT, ())


def _as_sb3(weights: np.ndarray) -> np.ndarray:
    """imix's bias-free weights W (8 x 2, row-major) as sb3-contrib's flattened (2, 8) weight."""
    return np.asarray(weights, dtype=np.float64).reshape(OBS, ACT).T.reshape(-1).astype(np.float32)


def _sb3_model(seed: int = 0, cls=None):
    import gymnasium as gym
    import torch
    from sb3_contrib import ARS
    from stable_baselines3.common.vec_env import DummyVecEnv

    torch.set_num_threads(1)
    return (cls or ARS)("LinearPolicy", DummyVecEnv([lambda: gym.make(SWIMMER)]), seed=seed, n_delta=1, n_top=1, learning_rate=0.02, delta_std=0.01)


def hybrid(first: int = 0, last: int = 10) -> None:
    import torch
    from sb3_contrib import ARS

    evaluator = _imix_evaluator()

    class OnImixEpisodes(ARS):
        def evaluate_candidates(self, candidate_weights, callback, async_eval):
            returns, steps = evaluator.evaluate(_as_imix(candidate_weights.cpu().numpy()), self.episode_rng.integers(0, 2**62, size=self.pop_size))
            self.num_timesteps += int(steps.sum())
            return torch.as_tensor(returns, dtype=torch.float32)

    reached_seeds, at_100 = 0, []
    for seed in range(first, last):
        model = _sb3_model(seed, OnImixEpisodes)
        model.episode_rng = np.random.default_rng(seed)
        reached, scores = None, []
        for iteration in range(1, 301):
            model.learn(total_timesteps=1, reset_num_timesteps=False)
            if iteration % 10 == 0:
                params = np.repeat(_as_imix(model.weights.numpy()), 3, axis=0)
                scores.append(float(evaluator.evaluate(params, model.episode_rng.integers(0, 2**62, size=3))[0].mean()))
                reached = reached or (2 * iteration if scores[-1] >= THRESHOLD else None)
        reached_seeds += reached is not None
        at_100.append(scores[4])
        print(f"seed {seed}: {scores[4]:.0f} after 100 episodes, {scores[-1]:.0f} after 600, episodes to {THRESHOLD:.0f}: {reached}", flush=True)
    print(f"reached {reached_seeds}/{last - first}; median after 100 episodes {np.median(at_100):.1f}")


def policy() -> None:
    from stable_baselines3.common.evaluation import evaluate_policy

    evaluator, model, rng = _imix_evaluator(), _sb3_model(), np.random.default_rng(5)
    for k in range(3):
        weights = 0.3 * rng.normal(size=OBS * ACT)
        ours = evaluator.evaluate(np.repeat(_as_imix(_as_sb3(weights).astype(np.float64)), 12, axis=0), rng.integers(0, 2**62, size=12))[0]
        model.policy.load_from_vector(_as_sb3(weights))
        theirs, _ = evaluate_policy(model.policy, model.env, n_eval_episodes=12, return_episode_rewards=True, warn=False)
        print(f"policy {k}: imix {ours.mean():.1f} ± {ours.std():.1f}, sb3-contrib {np.mean(theirs):.1f} ± {np.std(theirs):.1f}")


def pairs(trained: str | None = None) -> None:
    from stable_baselines3.common.evaluation import evaluate_policy

    from imix_cli.running.files.policy_files import read_policy

    evaluator, model, rng = _imix_evaluator(), _sb3_model(), np.random.default_rng(3)
    points = [("theta = 0", np.zeros(OBS * ACT))] + ([("trained", read_policy(trained).params[: OBS * ACT])] if trained else [])
    for name, mean in points:
        delta = rng.standard_normal(OBS * ACT)
        plus, minus = mean + 0.01 * delta, mean - 0.01 * delta
        ours, theirs = [], []
        for _ in range(15):
            r = evaluator.evaluate(np.concatenate([_as_imix(_as_sb3(plus)), _as_imix(_as_sb3(minus))]), rng.integers(0, 2**62, size=2))[0]
            ours.append(r[0] - r[1])
            pair = []
            for w in (plus, minus):
                model.policy.load_from_vector(_as_sb3(w))
                pair.append(evaluate_policy(model.policy, model.env, n_eval_episodes=1, return_episode_rewards=True, warn=False)[0][0])
            theirs.append(pair[0] - pair[1])
        print(f"{name}: r+ - r- imix mean {np.mean(ours):.2f} sd {np.std(ours):.2f}; sb3-contrib mean {np.mean(theirs):.2f} sd {np.std(theirs):.2f}")


def _sb3_to_imix_weights(weights) -> np.ndarray:
    """sb3-contrib's flattened (2, 8) weights as imix's bias-free search vector W (8 x 2, row-major), float64."""
    return np.asarray(weights, dtype=np.float64).reshape(-1, ACT, OBS).transpose(0, 2, 1).reshape(-1, OBS * ACT)


class _F64Policy:
    """``evaluate_policy``'s model: sb3-contrib's clipped linear policy computed in float64 (numpy)."""

    def __init__(self, weights):
        self.w = np.asarray(weights, dtype=np.float64).reshape(ACT, OBS)

    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        return np.clip(np.asarray(obs, dtype=np.float64) @ self.w.T, -1.0, 1.0), None


def _driven_ars():
    """sb3-contrib's ``ARS`` whose candidates' episodes are driven from outside: ``rollout`` is
    ``"native"`` (its own ``evaluate_candidates``: ``evaluate_policy`` on the ``DummyVecEnv``, float32
    torch policy, each episode starting where the env's reset stream is), ``"seeded"`` (the same loop,
    but candidate i's episode starts from ``reset(seed=next_seeds[i])``: ``venv.seed`` before its
    ``evaluate_policy``), ``"seeded64"`` (as seeded, policy in float64) or ``"imix"`` (imix's evaluator,
    the same seeds). Each call records ``last = (candidates, returns)``."""
    import copy

    import torch
    from sb3_contrib import ARS
    from stable_baselines3.common.evaluation import evaluate_policy

    class Driven(ARS):
        rollout, next_seeds, evaluator, last = "native", None, None, None

        def evaluate_candidates(self, candidate_weights, callback, async_eval):
            if self.rollout == "native":
                returns = super().evaluate_candidates(candidate_weights, callback, async_eval)
            elif self.rollout == "imix":
                r, steps = self.evaluator.evaluate(_as_imix(candidate_weights.cpu().numpy()), self.next_seeds)
                self.num_timesteps += int(steps.sum())
                returns = torch.as_tensor(r, dtype=torch.float32)
            else:
                policy, out = copy.deepcopy(self.policy), []
                for w, s in zip(candidate_weights, self.next_seeds):
                    policy.load_from_vector(w.cpu())
                    self.env.seed(int(s))
                    model = policy if self.rollout == "seeded" else _F64Policy(w.cpu().numpy())
                    r, steps = evaluate_policy(model, self.env, n_eval_episodes=1, return_episode_rewards=True, warn=False)
                    self.num_timesteps += int(steps[0])
                    out.append(r[0])
                returns = torch.as_tensor(np.asarray(out), dtype=torch.float32)
            self.last = (candidate_weights.cpu().numpy().copy(), returns.numpy().astype(np.float64))
            return returns

    return Driven


def _replay(weights, qpos, qvel) -> float:
    """The return of sb3-contrib's float32 policy ``weights`` on Swimmer-v5 from the start state (qpos, qvel)."""
    import gymnasium as gym
    import mujoco
    import torch

    global _REPLAY_ENV
    if "_REPLAY_ENV" not in globals():
        _REPLAY_ENV = gym.make(SWIMMER)
    env, w = _REPLAY_ENV, torch.as_tensor(np.asarray(weights, dtype=np.float32).reshape(ACT, OBS))
    env.reset(seed=0)
    sim = env.unwrapped
    mujoco.mj_resetData(sim.model, sim.data)
    sim.set_state(qpos, qvel)
    obs, ret, done = sim._get_obs(), 0.0, False
    while not done:
        with torch.no_grad():
            action = (torch.as_tensor(obs[None].astype(np.float32)) @ w.T).numpy()[0]
        obs, reward, terminated, truncated, _ = env.step(np.clip(action, -1.0, 1.0).astype(np.float32))
        ret += float(np.float32(reward))
        done = terminated or truncated
    return ret


class _Feed:
    """Stands in for an imix seed's random streams: its sampling stream draws ``normal`` (N(0, I)
    directions), its episode stream hands out ``seeds``."""

    normal, seeds, state = None, None, None

    def standard_normal(self, size, dtype=np.float64):
        return np.asarray(self.normal, dtype=dtype).reshape(size)

    def integers(self, low, high=None, size=None, dtype=np.int64):
        return np.asarray(self.seeds, dtype=dtype).reshape(size)


def _imix_lockstep(seed: int, lr: float):
    """One seed of ``imix run env=swimmer +ars=swimmer algo=ars lr=<lr>``, a generation per call of the
    returned function (:func:`imix_cli.running.loop.lockstep.advance_lockstep`: plan the mirrored pairs, roll
    them out, tell); returns ``(generation, feed)``, the generation giving the pair's returns [r+, r-]."""
    from imix_cli.core.mixing.generation import MixingSettings
    from imix_cli.running.loop.lockstep import LoopSettings, advance_lockstep, new_seed_state

    es_options = dict(popsize=2, sigma=0.01, lr=lr, weight_decay=0.0, weight_decay_form="estool", top=1)
    settings = LoopSettings(
        algo="ars", env=SWIMMER, mixing_name="none", popsize=2, generations=10**6, dim=OBS * ACT, obs_dim=OBS, es_options=es_options,
        mixing=MixingSettings(None), obs_norm_warmup=None, policy_bias=False, eval_mean_every=0, eval_mean_episodes=3, checkpoint_every=0,
    )  # fmt: skip
    feed = _Feed()
    feed.state = state = new_seed_state(settings, seed)
    state.sample_rng = state.episode_rng = feed

    evaluator = _imix_evaluator()
    original = evaluator.evaluate

    def recording(params, seeds):  # the generation's episodes: [theta+, theta-]
        returns, steps = original(params, seeds)
        feed.last = np.asarray(returns, dtype=np.float64).copy()
        return returns, steps

    evaluator.evaluate = recording

    def generation() -> np.ndarray:
        advance_lockstep([state], settings, evaluator)
        return feed.last

    return generation, feed


def _one_iteration(model) -> None:
    """One ARS iteration of ``model``, on its own torch random stream (several models run interleaved)."""
    import torch

    torch.set_rng_state(model.torch_state)
    model.learn(total_timesteps=1, reset_num_timesteps=False)
    model.torch_state = torch.get_rng_state()


def step(seed: int = 0, iterations: int = 30) -> None:
    """The loops on one candidate sequence: the same zero start, the same directions (sb3-contrib's
    torch draws for seed ``seed``), the same reset seed for each episode; per iteration r+ / r- of each
    and how far their weights are apart."""
    import torch

    evaluator, driven = _imix_evaluator(), _driven_ars()
    loops = {}
    for name in ("native", "seeded", "imix"):
        loops[name] = _sb3_model(seed, driven)
        loops[name].rollout, loops[name].evaluator, loops[name].torch_state = name, evaluator, torch.get_rng_state()
    # the native loop's episode starts (qpos, qvel after each reset), to replay its episodes from them
    starts, env = [], loops["native"].env.envs[0]
    native_reset = env.reset

    def recording_reset(*args, **kwargs):
        out = native_reset(*args, **kwargs)
        starts.append((env.unwrapped.data.qpos.copy(), env.unwrapped.data.qvel.copy()))
        return out

    env.reset = recording_reset
    replay_worst = 0.0
    # imix's own ARS, whole generations as `imix run` makes them, at sb3-contrib's step alpha / sqrt(2)
    # (sb3-contrib's sigma_R has ddof 1); its two random streams hand out sb3-contrib's direction and the seeds
    run, feed = _imix_lockstep(seed, lr=0.02 / np.sqrt(2))
    seeds = np.random.default_rng(seed)
    first_flip, worst = {}, {}
    print(f"seed {seed}: r+ / r- of sb3-contrib's loop with native resets, with seeded resets, the hybrid (imix's evaluator), imix's ARS (tell)")
    for it in range(1, iterations + 1):
        s = seeds.integers(0, 2**62, size=2)
        torch.set_rng_state(loops["seeded"].torch_state)
        delta = torch.normal(mean=0.0, std=1.0, size=(1, OBS * ACT)).numpy()  # the direction all sb3 loops draw now
        for model in loops.values():
            model.next_seeds = s
            _one_iteration(model)
        feed.normal, feed.seeds = _sb3_to_imix_weights(delta), s
        rows = {name: m.last[1] for name, m in loops.items()} | {"tell": run()}
        # each native episode is its explicit reset's start state (the auto-reset after it is not used)
        replayed = [_replay(w, *starts[-4 + 2 * i]) for i, w in enumerate(loops["native"].last[0])]
        replay_worst = max(replay_worst, float(np.max(np.abs(np.array(replayed) - rows["native"]))))
        w_seeded, w_hybrid = (_sb3_to_imix_weights(loops[n].weights.numpy())[0] for n in ("seeded", "imix"))
        for a, b in (("native", "seeded"), ("seeded", "imix"), ("imix", "tell")):
            same_sign = np.sign(rows[a][0] - rows[a][1]) == np.sign(rows[b][0] - rows[b][1])
            if not same_sign and (a, b) not in first_flip:
                first_flip[(a, b)] = it
            if (a, b) not in first_flip:
                worst[(a, b)] = max(worst.get((a, b), 0.0), float(np.max(np.abs(rows[a] - rows[b]))))
        returns = "  ".join(f"{n} {r[0]:+8.3f}/{r[1]:+8.3f}" for n, r in rows.items())
        apart = (
            f"|w seeded - hybrid| {np.max(np.abs(w_seeded - w_hybrid)):.1e}  |w hybrid - tell| {np.max(np.abs(w_hybrid - feed.state.es.distribution.mean)):.1e}"
        )
        print(f"{it:3d} {returns}  {apart}", flush=True)
    print(f"native episodes replayed from their recorded start states (float32 torch policy): largest return difference {replay_worst:.1e}")
    for a, b in (("native", "seeded"), ("seeded", "imix"), ("imix", "tell")):
        flip, most = first_flip.get((a, b)), worst.get((a, b), float("nan"))
        print(f"{a} vs {b}: first iteration whose r+ - r- has another sign: {flip}; largest return difference before it: {most:.2e}")


def resets(first: int = 0, last: int = 10, iterations: int = 50) -> None:
    """sb3-contrib's ARS, its own update and its directions, run ``iterations`` iterations on four
    rollouts: native (the env's reset stream, as sb3-contrib trains), seeded (each episode from
    ``reset(seed=s)``, fresh seeds), seeded64 (the same, float64 policy) and imix (imix's evaluator, the
    same seeds). Prints each seed's mean-policy return afterwards (10 episodes, imix's evaluator)."""
    import torch

    evaluator, driven = _imix_evaluator(), _driven_ars()
    names = ("native", "seeded", "seeded64", "imix")
    scores = {n: [] for n in names}
    for seed in range(first, last):
        line = []
        for name in names:
            model = _sb3_model(seed, driven)
            model.rollout, model.evaluator, model.torch_state = name, evaluator, torch.get_rng_state()
            episodes = np.random.default_rng(seed)
            for _ in range(iterations):
                model.next_seeds = episodes.integers(0, 2**62, size=2)
                _one_iteration(model)
            score = float(evaluator.evaluate(np.repeat(_as_imix(model.weights.numpy()), 10, axis=0), np.arange(10) + 10**6)[0].mean())
            scores[name].append(score)
            line.append(f"{name} {score:6.1f}")
        print(f"seed {seed}: " + "  ".join(line), flush=True)
    summary = "; ".join(f"{n}: median {np.median(v):.1f}, {np.sum(np.array(v) >= 150)}/{len(v)} at >= 150" for n, v in scores.items())
    print(f"after {2 * iterations} episodes: {summary}")


def starts(count: int = 4000) -> None:
    """Swimmer-v5's start states (qpos, qvel) two ways: ``count`` explicit resets of one env's reset
    stream as sb3-contrib trains on it (every other reset: the ``DummyVecEnv``'s auto-reset comes
    between), and ``count`` ``reset(seed=s)`` on fresh seeds; per coordinate the mean and the variance
    over 0.1^2 / 3 (uniform on +-0.1: 1), and the stream's largest lag-1 correlation."""
    import gymnasium as gym

    env = gym.make(SWIMMER)
    sim = env.unwrapped

    def state() -> np.ndarray:
        return np.concatenate([sim.data.qpos, sim.data.qvel])

    env.reset(seed=3)
    stream = []
    for _ in range(2 * count):
        env.reset()
        stream.append(state())
    stream = np.array(stream)[1::2]
    seeded = []
    for s in np.random.default_rng(3).integers(0, 2**62, size=count):
        env.reset(seed=int(s))
        seeded.append(state())
    for name, x in (("reset stream", stream), ("reset(seed=s)", np.array(seeded))):
        print(f"{name}: |mean| <= {np.abs(x.mean(0)).max():.4f}, variance / (0.1^2 / 3) in [{(x.var(0) * 300).min():.3f}, {(x.var(0) * 300).max():.3f}]")
    lag = max(abs(np.corrcoef(stream[:-1, j], stream[1:, j])[0, 1]) for j in range(stream.shape[1]))
    print(f"reset stream: largest lag-1 correlation {lag:.3f}")


if __name__ == "__main__":
    what, args = (sys.argv[1] if len(sys.argv) > 1 else "policy"), sys.argv[2:]
    {
        "hybrid": lambda: hybrid(*map(int, args)),
        "policy": policy,
        "pairs": lambda: pairs(*args),
        "step": lambda: step(*map(int, args)),
        "resets": lambda: resets(*map(int, args)),
        "starts": lambda: starts(*map(int, args)),
    }[what]()

"""evosax's evolution strategies (JAX) as ES that :class:`~imix_cli.MixingES` mixes for.

One call turns an evosax algorithm, its params and a PRNG key into an object MixingES takes::

    algorithm = evosax.algorithms.SNES(population_size=50, solution=jnp.zeros(dim))
    es = from_evosax(algorithm, algorithm.default_params, jax.random.key(0))   # the one new line
    m = imix_cli.MixingES(es, "exact", rng=0)
    for generation in range(100):
        x = m.ask()                      # numpy rows: only the members to evaluate
        m.tell(x, fitness(x))            # evosax's convention: minimised

Mixing saves episodes only where consecutive distributions overlap: evosax's SNES at its defaults
moves too far per generation for that (docs/adapters.md, CartPole: more episodes with mixing than
without), and :func:`snes_for_mixing` builds it with step sizes under which mixing pays.

Mixing runs on the host in numpy; the update stays evosax's own jitted ``tell``. Why evosax's
``ask`` is still called: some algorithms prepare their state for ``tell`` in ``ask`` (CMA_ES and
Sep_CMA_ES eigendecompose C there, and ``tell`` uses that B and D), so the adapter calls ``ask``
once per generation for the state it returns -- the population it draws is discarded -- and
reads from that state the Gaussian ``ask`` samples from (:data:`DISTRIBUTIONS`). The members told
are the mixed generation, fresh and reused alike, in float32 if evosax runs in float32 (JAX's
default): mixing and the archive are float64, evosax sees its own precision.

``Open_ES`` samples antithetic pairs by default (``use_antithetic_sampling=True``): a pair's
halves are not independent draws, so the adapter mixes the pairs' anchors and evaluates every
mirror afresh, as imix does for ARS (:mod:`imix_cli.core.mixing.mirrored`); mixing then saves at most half
of the evaluations.

State is data. :meth:`EvosaxES.state_dict` is the evosax state and key as flat arrays under
their paths in the state's tree, and :func:`imix_cli.running.files.mixing_checkpoint.save_mixing` writes a
whole MixingES -- the adapter's state, the archive of generations with their returns and ages, the
mixing stream -- as imix's checkpoints are written (an ``.npz`` of arrays with a JSON header, no
pickle), read back onto a MixingES built with the same arguments.
"""

from __future__ import annotations

import functools

import numpy as np

from imix_cli.core.distributions import DiagonalGaussian, FullGaussian
from imix_cli.core.mixing.mirrored import MIRRORED_PAIRS

__all__ = ["DISTRIBUTIONS", "SNES_FOR_MIXING", "EvosaxES", "from_evosax", "snes_for_mixing"]


def _diag(mean, std):
    return DiagonalGaussian(mean, std)


#: evosax algorithm class name -> the Gaussian its ``ask`` samples from, read from the state ``ask``
#: returns (numpy float64 arrays: mean, std, and C's factors where there are). Register another here.
DISTRIBUTIONS = {
    "SNES": lambda s, d: _diag(s["mean"], s["std"]),
    "Open_ES": lambda s, d: _diag(s["mean"], np.full(d, float(s["std"]))),
    "CMA_ES": lambda s, d: FullGaussian(s["mean"], float(s["std"]) ** 2 * ((s["B"] * s["D"] ** 2) @ s["B"].T)),
    "Sep_CMA_ES": lambda s, d: _diag(s["mean"], float(s["std"]) * s["D"]),
}


def _reader(algorithm):
    for cls in type(algorithm).__mro__:
        if cls.__name__ in DISTRIBUTIONS and cls.__module__.startswith("evosax"):
            return DISTRIBUTIONS[cls.__name__]
    raise ValueError(f"evosax {type(algorithm).__name__}: no mixing adapter for it (supported: {', '.join(DISTRIBUTIONS)})")


def from_evosax(algorithm, params, key, mean=None) -> EvosaxES:
    """The adapter MixingES takes for evosax ``algorithm`` with ``params`` and PRNG ``key`` (its
    state initialised from ``key`` at ``mean``, a solution pytree; default: the algorithm's ``solution``)."""
    return EvosaxES(algorithm, params, key, mean)


#: evosax SNES's step sizes for mixing (:func:`snes_for_mixing`): Adam on the mean (learning rate, beta1) and
#: the learning rate of log std, as imix's SNES takes them (Adam, beta1 0.99, ~0.01 per generation on log std)
#: but the mean's rate 3x imix's 0.01. Measured on CartPole (docs/adapters.md, ``benchmarks/adapters.py evosax``).
SNES_FOR_MIXING = {"lr": 0.03, "b1": 0.99, "lr_std": 0.01}


def snes_for_mixing(population_size, solution, std_init=0.25, lr=SNES_FOR_MIXING["lr"], b1=SNES_FOR_MIXING["b1"], lr_std=SNES_FOR_MIXING["lr_std"]):
    """An evosax SNES and its params with step sizes that suit mixing: ``(algorithm, params)``.

    Why not evosax's defaults: its SNES moves the mean by a whole natural-gradient step per generation
    (SGD, learning rate 1) and log std by (3 + ln d) / (5 sqrt d) of its gradient. Consecutive
    distributions then overlap little, and mixing reuses a third of the members at best while its
    stored returns slow the search (docs/adapters.md: more episodes than evosax alone on CartPole).
    Adam with a small learning rate moves each coordinate of the mean by about ``lr`` standard units
    of its gradient per generation and log std by about ``lr_std``: most members of a generation lie
    where the next distribution still samples, and reuse is high.
    """
    import jax.numpy as jnp
    import optax
    from evosax.algorithms import SNES

    algorithm = SNES(population_size=population_size, solution=solution, optimizer=optax.adam(lr, b1=b1))
    params = algorithm.default_params.replace(std_init=jnp.asarray(std_init), lr_std_init=jnp.asarray(lr_std))
    return algorithm, params


class EvosaxES:
    """An evosax distribution-based algorithm with imix's ES protocol; fitness is evosax's (minimised).

    Attributes: ``algorithm``, ``params``, ``state`` (evosax's, as ``tell`` returned it), ``key``.
    """

    def __init__(self, algorithm, params, key, mean=None):
        import jax

        self._reader = _reader(algorithm)
        self.algorithm, self.params = algorithm, params
        self.name = f"evosax {type(algorithm).__name__}"
        self.dim = int(algorithm.num_dims)
        #: antithetic pairs (Open_ES's default): mixed as mirrored pairs (module docstring)
        self.generation_scheme = MIRRORED_PAIRS if getattr(algorithm, "use_antithetic_sampling", False) else None
        if self.generation_scheme is not None:
            self.directions = algorithm.population_size // 2
        key, k_init = jax.random.split(key)
        self.state = algorithm.init(k_init, algorithm.solution if mean is None else mean, params)
        self.key = key
        self.generation = 0
        self.mean_weights = None
        self._asked = None  # the state evosax's ask returned for this generation, and its distribution
        self._ask_step, self._tell_step = _jitted_steps(algorithm)

    @property
    def popsize(self) -> int:
        return int(self.algorithm.population_size)

    def _prepared(self):
        if self._asked is None:
            import jax

            self.key, state = self._ask_step(self.key, self.state, self.params)
            fields = jax.device_get({k: v for k, v in vars(state).items() if k in ("mean", "std", "B", "D")})  # one transfer
            values = {k: np.asarray(v, dtype=np.float64) for k, v in fields.items()}
            self._asked = (state, self._reader(values, self.dim))
        return self._asked

    @property
    def distribution(self):
        """The Gaussian evosax's ``ask`` samples from this generation."""
        return self._prepared()[1]

    def ask(self, rng: np.random.Generator) -> np.ndarray:
        return self.distribution.sample(self.popsize, rng)

    def probes(self, rng):
        return None

    def tell(self, samples, fitness) -> None:
        """evosax's ``tell`` of the whole generation (rows unravelled into the solution's pytree)."""
        import jax.numpy as jnp

        state, _ = self._prepared()
        dtype = state.mean.dtype
        flat = jnp.asarray(np.asarray(samples), dtype=dtype)
        self.key, self.state = self._tell_step(self.key, flat, jnp.asarray(np.asarray(fitness, dtype=np.float64), dtype=dtype), state, self.params)
        self._asked = None
        self.generation += 1

    @property
    def mean(self) -> np.ndarray:
        return self.distribution.mean

    # ------------------------------------------------------------------ state as data
    def state_dict(self) -> dict:
        """evosax's state and the key as flat numpy arrays (keys: the state's tree paths), and the generation."""
        import jax

        leaves = jax.tree_util.tree_flatten_with_path(self.state)[0]
        out = {f"state{jax.tree_util.keystr(path)}": np.asarray(leaf) for path, leaf in leaves}
        out["key"] = np.asarray(jax.random.key_data(self.key))
        out["generation"] = int(self.generation)
        return out

    def load_state_dict(self, state: dict) -> None:
        """Restore :meth:`state_dict` on an adapter built with the same algorithm and params; ValueError
        naming the entry that does not fit."""
        import jax
        import jax.numpy as jnp

        leaves, treedef = jax.tree_util.tree_flatten_with_path(self.state)
        new = []
        for path, leaf in leaves:
            name = f"state{jax.tree_util.keystr(path)}"
            if name not in state:
                raise ValueError(f"evosax state: {name} is missing")
            value = np.asarray(state[name])
            if value.shape != np.shape(leaf):
                raise ValueError(f"evosax state: {name} has shape {value.shape}, expected {np.shape(leaf)}")
            new.append(jnp.asarray(value, dtype=jnp.asarray(leaf).dtype))
        self.state = jax.tree_util.tree_unflatten(treedef, new)
        key_data = jnp.asarray(np.asarray(state["key"]), dtype=jnp.uint32)
        self.key = jax.random.wrap_key_data(key_data) if _typed(self.key) else key_data
        self.generation = int(state["generation"])
        self._asked = None


@functools.lru_cache(maxsize=32)
def _jitted_steps(algorithm):
    """evosax's ask (for its state) and tell with the key split and the rows unravelled into the solution's
    pytree, each one jitted call: called eagerly, the split and the unravelling dispatch a dozen small JAX
    operations per generation, several times the cost of the host's mixing. One pair per algorithm object
    (cached), so that adapters of the same algorithm compile once, as evosax's own jitted methods do."""
    import jax

    @jax.jit
    def ask_step(key, state, params):
        key, k_ask = jax.random.split(key)
        return key, algorithm.ask(k_ask, state, params)[1]

    @jax.jit
    def tell_step(key, flat, fitness, state, params):
        key, k_tell = jax.random.split(key)
        return key, algorithm.tell(k_tell, jax.vmap(algorithm._unravel_solution)(flat), fitness, state, params)[0]

    return ask_step, tell_step


def _typed(key) -> bool:
    import jax

    return jax.dtypes.issubdtype(key.dtype, jax.dtypes.prng_key)

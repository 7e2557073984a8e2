"""Environment ids and the modules they name: imported when the user types them, never when a file says so.

Why: gymnasium's ``module:Id`` convention (``gym.make("myenvs:Reach1D-v0")`` imports ``myenvs``,
whose import registers ``Reach1D-v0``) is how users bring their own environments, so ``imix run
env=gym env.id=myenvs:Reach1D-v0`` supports it: the user named the module, the user runs its code.
But an env id also comes back from files -- a policy file's header, a run's ``config.yaml`` -- and
results folders travel (a colleague's results, a download). A file naming a module must never
make imix import it: ``env_id="this:CartPole-v0"`` would run ``this`` on ``imix render``. So:

* :func:`import_user_env` -- for ids the user typed (``imix run``'s command line or own config):
  imports the named module, returns the plain id;
* :func:`file_env_id` -- for ids read from a file: refuses a ``module:`` prefix unless the user named
  that very module again on the command line (``imix eval import=myenvs``), and accepts only ids
  gymnasium already has registered (looking one up in the registry imports nothing).

The plain id (``Reach1D-v0``) is what imix then gives gymnasium; the full id is what it records
(``config.yaml``, the policy header), so that eval and render can say which module to name.
"""

from __future__ import annotations

import importlib
import re

#: A Python module path, as ``import`` accepts it: dotted identifiers.
_MODULE = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*$")


class EnvIdError(ValueError):
    """An env id that cannot be used; ``str(err)`` is one line naming it."""


def split_env_id(env_id: str) -> tuple[str | None, str]:
    """``"myenvs:Reach1D-v0"`` -> ``("myenvs", "Reach1D-v0")``; ``"CartPole-v0"`` -> ``(None, "CartPole-v0")``."""
    if ":" not in env_id:
        return None, env_id
    module, _, name = env_id.partition(":")
    return module, name


def plain_env_id(env_id: str) -> str:
    """The id without its ``module:`` prefix (what gymnasium's registry holds)."""
    return split_env_id(env_id)[1]


def import_user_env(env_id: str) -> str:
    """Import the module of an id the *user typed* (``module:Id``), then return the plain ``Id``.

    EnvIdError (one line) if the module cannot be imported or does not register the id.
    """
    module, name = split_env_id(env_id)
    if module is None:
        return env_id
    if not _MODULE.match(module) or not name or ":" in name:
        raise EnvIdError(f"env.id={env_id!r}: expected module:Id, e.g. myenvs:Reach1D-v0")
    try:
        importlib.import_module(module)
    except Exception as err:  # an import error or any error raised by the user's module
        text = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        raise EnvIdError(f"env.id={env_id!r}: cannot import {module} ({type(err).__name__}: {text}); is its folder on PYTHONPATH?") from None
    if not is_registered(name):
        raise EnvIdError(f"env.id={env_id!r}: importing {module} did not register {name!r} (gymnasium.register it at import)")
    return name


def user_modules(value: str | None) -> tuple[str, ...]:
    """The modules of an ``import=a,b`` argument, each checked to be a module path (UsageError-free: EnvIdError)."""
    if not value:
        return ()
    modules = tuple(m.strip() for m in value.split(",") if m.strip())
    bad = [m for m in modules if not _MODULE.match(m)]
    if bad:
        raise EnvIdError(f"bad value for import: {bad[0]!r} (expected module names, e.g. import=myenvs)")
    return modules


def file_env_id(env_id, allowed_modules=(), where: str = "the file") -> str:
    """The plain, registered id of an env id read from a file; EnvIdError (one line) otherwise.

    A ``module:`` prefix is accepted only if the user named that module (``allowed_modules``, from
    ``import=`` on their command line); it is then imported, as the user asked. Without a prefix,
    the id must already be registered: nothing is imported to find it.
    """
    if not isinstance(env_id, str) or not env_id or len(env_id) > 200:
        raise EnvIdError(f"{where}: env_id {env_id!r} is not an env id")
    module, name = split_env_id(env_id)
    if module is not None:
        if module not in allowed_modules:
            raise EnvIdError(
                f"{where}: env_id {env_id!r} names a module to import ({module}); imix never imports code named in a file: "
                f"if you trust it, name it yourself with import={module}"
            )
        return import_user_env(env_id)
    if not is_registered(env_id):
        raise EnvIdError(f"{where}: env_id {env_id!r} is not a registered gymnasium environment")
    return env_id


def is_registered(env_id: str) -> bool:
    """Whether gymnasium's registry (plus imix's own envs) holds ``env_id``; imports no user module."""
    import gymnasium as gym

    import imix_cli.core.envs  # noqa: F401  (registers the imix/ environments)

    return isinstance(env_id, str) and env_id in gym.registry
